"""Shared helpers for the benchmark sections: presets, timing, machine description."""

from __future__ import annotations

import platform
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ROOT / "presets" / "lenses"


#: the render time `python -m neurolens_addon.render` prints (", 4.2 s | ..." or ", 0.5 s")
RENDER_TIME_RE = re.compile(r", ([0-9.]+) s( \||$)", re.M)


def cli_render_seconds(scene, args) -> float:
    """Render the .blend `scene` with the command line and `args`; the render time it prints
    (start-up excluded)."""
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(scene), *map(str, args)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise RuntimeError(f"render failed: {p.stderr[-400:]}")
    m = RENDER_TIME_RE.search(p.stdout + p.stderr)
    if m is None:
        raise RuntimeError(f"no render time in the output: {(p.stdout + p.stderr)[-300:]}")
    return float(m.group(1))


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


def blender_version() -> str | None:
    """The Blender the benchmarks run in: the bpy module's version ("5.2.3"), read without
    importing bpy, or None where bpy is not installed."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("bpy")
    except PackageNotFoundError:
        return None


def main_blender() -> str:
    """The project's main Blender, major.minor ("5.0"): the bpy that requirements.txt pins."""
    text = (ROOT / "requirements.txt").read_text(encoding="utf-8")
    m = re.search(r"^bpy==(\d+\.\d+)", text, re.M)
    if m is None:
        raise RuntimeError("requirements.txt pins no bpy")
    return m.group(1)


def machine() -> str:
    """The machine line of a section: CPU, cores, Python, numpy and the Blender (bpy) whose
    Cycles, BVH and Python the figures come from."""
    import numpy

    from neurolens_addon.core.machine import processor
    blender = blender_version()
    return (f"{processor()}, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}" + (f", Blender {blender} (bpy)" if blender else ""))


def md_table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def measured_inputs(*paths: Path) -> str:
    """A digest of what a lens's figures depend on: its file and its models' model.json (the
    recorded evaluation included), so a changed lens or a retrained model is measured again."""
    import hashlib
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        f = p / "model.json" if p.is_dir() else p
        h.update(str(f.relative_to(ROOT) if f.is_relative_to(ROOT) else f).encode())
        h.update(f.read_bytes() if f.exists() else b"(missing)")
    return h.hexdigest()[:16]


class LensRecords:
    """Per-lens figures of a section that measures lens after lens (hours for the library):
    every lens's figures are measured together in one run (the ratios between its models),
    kept in build/bench-progress/SECTION.json as soon as they are, and with `resume` a lens
    whose inputs (measured_inputs) are unchanged since its figures in that file or in the
    section's last docs/bench/SECTION.json is not measured again: a run cut short goes on
    where it stopped. `only` (stems): measure those lenses and keep every other lens's last
    figures as they stand (a new preset measured without re-measuring the library, whose
    inputs may have changed since: its date says when each was measured); a lens with no
    kept figures at all is measured. Each lens's figures carry the date they were measured."""

    def __init__(self, section: str, resume: bool, only=None):
        import json
        self.progress = ROOT / "build" / "bench-progress" / f"{section}.json"
        self.only = None if only is None else set(only)
        self.kept: dict = {}
        if resume:
            for src in (ROOT / "docs" / "bench" / f"{section}.json", self.progress):
                try:
                    self.kept.update(json.loads(src.read_text(encoding="utf-8")))
                except (OSError, ValueError):
                    pass

    def get(self, stem: str, inputs: str):
        """The lens's kept figures when measured from the same inputs, else None."""
        figs = self.kept.get(stem)
        if not isinstance(figs, dict):
            return None
        if self.only is not None:
            return None if stem in self.only else figs
        return figs if figs.get("inputs") == inputs else None

    def put(self, stem: str, inputs: str, figs: dict) -> dict:
        """Record a lens's fresh figures (with their inputs and today's date)."""
        import datetime
        import json
        import os
        figs = dict(figs, inputs=inputs, measured=datetime.date.today().isoformat())
        self.kept[stem] = figs
        self.progress.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.progress.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.kept, indent=1), encoding="utf-8")
        os.replace(tmp, self.progress)
        return figs


#: run by peak_rss_of: starts the command, waits for it, writes "status peak_bytes" to argv[1]
_MEASURE = ("import os, subprocess, sys, threading\n"
            "p = subprocess.Popen(sys.argv[3:])\n"
            "timer = threading.Timer(float(sys.argv[2]), p.kill)\n"
            "timer.start()\n"
            "_pid, status, usage = os.wait4(p.pid, 0)   # (p.wait would reap it first)\n"
            "timer.cancel()\n"
            "open(sys.argv[1], 'w').write(f'{os.waitstatus_to_exitcode(status)} '\n"
            "                             f'{usage.ru_maxrss * 1024}')\n")


def peak_rss_of(cmd, timeout: float = 1200.0) -> tuple[int, str, int]:
    """(exit status, output, peak resident set in bytes) of a command's own process, measured
    from a small intermediate process: Linux starts a (v)forked child's ru_maxrss at its
    parent's high-water mark, and a benchmark's own process may have held gigabytes."""
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        peak_file = Path(tmp) / "peak"
        done = subprocess.run([sys.executable, "-c", _MEASURE, str(peak_file), str(timeout),
                               *map(str, cmd)], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT)
        text = done.stdout.decode(errors="replace")
        if not peak_file.exists():
            return -1, text, -1
        rc, peak = map(int, peak_file.read_text().split())
        return rc, text, peak
