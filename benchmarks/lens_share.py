"""The lens's share of the engine's frame and what the learned lens saves, per preset, with the
shading compiled.

The demo scene (presets/scenes/demo.blend) through every preset at its design f-number and
focus (the command line's defaults for the camera), WIDTH x HEIGHT, SAMPLES samples, one colour
ray, not denoised, rendered by the command line with the exact lens (numba-compiled trace) and
with the shipped learned model (onnxruntime on the CPU). From the summary line each render
prints: camera samples per second of the render loop (set-up excluded) and the lens's share of
the loop's work. Gain: the learned render's samples per second over the exact one's (> 1: the
learned lens makes the frame faster). The kernels are warmed first (kernel_warmup), so no
render pays a compile.

    python -m benchmarks.run lens_share
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import ROOT, md_table, preset_paths

WIDTH, HEIGHT, SAMPLES = 128, 72, 16
_RATE = re.compile(r"([0-9,]+) samples/s")
_LENS = re.compile(r"lens (\d+)%")


def _render(lens: str, model: str, out: Path):
    cmd = [sys.executable, "-m", "neurolens_addon.render",
           str(ROOT / "presets" / "scenes" / "demo.blend"), "--lens", lens, "--model", model,
           "--samples", str(SAMPLES), "--resolution", f"{WIDTH}x{HEIGHT}", "--colour-rays",
           "1", "--no-denoise", "--quiet", "--out", str(out)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1200)
    text = p.stdout + p.stderr
    if p.returncode != 0 or not _RATE.search(text):
        return None
    return {"samples_per_s": int(_RATE.search(text).group(1).replace(",", "")),
            "lens_share": int(_LENS.search(text).group(1)) / 100}


def run():
    subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"], cwd=ROOT,
                   check=True, capture_output=True)
    figs, rows = {}, []
    with tempfile.TemporaryDirectory() as tmp:
        for path in preset_paths():
            lens = path.stem
            exact = _render(lens, "exact", Path(tmp) / "e.png")
            learned = _render(lens, "learned", Path(tmp) / "l.png")
            f = {"exact": exact, "learned": learned}
            if exact and learned:
                f["gain"] = round(learned["samples_per_s"] / exact["samples_per_s"], 3)
            figs[lens] = f
            print(f"[lens_share] {lens}: {f}", flush=True)

            def cell(r):
                return "failed" if r is None else \
                    f"{r['samples_per_s']:,} ({100 * r['lens_share']:.0f} %)"
            rows.append([lens, cell(exact), cell(learned),
                         f"{f['gain']:.2f}x" if "gain" in f else ""])
    gains = sorted(f["gain"] for f in figs.values() if "gain" in f)
    median = gains[len(gains) // 2] if gains else float("nan")
    text = "\n".join([
        "## The lens's share of the engine's frame, per preset (compiled shading)",
        "",
        f"The demo scene through every preset (`benchmarks/lens_share.py`), {WIDTH}x{HEIGHT}, "
        f"{SAMPLES} samples, one colour ray, not denoised, by the command line: camera samples "
        "per second of the render loop (set-up excluded) and, in brackets, the lens's share "
        "of the loop's work, with the exact lens (the numba-compiled trace) and with the "
        "shipped learned model (onnxruntime, CPU). Gain: learned over exact (> 1: the learned "
        f"lens makes the frame faster). Median gain {median:.2f}x over {len(gains)} presets.",
        "",
        md_table(["preset", "exact: samples/s (lens)", "learned: samples/s (lens)", "gain"],
                 rows),
    ])
    return text, figs
