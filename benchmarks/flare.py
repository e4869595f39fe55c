"""Flare from Blender's lamps (engine.flare; Cycles: blender.flare_compositor), issue 31's
figures, on the scenes of testdata/flare_scenes.py through the double Gauss at f/4 (the
anamorphic streak through anamorphic_2x_60mm_f1_9), rendered headless by the command line
(`--ghosts`, its defaults: a single MgF2 layer on every air-glass surface, eight ghosts, a
quarter of the samples), 160x90:
  convergence  the point lamp in the dark, two seeds, the engine at 64 samples and Cycles at
               256: the correlation of the two flare images over 4x4 pixel blocks;
  against samples  the same lamp's flare at 4, 16 and 64 samples, two seeds each: the RMS
               noise of one estimate (their difference's RMS / sqrt 2) relative to the image's
               RMS; light tracing's falls as 1 / sqrt(rays);
  share        the night street (four lamps lighting a street): the flare's share of the
               frame's light (the Flare pass against Combined);
  streak       the anamorphic preset and the point lamp, 64 samples: the share of the flare's
               light in the band of rows through its brightest row, against the band's share
               of the frame;
  cost         a street of 16 lamps, the engine at 64 samples: the flare's own time (the
               command's summary) against the rest of the frame; and Cycles' frame with and
               without ghosts;
  images       the night street and the sun in frame, both renderers, in docs/images.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np

from neurolens_addon.engine.flare import MAX_SAMPLES

from .common import ROOT, cli_render_seconds, md_table

RES = "160x90"
#: the cost's larger frame (Cycles): resolution and samples
LARGE = ("480x270", 256)
IMAGES = ROOT / "docs" / "images"
ANAMORPHIC = "anamorphic_2x_60mm_f1_9"
_FLARE_S = re.compile(r"flare ([0-9.]+) s")
COATING = "single"


def _rgb(path: Path, layer: str) -> np.ndarray:
    from testdata.engine_scenes import read_exr
    ch = read_exr(path)
    return np.stack([ch[f"{layer}.{c}"] for c in "RGB"], axis=-1).astype(np.float64)


def _render(blend: Path, out: Path, engine: str, samples: int, *extra) -> float:
    """The command's render time; with ghosts, the panel's default coating (a single MgF2
    layer) named explicitly."""
    coat = ["--coating", COATING] if "--ghosts" in extra else []
    return cli_render_seconds(blend, ["--engine", engine, "--samples", samples, "--resolution",
                                      RES, "--out", out, *extra, *coat])


def _flare(path: Path, engine: str) -> np.ndarray:
    """The frame's flare: the engine's Flare pass, Cycles' composite (the render of a dark
    scene adds nothing to it: the point lamp's scene)."""
    return _rgb(path, "Flare" if engine == "neurolens" else "Composite.Combined")


def _blocks(img: np.ndarray) -> np.ndarray:
    lum = img.sum(axis=-1)
    h, w = (lum.shape[0] // 4) * 4, (lum.shape[1] // 4) * 4
    return lum[:h, :w].reshape(h // 4, 4, w // 4, 4).sum(axis=(1, 3)).ravel()


def _convergence(tmp: Path) -> dict:
    from testdata import flare_scenes
    blend = flare_scenes.write("point_lamp", tmp)
    out = {}
    for engine, samples in (("neurolens", 64), ("cycles", 256)):
        imgs = []
        for seed in (1, 2):
            exr = tmp / f"conv_{engine}_{seed}.exr"
            _render(blend, exr, engine, samples, "--ghosts", "--seed", seed)
            imgs.append(_flare(exr, engine))
        out[engine] = {"samples": samples,
                       "block_correlation": float(np.corrcoef(*map(_blocks, imgs))[0, 1])}
        print(f"  convergence {engine} {samples} spp: {out[engine]}", flush=True)
    # against samples: two seeds at each count; the relative RMS noise of one estimate is
    # their difference's RMS over the mean image's, / sqrt(2)
    out["against_samples"] = {}
    for n in (4, 16, 64):
        pair = []
        for seed in (4, 5):
            exr = tmp / f"conv_{n}_{seed}.exr"
            _render(blend, exr, "neurolens", n, "--ghosts", "--seed", seed)
            pair.append(_flare(exr, "neurolens"))
        mean = 0.5 * (pair[0] + pair[1])
        rel = float(np.sqrt(np.mean((pair[0] - pair[1]) ** 2) / 2.0)
                    / np.sqrt(np.mean(mean ** 2)))
        out["against_samples"][n] = rel
        print(f"  flare at {n} spp: relative RMS noise {rel:.3f}", flush=True)
    return out


def _share_and_images(tmp: Path) -> dict:
    from testdata import flare_scenes
    from .lens_effects import _save_png
    out = {}
    for name in ("night_street", "sun_in_frame"):
        blend = flare_scenes.write(name, tmp)
        for engine, samples in (("neurolens", 64), ("cycles", 256)):
            exr = tmp / f"{name}_{engine}.exr"
            seconds = _render(blend, exr, engine, samples, "--ghosts")
            layer = "Combined" if engine == "neurolens" else "Composite.Combined"
            frame = _rgb(exr, layer)
            _save_png(frame, frame, IMAGES / f"flare_{name}_{engine}.png")
            fig = {"seconds": seconds}
            if engine == "neurolens":
                flare = _rgb(exr, "Flare")
                fig["flare_share"] = float(flare.sum() / frame.sum())
            out[f"{name} {engine}"] = fig
            print(f"  {name} {engine}: {fig}", flush=True)
    return out


def _streak(tmp: Path) -> dict:
    from testdata import flare_scenes
    import bpy
    flare_scenes.point_lamp(lens=ANAMORPHIC)
    blend = tmp / "anamorphic_lamp.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    exr = tmp / "streak.exr"
    _render(blend, exr, "neurolens", 64, "--ghosts")
    lum = _flare(exr, "neurolens").sum(axis=-1)
    row = int(np.argmax(lum.sum(axis=1)))
    band = slice(max(0, row - 2), row + 3)
    rows = band.stop - band.start
    share = float(lum[band].sum() / lum.sum())
    from .lens_effects import _save_png
    _save_png(_flare(exr, "neurolens"), lum, IMAGES / "flare_anamorphic_lamp.png")
    out = {"band_rows": rows, "share": share, "concentration": share / (rows / lum.shape[0])}
    print(f"  streak: {out}", flush=True)
    return out


def _cost(tmp: Path) -> dict:
    from testdata import flare_scenes
    import subprocess
    import sys
    blend = flare_scenes.write("night_street", tmp, lamps=16)
    out = {}
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(blend), "--engine", "neurolens",
           "--samples", "64", "--resolution", RES, "--ghosts", "--coating", COATING, "--out",
           str(tmp / "c16.exr")]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    text = p.stdout + p.stderr
    from .common import RENDER_TIME_RE
    total = float(RENDER_TIME_RE.search(text).group(1))
    flare = float(_FLARE_S.search(text).group(1))
    out["neurolens"] = {"frame_s": total, "flare_s": flare,
                        "added": flare / max(total - flare, 1e-9)}
    p = subprocess.run(cmd[:5] + ["cycles"] + cmd[6:-1] + [str(tmp / "c16c.exr")], cwd=ROOT,
                       capture_output=True, text=True, timeout=1800)
    text = p.stdout + p.stderr
    with_s = float(RENDER_TIME_RE.search(text).group(1))
    flare_s = float(_FLARE_S.search(text).group(1))       # traced before the render
    without_s = _render(blend, tmp / "c16n.exr", "cycles", 64, "--no-ghosts")
    out["cycles"] = {"with_ghosts_s": with_s, "without_s": without_s, "flare_s": flare_s,
                     "added": flare_s / without_s}
    # a frame nearer production: Cycles' cost grows with pixels and samples, the flare's
    # rays with pixels only (MAX_SAMPLES' worth)
    res, spp = LARGE
    large = cmd[:5] + ["cycles", "--samples", str(spp), "--resolution", res] + cmd[10:-1]
    p = subprocess.run(large + [str(tmp / "c16l.exr")], cwd=ROOT, capture_output=True,
                       text=True, timeout=3600)
    text = p.stdout + p.stderr
    flare_l = float(_FLARE_S.search(text).group(1))
    without_l = cli_render_seconds(blend, ["--engine", "cycles", "--samples", spp,
                                           "--resolution", res, "--out", tmp / "c16ln.exr",
                                           "--no-ghosts"])
    out["cycles_large"] = {"resolution": res, "samples": spp, "flare_s": flare_l,
                           "without_s": without_l, "added": flare_l / without_l}
    print(f"  cost, 16 lamps: {out}", flush=True)
    return out


def run() -> tuple[str, dict]:
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        figs = {"convergence": _convergence(tmp), "share": _share_and_images(tmp),
                "streak": _streak(tmp), "cost": _cost(tmp)}
    return report(figs), figs


def report(figs: dict) -> str:
    c, s, k = figs["convergence"], figs["streak"], figs["cost"]
    rows = [[name, f"{f['seconds']:.1f}",
             "" if "flare_share" not in f else f"{100 * f['flare_share']:.2f} %"]
            for name, f in figs["share"].items()]
    return "\n".join([
        "## Flare from Blender's lamps",
        "",
        "Light-traced ghosts of the scene's lamps (`benchmarks/flare.py`: engine.flare; Cycles "
        "adds the same layer in the compositor), the double Gauss at f/4 with a single MgF2 "
        "layer on its air-glass surfaces (the panel's default), 160x90, eight ghosts, a "
        "quarter of the samples' worth of rays.",
        "",
        f"- **Convergence**, a point lamp in the dark, two seeds: the flare images correlate "
        f"at {c['neurolens']['block_correlation']:.3f} over 4x4 blocks in the engine at 64 "
        f"samples and {c['cycles']['block_correlation']:.3f} in Cycles at 256 (its flare "
        f"traced with {MAX_SAMPLES} samples' worth of rays, engine.flare.MAX_SAMPLES; target "
        ">= 0.9). "
        "Against samples (one estimate's RMS noise relative to the image's RMS, from two "
        "seeds): "
        + ", ".join(f"{n} spp {v:.3f}" for n, v in c["against_samples"].items()) + ".",
        f"- **Streak**: through {ANAMORPHIC} the point lamp's flare puts {100 * s['share']:.0f}"
        f" % of its light in the {s['band_rows']} rows through its brightest row, "
        f"{s['concentration']:.1f}x their share of the frame (target >= 5x): "
        "docs/images/flare_anamorphic_lamp.png.",
        f"- **Cost**, a street of 16 lamps at 64 samples: the engine's flare takes "
        f"{k['neurolens']['flare_s']:.1f} s of a {k['neurolens']['frame_s']:.1f} s frame "
        f"(+{100 * k['neurolens']['added']:.0f} % over the rest; target <= 30 %); for Cycles "
        f"the flare is traced in {k['cycles']['flare_s']:.1f} s before the render, "
        f"{100 * k['cycles']['added']:.0f} % of its {k['cycles']['without_s']:.1f} s frame "
        f"without ghosts at these 64 samples (the flare's rays stop growing at {MAX_SAMPLES} "
        "samples, "
        f"Cycles' frame does not); with ghosts, its own ghost samples too, "
        f"{k['cycles']['with_ghosts_s']:.1f} s."
        + ("" if "cycles_large" not in k else
           f" At {k['cycles_large']['resolution']} and {k['cycles_large']['samples']} "
           f"samples the flare is traced in {k['cycles_large']['flare_s']:.1f} s, "
           f"{100 * k['cycles_large']['added']:.0f} % of Cycles' "
           f"{k['cycles_large']['without_s']:.1f} s frame without ghosts."),
        "",
        "The frames (docs/images/flare_night_street_*.png, flare_sun_in_frame_*.png; the "
        "engine at 64 samples, Cycles at 256), and the flare's share of the frame's light:",
        "",
        md_table(["scene and renderer", "frame (s)", "flare / frame light"], rows),
    ])
