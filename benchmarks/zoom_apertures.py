"""One zoom lens, three focal lengths, both renderers: the defocus discs of far lights.

The testdata `far_lights` scene (three small emissive spheres 40 m away in a black world)
through the Canon RF 24-70 f/2.8 (US 2019/0278068 A1, example 5) wide open, focused at 0.5 m,
at 24.72, 48 (between the tabulated 44.86 and 67.89) and 67.89 mm, rendered by the command
line with Cycles and with the NeuroLens engine (dispersion off, raw images) at 200 x 80 and
256 samples. The middle disc's RMS radius (pixels) about its centroid is measured in both
(testdata.agreement_scenes.middle_light_rms_px) and predicted from the exact trace through the
derived camera (far_light_prediction). The frames go side by side to
docs/images/zoom_bokeh.png.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from testdata import agreement_scenes

from .common import ROOT, cli_render_seconds, md_table

FOCAL_MM = (24.72, 48.0, 67.89)
RES = (200, 80)
SAMPLES = 256
ENGINES = ("cycles", "neurolens")
IMAGE = ROOT / "docs" / "images" / "zoom_bokeh.png"


def _write_image(frames: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(ENGINES), len(FOCAL_MM), figsize=(12, 3.2))
    for j, f in enumerate(FOCAL_MM):
        for i, engine in enumerate(ENGINES):
            v = frames[engine, f] @ np.array([0.2126, 0.7152, 0.0722])
            ax = axes[i, j]
            ax.imshow(np.clip(v / np.percentile(v[v > 0], 95), 0.0, 1.0) ** (1 / 2.2),
                      cmap="gray", interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{'Cycles' if engine == 'cycles' else 'NeuroLens engine'}, "
                         f"{f:g} mm", fontsize=9)
    fig.suptitle("Canon RF 24-70 f/2.8 wide open, focused at 0.5 m: lights 40 m away",
                 fontsize=10)
    fig.tight_layout()
    IMAGE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(IMAGE, dpi=100)
    plt.close(fig)


def run():
    from testdata.engine_scenes import read_exr
    rows, figs, frames = [], {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        blend = agreement_scenes.write("far_lights", tmp)
        for f in FOCAL_MM:
            pred = agreement_scenes.far_light_prediction(f, *RES)
            want, n, stop = pred["rms_radius_px"], pred["f_number"], pred["stop_radius_mm"]
            got = {}
            for engine in ENGINES:
                out = tmp / f"{engine}_{f:g}.exr"
                seconds = cli_render_seconds(blend, [
                    "--model", "exact", "--focal-length", f, "--no-dispersion", "--samples",
                    SAMPLES, "--resolution", f"{RES[0]}x{RES[1]}", "--engine", engine,
                    "--seed", 1, "--no-denoise", "--quiet", "--out", out])
                ch = read_exr(out)
                frames[engine, f] = np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1)
                got[engine] = agreement_scenes.middle_light_rms_px(frames[engine, f], f)
                figs[f"{f:g}mm_{engine}"] = {"rms_radius_px": got[engine], "seconds": seconds}
            figs[f"{f:g}mm"] = {"f_number": n, "stop_radius_mm": stop,
                                "predicted_rms_radius_px": want}
            rows.append([f"{f:g}", f"{n:.3f}", f"{stop:.3f}", f"{want:.2f}",
                         f"{got['cycles']:.2f}", f"{got['neurolens']:.2f}",
                         f"{got['cycles'] / got['neurolens']:.3f}"])
    _write_image(frames)
    text = "\n".join([
        "## One zoom, three focal lengths, both renderers (defocus discs)",
        "",
        "The RF 24-70 f/2.8 wide open (its iris opens as it zooms: F/2.91 at every tabulated "
        "focal length), focused at 0.5 m, lights 40 m away (`python -m benchmarks.run "
        "zoom_apertures`; dispersion off, 200 x 80, 256 samples): the RMS radius of the "
        "middle light's disc in pixels, predicted by the exact trace through the derived "
        "camera and rendered by each renderer (at 24.72 mm the disc is about the sphere's "
        "own image and a pixel: the ratio there says least).",
        "",
        md_table(["focal length mm", "f-number", "stop radius mm", "predicted px",
                  "Cycles px", "engine px", "Cycles / engine"], rows),
        "",
        "Frames: docs/images/zoom_bokeh.png.",
    ])
    return text, figs
