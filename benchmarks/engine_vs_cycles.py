"""The NEUROLENS engine against Cycles with the project's exact OSL camera, on the scenes of
testdata/agreement_scenes.py: whether they estimate the same image, and how fast each shades
camera samples.

Every scene is rendered by the command line (`python -m neurolens_addon.render`) at WIDTH x
HEIGHT and SAMPLES samples, same lens, focus and f-number, the scene's own light paths, both
denoised: Cycles on the CPU, the engine with Embree, three colour rays a sample (its default:
no colour noise) and one (as the Cycles camera). Agreement: the mean of the Combined pass
(engine / Cycles) and the SSIM of the two luminance images clipped to [0, 1] (the passes
both engines write with one meaning: Cycles' depth of a custom camera is not the engine's
view-axis depth). Speed: camera samples shaded per second, W H spp / the render time the
command prints (scene sync, BVH build and denoising included for both), the median of REPEATS
runs of each, interleaved (one run varies by 5-10 % on a shared 2-core machine). The lens's share of
the engine's work is the engine's own figure. The demo scene renders with the learned lens
for the speed figure's lens share (the other scenes' lens is exact: the learned model is a
camera choice, not a scene's).

    python -m benchmarks.run engine_vs_cycles
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import ROOT, md_table
from .render_tradeoff import combined, luminance, ssim

WIDTH, HEIGHT, SAMPLES = 160, 90, 256
#: runs of each render whose median time is the figure
REPEATS = 3
SCENES = ("demo", "still_life", "environment", "million")
_TIME = re.compile(r"focus [0-9.]+ m, ([0-9.]+) s")
_LENS = re.compile(r"lens (\d+)%")


def _render(blend: Path, engine: str, out: Path, camera, model="exact", extra=()) -> dict:
    lens, focus, fstop = camera
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(blend), "--lens", lens,
           "--model", model, "--focus", str(focus), "--fstop", str(fstop), "--samples",
           str(SAMPLES), "--resolution", f"{WIDTH}x{HEIGHT}", "--engine", engine, "--quiet",
           "--out", str(out), *extra]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=3600)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr[-2000:]}")
    text = p.stdout + p.stderr
    seconds = float(_TIME.search(text).group(1))
    lens_share = _LENS.search(text)
    return {"seconds": seconds,
            "samples_per_s": round(WIDTH * HEIGHT * SAMPLES / seconds),
            "lens_share": None if lens_share is None else int(lens_share.group(1)) / 100,
            "image": combined(out)}


def _median(runs: list) -> dict:
    """The run of median time (its image and lens share with it)."""
    return sorted(runs, key=lambda r: r["seconds"])[len(runs) // 2]


def run():
    from testdata import agreement_scenes as scenes
    # the compiled kernels ready before anything is timed (their first compile is once)
    subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"], cwd=ROOT,
                   check=True, capture_output=True)
    figs = {"width": WIDTH, "height": HEIGHT, "samples": SAMPLES, "scenes": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in SCENES:
            blend = scenes.write(name, tmp)
            camera = scenes.CAMERAS[name]
            model = "learned" if name == "demo" else "exact"
            # interleaved, so that a slow spell of the machine falls on every renderer alike
            runs = {"cycles": [], 3: [], 1: []}
            for _ in range(REPEATS):
                runs["cycles"].append(_render(blend, "cycles", tmp / f"{name}_cycles.exr",
                                              camera, model))
                for rays in (3, 1):
                    runs[rays].append(_render(blend, "neurolens", tmp / f"{name}_{rays}.exr",
                                              camera, model, ("--colour-rays", str(rays))))
            cyc = _median(runs["cycles"])
            row = {"cycles_samples_per_s": cyc["samples_per_s"],
                   "cycles_seconds": cyc["seconds"]}
            for rays in (3, 1):
                eng = _median(runs[rays])
                a, b = cyc["image"], eng["image"]
                row[f"rays{rays}"] = {
                    "samples_per_s": eng["samples_per_s"], "seconds": eng["seconds"],
                    "runs_seconds": [r["seconds"] for r in runs[rays]],
                    "vs_cycles": round(eng["samples_per_s"] / cyc["samples_per_s"], 3),
                    "lens_share": eng["lens_share"],
                    "mean_ratio": round(float(b.mean() / a.mean()), 4),
                    "ssim": round(ssim(luminance(a), luminance(b)), 4)}
            row["cycles_runs_seconds"] = [r["seconds"] for r in runs["cycles"]]
            figs["scenes"][name] = row
            print(f"[engine_vs_cycles] {name}: {row}", flush=True)
    return figs


def section():
    figs = run()
    rows = []
    for name, r in figs["scenes"].items():
        for rays in (3, 1):
            e = r[f"rays{rays}"]
            rows.append([name, str(rays), f"{e['mean_ratio']:.3f}", f"{e['ssim']:.3f}",
                         f"{e['samples_per_s']:,}", f"{r['cycles_samples_per_s']:,}",
                         f"**{e['vs_cycles']:.2f}x**", f"{100 * e['lens_share']:.0f} %"])
    text = "\n".join([
        "## The engine against Cycles",
        "",
        f"Four scenes (`testdata/agreement_scenes.py`: the demo, a glass and metal still life "
        f"under an area light, an environment-lit bokeh scene, the still life on a floor of a "
        f"million triangles), {figs['width']}x{figs['height']}, {figs['samples']} samples, "
        "same lens, focus and f-number, each scene's own light paths, both denoised, rendered "
        "by the command line (`benchmarks/engine_vs_cycles.py`). Agreement: mean of the "
        "engine's Combined over Cycles' (target within 3 %) and SSIM of the clipped luminance "
        "(target >= 0.95). Speed: camera samples per second from the render time each command "
        "prints (sync, BVH and denoising included), the median of "
        f"{REPEATS} runs each, interleaved, Cycles on the CPU with the project's OSL "
        "camera, the engine with Embree and one worker thread per core; colour rays: three "
        "(R, G, B; the engine's default, no colour noise) or one (as the Cycles camera). "
        "Targets: 0.5x Cycles on the demo and on a million triangles; lens < 15 % of the "
        "engine's work (the demo renders through the learned lens, the others the exact one).",
        "",
        md_table(["scene", "colour rays", "mean engine / Cycles", "SSIM", "engine samples/s",
                  "Cycles samples/s", "engine / Cycles", "lens share"], rows)])
    return text, figs


if __name__ == "__main__":
    print(section()[0])
