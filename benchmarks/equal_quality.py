"""Equal quality: how long the engine takes to reach the noise Cycles reaches, on the still life
(glass, metal, an area light; testdata/agreement_scenes.py) with the lens's dispersion on.

Both renderers render through the same lens, focus and f-number at WIDTH x HEIGHT, raw (no
denoising), by the command line, in one run:
- Cycles (CPU, the project's OSL camera) at CYCLES_SAMPLES samples: one wavelength per camera
  ray, so dispersion brings colour noise; the engine at ENGINE_SAMPLES with three colour rays
  (R, G, B: no colour noise; its default) and with one;
- each renderer's own reference at REFERENCE_SAMPLES, another seed (independent noise).
Noise: the relative RMSE of the linear Combined RGB against the renderer's own reference,
    e = sqrt(mean((x - ref)^2)) / mean(ref),
with the reference's own noise taken out: for independent noise the measured mean square is
the image's plus the reference's, which is the image's times s / S (s samples, S the
reference's), so e^2 = measured^2 / (1 + s / S). Own references, because the two renderers'
converged images differ by a few per cent (engine_vs_cycles): against one reference the other
would never converge. The engine's time to Cycles' noise: its noise falls as 1 / sqrt(s), so
from each run s_i the samples to reach e_C are s_i (e_i / e_C)^2 (their median), and its frame
time at those samples is interpolated linearly in the samples between the runs (set-up
included, as the times the commands print).

    python -m benchmarks.run equal_quality
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from .common import md_table
from .engine_vs_cycles import _TIME
from .render_tradeoff import combined

WIDTH, HEIGHT = 160, 90
CYCLES_SAMPLES = 64
ENGINE_SAMPLES = (16, 32, 64, 128)
REFERENCE_SAMPLES = 1024
SCENE = "still_life"


def _render(blend, engine, out, camera, samples, seed, extra=()):
    import subprocess
    import sys

    from .common import ROOT
    lens, focus, fstop = camera
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(blend), "--lens", lens,
           "--model", "exact", "--focus", str(focus), "--fstop", str(fstop), "--samples",
           str(samples), "--resolution", f"{WIDTH}x{HEIGHT}", "--engine", engine,
           "--dispersion", "--no-denoise", "--seed", str(seed), "--quiet", "--out", str(out),
           *extra]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=3600)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr[-2000:]}")
    return float(_TIME.search(p.stdout + p.stderr).group(1)), combined(out)


def noise(image, reference, samples, reference_samples) -> float:
    """The relative RMSE of `image` against `reference`, the reference's noise taken out
    (module docstring)."""
    measured = float(np.mean((image - reference) ** 2))
    return float(np.sqrt(measured / (1.0 + samples / reference_samples)) / reference.mean())


def samples_to_reach(runs, target) -> float:
    """The samples at which noise falling as 1 / sqrt(s) reaches `target`, from runs
    [(samples, noise)]: the median of s_i (e_i / target)^2."""
    return float(np.median([s * (e / target) ** 2 for s, e in runs]))


def time_at(runs, samples) -> float:
    """Frame time at `samples`, linear in the samples through runs [(samples, seconds)]
    (extrapolated from the nearest two outside them)."""
    s, t = (np.array(v, dtype=np.float64) for v in zip(*sorted(runs)))
    if samples <= s[0]:
        i = 0
    elif samples >= s[-1]:
        i = len(s) - 2
    else:
        i = int(np.searchsorted(s, samples)) - 1
    slope = (t[i + 1] - t[i]) / (s[i + 1] - s[i])
    return float(t[i] + slope * (samples - s[i]))


def run():
    from testdata import agreement_scenes as scenes
    from .common import ROOT
    import subprocess
    import sys
    # the compiled kernels ready before anything is timed (their first compile is once)
    subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"], cwd=ROOT,
                   check=True, capture_output=True)
    figs = {"width": WIDTH, "height": HEIGHT, "scene": SCENE, "reference": REFERENCE_SAMPLES,
            "cycles_samples": CYCLES_SAMPLES}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        blend = scenes.write(SCENE, tmp)
        camera = scenes.CAMERAS[SCENE]
        _, ref_c = _render(blend, "cycles", tmp / "ref_c.exr", camera, REFERENCE_SAMPLES, 7)
        t_c, img_c = _render(blend, "cycles", tmp / "c.exr", camera, CYCLES_SAMPLES, 1)
        e_c = noise(img_c, ref_c, CYCLES_SAMPLES, REFERENCE_SAMPLES)
        figs["cycles"] = {"seconds": t_c, "noise": round(e_c, 5)}
        print(f"[equal_quality] cycles: {figs['cycles']}", flush=True)
        for rays in (3, 1):
            extra = ("--colour-rays", str(rays))
            _, ref_e = _render(blend, "neurolens", tmp / f"ref_{rays}.exr", camera,
                               REFERENCE_SAMPLES, 7, extra)
            runs = []
            for s in ENGINE_SAMPLES:
                t, img = _render(blend, "neurolens", tmp / f"e{rays}_{s}.exr", camera, s, 1,
                                 extra)
                runs.append({"samples": s, "seconds": t,
                             "noise": round(noise(img, ref_e, s, REFERENCE_SAMPLES), 5)})
                print(f"[equal_quality] engine {rays} rays: {runs[-1]}", flush=True)
            need = samples_to_reach([(r["samples"], r["noise"]) for r in runs], e_c)
            t_e = time_at([(r["samples"], r["seconds"]) for r in runs], need)
            figs[f"rays{rays}"] = {"runs": runs, "samples_to_cycles_noise": round(need, 1),
                                   "seconds_to_cycles_noise": round(t_e, 2),
                                   "vs_cycles": round(t_c / t_e, 3)}
    rows = [["Cycles (1 colour ray, spectral)", CYCLES_SAMPLES, f"{e_c:.4f}", f"{t_c:.1f}", "",
             "1.00x"]]
    for rays in (3, 1):
        f = figs[f"rays{rays}"]
        rows.append([f"engine, {rays} colour ray{'s' if rays > 1 else ''}",
                     f"{f['samples_to_cycles_noise']:.0f}", f"{e_c:.4f}",
                     f"{f['seconds_to_cycles_noise']:.1f}",
                     ", ".join(f"{r['samples']}: {r['noise']:.4f} in {r['seconds']:.1f} s"
                               for r in f["runs"]),
                     f"**{f['vs_cycles']:.2f}x**"])
    text = "\n".join([
        "## Equal quality: the engine's time to Cycles' noise",
        "",
        f"The still life with the lens's dispersion on (`benchmarks/equal_quality.py`), "
        f"{WIDTH}x{HEIGHT}, raw (no denoising), rendered by the command line: Cycles (CPU, "
        f"the project's OSL camera, one wavelength per camera ray) at {CYCLES_SAMPLES} "
        f"samples, the engine at {', '.join(map(str, ENGINE_SAMPLES))} samples with three "
        "colour rays (its default: no colour noise) and with one. Noise: the relative RMSE "
        "of the linear Combined against each renderer's own reference "
        f"({REFERENCE_SAMPLES} samples, another seed; its own noise taken out). The engine's "
        "samples to Cycles' noise follow from 1 / sqrt(samples), its time to them is "
        "interpolated between its runs (set-up included). Speed: Cycles' time over the "
        "engine's (target: >= 1x with three colour rays).",
        "",
        md_table(["renderer", "samples", "noise", "seconds", "engine runs (samples: noise)",
                  "speed vs Cycles"], rows),
    ])
    return text, figs
