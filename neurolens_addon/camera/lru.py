"""The camera package's caches (core.lru: thread-safe, least recently used first out) and how
often they missed."""

from __future__ import annotations

from ..core import lru as _core
from ..core.lru import Bounded, cache

#: how often each cache missed (for tests, and for anyone profiling the panel)
stats = {"lens_reads": 0, "focus_solves": 0, "fov_traces": 0}


def clear_all() -> None:
    """Forget every cache (core's and the camera's) and reset the counts."""
    _core.clear_all()
    for key in stats:
        stats[key] = 0


__all__ = ["Bounded", "cache", "clear_all", "stats"]
