"""Shared helpers for the benchmark sections: presets, timing, machine description."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ROOT / "presets" / "lenses"


def preset_paths():
    return sorted(PRESETS.glob("*.toml"))


def lens_of_model(lens, model_dir):
    """The lens a model learned: the file's own, or the lens at one of its tabulated zoom or
    focus positions (scripts/train_presets.py trains one model per position), matched by the
    content hash the model records."""
    from neurolens_addon.core.variable_gaps import position_lenses
    from neurolens_addon.neural.modelfile import read_header
    want = read_header(model_dir).lens_content_hash
    candidates = [lens] + [moved for _key, _k, moved in position_lenses(lens)]
    return next((c for c in candidates if c.content_hash() == want), lens)


def is_position_model(name: str) -> bool:
    """A model trained at a zoom or focus position (STEM.zoomFmm / STEM.focusDmm)."""
    return ".zoom" in name or ".focus" in name


def best_time(fn, repeats: int = 3) -> float:
    """Smallest wall time of `repeats` calls (seconds)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numpy
    return (f"{cpu}, {os.cpu_count()} logical cores, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}")


def md_table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)
