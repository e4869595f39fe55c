"""One zoom lens, three focal lengths, both renderers: the defocus discs of far lights.

The testdata `far_lights` scene (three small emissive spheres 40 m away in a black world)
through the Canon RF 24-70 f/2.8 (US 2019/0278068 A1, example 5) wide open, focused at 0.5 m,
at 24.72, 48 (between the tabulated 44.86 and 67.89) and 67.89 mm, rendered by the command
line with Cycles and with the NeuroLens engine (dispersion off: see docs/measurements.md for
Cycles with dispersion) at 200 x 80 and 256 samples. Each disc's RMS radius (pixels) about its
centroid (testdata.light_shape.spread_px) is measured in both, and predicted from the exact
trace: a point 40 m away traced from the scene through the derived camera's lens and stop
onto its sensor plane, its spot's RMS radius combined in quadrature with the sphere's own
image (a uniform disc of radius f tan(asin(r / d)): RMS radius / sqrt(2)). The frames go side
by side to docs/images/zoom_bokeh.png.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from testdata import agreement_scenes
from testdata.light_shape import spread_px

from .common import ROOT, cli_render_seconds, md_table

FOCAL_MM = (24.72, 48.0, 67.89)
RES = (200, 80)
SAMPLES = 256
ENGINES = ("cycles", "neurolens")
SPHERE_RADIUS_M, SPHERE_DISTANCE_M = 0.25, 40.0
IMAGE = ROOT / "docs" / "images" / "zoom_bokeh.png"


def _disc(img: np.ndarray, focal_mm: float) -> float:
    """The middle light's RMS radius (px) about its centroid: the columns within half the
    lights' spacing (6 m apart at 40 m) of the frame's middle."""
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    half = 0.5 * focal_mm * 6.0 / SPHERE_DISTANCE_M / (32.0 / RES[0])
    c = lum.shape[1] // 2
    return float(np.hypot(*spread_px(lum[:, int(c - half):int(c + half) + 1])))


def _predicted(focal_mm: float) -> tuple[float, float, float]:
    """(predicted RMS radius px, the derived camera's f-number, stop radius mm) at a focal
    length (module docstring)."""
    from neurolens_addon.camera import CameraSettings, resolve_camera
    from neurolens_addon.camera.lenses import PRESETS_DIR
    from neurolens_addon.core.film import FilmSettings
    from neurolens_addon.core.rays import Rays
    from neurolens_addon.core.trace import trace
    lens_name, focus_m, fstop = agreement_scenes.CAMERAS["far_lights"]
    setup = resolve_camera(CameraSettings(
        camera="cam", lens_path=str(PRESETS_DIR / f"{lens_name}.toml"), model="exact",
        f_number=fstop, focus_distance_mm=1000.0 * focus_m, zoom_mm=focal_mm,
        dispersion=False, film=FilmSettings(sensor_width=32.0, sensor_fit="HORIZONTAL",
                                            resolution_x=RES[0], resolution_y=RES[1])))
    c = setup.derived
    n = 200_000
    rng = np.random.default_rng(0)
    front = c.lens.surfaces[0].semi_diameter_mm
    r, phi = front * np.sqrt(rng.random(n)), 2.0 * np.pi * rng.random(n)
    z0 = 1000.0 * SPHERE_DISTANCE_M
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, c.lens.vertex_z[0] - z0)])
    d /= np.linalg.norm(d, axis=0)
    o = np.tile(np.array([[0.0], [0.0], [z0]]), (1, n))
    res = trace(c.lens, Rays(o, d, np.full(n, 587.5618)), from_sensor=False,
                sensor_z=c.sensor_z_mm, stop_radius=c.stop_radius_mm)
    x, y = res.rays.o[0, res.valid], res.rays.o[1, res.valid]
    spot = math.sqrt(((x - x.mean()) ** 2 + (y - y.mean()) ** 2).mean())
    sphere = setup.entry.efl_mm * math.tan(math.asin(SPHERE_RADIUS_M / SPHERE_DISTANCE_M))
    pitch = 32.0 / RES[0]
    return math.hypot(spot, sphere / math.sqrt(2.0)) / pitch, c.f_number, c.stop_radius_mm


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
            want, n, stop = _predicted(f)
            got = {}
            for engine in ENGINES:
                out = tmp / f"{engine}_{f:g}.exr"
                seconds = cli_render_seconds(blend, [
                    "--model", "exact", "--focal-length", f, "--no-dispersion", "--samples",
                    SAMPLES, "--resolution", f"{RES[0]}x{RES[1]}", "--engine", engine,
                    "--seed", 1, "--no-denoise", "--quiet", "--out", out])
                ch = read_exr(out)
                frames[engine, f] = np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1)
                got[engine] = _disc(frames[engine, f], f)
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
