"""Cost of the lens effects against renders without them (issue 17 figures).

Diffraction (core.diffraction): the shipped demo scene through the double Gauss (the scene
camera's aperture shape; the cost does not depend on it), focused at 1.6 m, at f/2.8 and f/16 (the kernel grows with the working
f-number), rendered headless (`python -m neurolens_addon.render`, one process per render, the
render time the command prints) by the NEUROLENS engine and by Cycles, each with and without
`--diffraction`, in one run: the difference is the kernel (built once per process: the
pattern's two FFTs and 21 wavelengths on the film's grid) and the frame's FFT convolution
(the engine's own, after denoising; Cycles' compositor Convolve node). In-process timings of
the kernel and of the convolution of a 1920 x 1080 frame are given beside them.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .common import ROOT, md_table

SCENE = ROOT / "presets" / "scenes" / "demo.blend"
LENS = "double_gauss_50mm_f2"
RES = "480x270"
SAMPLES = {"neurolens": 8, "cycles": 32}
F_NUMBERS = (2.8, 16.0)


def _render(engine: str, fstop: float, diffraction: bool, out: Path) -> float:
    from .render_tradeoff import TIME_RE
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(SCENE), "--lens", LENS,
           "--model", "exact", "--focus", "1.6", "--fstop", f"{fstop:g}", "--samples",
           str(SAMPLES[engine]), "--resolution", RES, "--engine", engine, "--seed", "1",
           "--quiet", "--out", str(out)]
    cmd.append("--diffraction" if diffraction else "--no-diffraction")
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise RuntimeError(f"render failed: {p.stderr[-400:]}")
    m = TIME_RE.search(p.stdout + p.stderr)
    if m is None:
        raise RuntimeError(f"no render time in the output: {(p.stdout + p.stderr)[-300:]}")
    return float(m.group(1))


def _in_process() -> dict:
    from neurolens_addon.core.aperture import PolygonAperture
    from neurolens_addon.core.diffraction import build_pattern, convolve, film_kernel
    ap = PolygonAperture(6)
    t0 = time.perf_counter()
    pattern = build_pattern(ap)
    t_pattern = time.perf_counter() - t0
    out = {"pattern_s": t_pattern}
    img = np.random.default_rng(0).random((1080, 1920, 4)).astype(np.float32)
    for n in F_NUMBERS:
        t0 = time.perf_counter()
        k = film_kernel(pattern, pixel_mm=36.0 / 1920, working_f_number=n, dispersion=True,
                        max_radius_px=1920)
        t_kernel = time.perf_counter() - t0
        t0 = time.perf_counter()
        convolve(img, k)
        out[f"f{n:g}"] = {"kernel_s": t_kernel, "convolve_1080p_s": time.perf_counter() - t0,
                          "kernel_px": int(k.kernels.shape[1])}
    return out


def run() -> tuple[str, dict]:
    figs = {"in_process": _in_process()}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for engine in ("neurolens", "cycles"):
            for n in F_NUMBERS:
                off = _render(engine, n, False, Path(tmp) / "off.exr")
                on = _render(engine, n, True, Path(tmp) / "on.exr")
                figs[f"{engine} f{n:g}"] = {"without_s": off, "with_s": on}
                rows.append([engine, f"f/{n:g}", SAMPLES[engine], f"{off:.2f}", f"{on:.2f}",
                             f"{on - off:+.2f}", f"{on / off:.2f}"])
                print(f"  {engine} f/{n:g}: {off:.2f} s without, {on:.2f} s with diffraction",
                      flush=True)
    ip = figs["in_process"]
    inproc = [[f"f/{n:g}", ip[f"f{n:g}"]["kernel_px"], f"{ip[f'f{n:g}']['kernel_s']:.2f}",
               f"{ip[f'f{n:g}']['convolve_1080p_s']:.2f}"] for n in F_NUMBERS]
    text = "\n".join([
        "## Lens effects: the cost of diffraction (same run, both renderers)",
        "",
        f"Demo scene, {LENS}, focus 1.6 m, {RES}, exact lens; render time the "
        "command prints (one process per render: the kernel is built in each).",
        "",
        md_table(["engine", "f-number", "samples", "without s", "with s", "difference s",
                  "ratio"], rows),
        "",
        f"In process (hexagon): the pattern's two FFTs {ip['pattern_s']:.2f} s once per "
        "aperture shape; per film and f-number (1920 x 1080 on 36 mm, dispersion: 21 "
        "wavelengths):",
        "",
        md_table(["f-number", "kernel side px", "kernel s", "convolution of a 1080p frame s"],
                 inproc)])
    return text, figs
