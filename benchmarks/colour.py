"""Colour with Dispersion on: negative pixels, colour noise, lateral colour.

Three measurements, one run:
  lateral colour  every preset, a distant point at 70 % of the half field: the distance from the
                  blue to the red image (core.field.lateral_colour_mm) under the signed
                  colour-matching weights the renderers used before, under our non-negative
                  responses (core.sensor_response) and under the plainly clipped curves;
  negative pixels every preset through the exact lens, Dispersion on, 1 and 16 samples, in the
                  engine (coloured spheres before an emissive checker; Combined, Depth,
                  Vignetting and Lens Uncertainty; Normal is a signed vector and left out) and
                  in Cycles (the same kind of scene; Combined);
  colour noise    a grey wall 2 m away lit by white light, and by a red and a blue light: the
                  standard deviation of R - G over the wall's centre at 16 samples, Dispersion
                  on and off, in the engine and in Cycles (Blender's own camera as reference).

    python -m benchmarks.run colour
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from .common import ROOT, md_table, preset_paths

if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

NOISE_SAMPLES = 16
WALL_PX = 64
LIGHTS = {"white": [(1.0, 1.0, 1.0)], "red+blue": [(1.0, 0.2, 0.2), (0.2, 0.2, 1.0)]}
ENGINE_PASSES = ("Combined.R", "Combined.G", "Combined.B", "Combined.A", "Depth", "Vignetting",
                 "Lens Uncertainty")


def lateral_colour() -> list[dict]:
    from neurolens_addon.core.field import half_field_deg, lateral_colour_mm
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.sensor_response import sensor_response
    from neurolens_addon.core.spectrum import cmf_rgb, rgb_normalisation
    k = rgb_normalisation()
    rows = []
    for path in preset_paths():
        lens = load_lens(path)
        field = 0.7 * half_field_deg(lens)
        signed = lateral_colour_mm(lens, field, lambda lam: cmf_rgb(lam) * k)
        ours = lateral_colour_mm(lens, field, sensor_response().at)
        clipped = lateral_colour_mm(lens, field, lambda lam: np.maximum(cmf_rgb(lam) * k, 0.0))
        rows.append({"lens": path.stem, "field_deg": round(field, 2),
                     "signed_um": round(signed * 1e3, 2), "responses_um": round(ours * 1e3, 2),
                     "clipped_um": round(clipped * 1e3, 2),
                     "responses_over_signed": round(ours / signed, 3),
                     "clipped_over_signed": round(clipped / signed, 3)})
    return rows


# ---- engine --------------------------------------------------------------------------------

def _engine_spheres(lens_name: str):
    import bpy
    from testdata import engine_scenes as scenes
    scenes.reset()
    for i, (x, c) in enumerate([(-0.5, (1, 0.2, 0.1)), (0.0, (0.1, 1, 0.2)),
                                (0.5, (0.2, 0.3, 1))]):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.2, location=(x, 0.0, -2.0 - i * 0.5))
        bpy.context.object.data.materials.append(scenes.material(f"m{i}", c))
    scenes.checker_plane(-4.0, 6.0, 8)
    bpy.ops.object.light_add(type="SUN", rotation=(0.5, 0.2, 0.0))
    scenes.camera(lens=lens_name, focus=2.0, fstop=4.0, sensor_width=36.0, model="exact")


def engine_figures(tmp: Path) -> dict:
    from testdata import engine_scenes as scenes
    negatives = []
    for path in preset_paths():
        _engine_spheres(path.stem)
        row = {"lens": path.stem}
        for spp in (1, 16):
            ch = scenes.render(tmp / "e.exr", 48, 32, spp, dispersion=True)
            vals = np.concatenate([ch[k].ravel() for k in ENGINE_PASSES if k in ch])
            row[f"negative_{spp}spp"] = int((vals < 0).sum())
            row[f"min_{spp}spp"] = float(vals.min())
        negatives.append(row)
    noise = []
    c = slice(WALL_PX // 6, WALL_PX - WALL_PX // 6)
    for name, colours in LIGHTS.items():
        scenes.lit_wall(colours)
        row = {"light": name}
        for disp in (False, True):
            t0 = time.perf_counter()
            ch = scenes.render(tmp / "w.exr", WALL_PX, WALL_PX, NOISE_SAMPLES, dispersion=disp)
            key = "on" if disp else "off"
            row[f"seconds_{key}"] = round(time.perf_counter() - t0, 2)
            row[f"rg_std_{key}"] = float((ch["Combined.R"] - ch["Combined.G"])[c, c].std())
            row[f"g_std_{key}"] = float(ch["Combined.G"][c, c].std())
        noise.append(row)
    return {"negatives": negatives, "noise": noise}


# ---- Cycles --------------------------------------------------------------------------------

def cycles_figures(tmp: Path) -> dict:
    from neurolens_addon.blender.cycles_camera import apply_lens_camera, clear_lens_camera
    from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.cycles import CameraSpec
    from testdata.cycles_scenes import lit_wall, render, spheres_scene

    def spec(lens, disp, focus_mm):
        return CameraSpec("exact", lens=lens, sensor_z_mm=focus_sensor_z(lens, focus_mm),
                          dispersion=disp, sensor_width_mm=36.0, sensor_height_mm=24.0)

    negatives = []
    scene, cam = spheres_scene(48, 32, 1)
    for path in preset_paths():
        lens = load_lens(path)
        apply_lens_camera(cam.data, spec(lens, True, max(2000.0, closest_focus_mm(lens))))
        row = {"lens": path.stem}
        for spp in (1, 16):
            scene.cycles.samples = spp
            img, _ = render(scene, tmp / "c.exr")
            row[f"negative_{spp}spp"] = int((img[..., :3] < 0).sum())
            row[f"min_{spp}spp"] = float(img[..., :3].min())
        negatives.append(row)
    noise = []
    c = slice(WALL_PX // 6, WALL_PX - WALL_PX // 6)
    dg = load_lens(ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml")
    for name, colours in LIGHTS.items():
        scene, cam = lit_wall(colours, WALL_PX, WALL_PX, NOISE_SAMPLES)
        row = {"light": name}
        for key in ("blender", "off", "on"):
            if key == "blender":
                clear_lens_camera(cam.data)
                cam.data.lens = 50.0
            else:
                apply_lens_camera(cam.data, spec(dg, key == "on", 2000.0))
            img, dt = render(scene, tmp / "w.exr")
            row[f"rg_std_{key}"] = float((img[c, c, 0] - img[c, c, 1]).std())
            row[f"g_std_{key}"] = float(img[c, c, 1].std())
        noise.append(row)
    return {"negatives": negatives, "noise": noise}


def run() -> tuple[str, dict]:
    import tempfile
    import bpy  # noqa: F401  (Blender in this process)
    with tempfile.TemporaryDirectory() as d:
        figs = {"lateral_colour": lateral_colour(), "engine": engine_figures(Path(d)),
                "cycles": cycles_figures(Path(d)), "noise_samples": NOISE_SAMPLES}
    return report(figs), figs


def report(f: dict) -> str:
    lc = f["lateral_colour"]
    out = ["## Colour with Dispersion on", "",
           "Regenerated by `python -m benchmarks.run colour` (benchmarks/colour.py). Each ray "
           "now carries non-negative channel responses (core.sensor_response): the engine "
           "traces three rays a sample (R, G, B, sharing every other random number), Cycles one "
           "ray with weight 3 s / sum s.", "",
           "### Lateral colour (blue-to-red image distance, 70 % of the half field, um)", "",
           md_table(["lens", "signed CMF (before)", "responses (now)", "now / before",
                     "clipped CMF", "clipped / before"],
                    [[r["lens"], f"{r['signed_um']:.2f}", f"{r['responses_um']:.2f}",
                      f"{r['responses_over_signed']:.2f}", f"{r['clipped_um']:.2f}",
                      f"{r['clipped_over_signed']:.2f}"] for r in lc]), ""]
    for where in ("engine", "cycles"):
        neg = f[where]["negatives"]
        total = sum(r["negative_1spp"] + r["negative_16spp"] for r in neg)
        worst = min(min(r["min_1spp"], r["min_16spp"]) for r in neg)
        out += [f"### Negative pixels, {where} (every preset, 1 and 16 samples)", "",
                f"{total} negative values in {2 * len(neg)} renders; the smallest value is "
                f"{worst:.4g}.", ""]
    e, c = f["engine"]["noise"], f["cycles"]["noise"]
    out += [f"### Colour noise on a grey wall ({f['noise_samples']} samples, std of R - G; "
            "G's std for scale)", "",
            md_table(["renderer", "light", "Dispersion off", "Dispersion on", "on / off",
                      "G std (on)", "time on / off"],
                     [["engine", r["light"], f"{r['rg_std_off']:.4f}", f"{r['rg_std_on']:.4f}",
                       f"{r['rg_std_on'] / max(r['rg_std_off'], 1e-12):.2f}"
                       if r["rg_std_off"] > 1e-9 else "(off is exactly grey)",
                       f"{r['g_std_on']:.4f}",
                       f"{r['seconds_on'] / r['seconds_off']:.2f}"] for r in e]
                     + [["Cycles", r["light"], f"{r['rg_std_off']:.4f}", f"{r['rg_std_on']:.4f}",
                         f"{r['rg_std_on'] / max(r['rg_std_off'], 1e-12):.2f}"
                         if r["rg_std_off"] > 1e-9 else "(off is exactly grey)",
                         f"{r['g_std_on']:.4f}", ""] for r in c]
                     + [["Cycles, Blender's camera", r["light"], f"{r['rg_std_blender']:.4f}",
                         "", "", f"{r['g_std_blender']:.4f}", ""] for r in c]), ""]
    return "\n".join(out)
