"""The machine a measurement ran on, in words: its processor and logical cores (the figures
the project records say where they were taken; ratios travel between machines, values less)."""

from __future__ import annotations

import os
import platform


def processor() -> str:
    """"<CPU model>, <N> logical cores" (the model from /proc/cpuinfo where there is one)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical cores"
