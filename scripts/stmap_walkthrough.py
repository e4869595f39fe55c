"""The user guide's compositing walk-through, made for real: a plate shot through a lens, the
plate undistorted, CG rendered through Blender's pinhole camera with the overscan the lens
needs, and the CG distorted back and laid over the plate, all with the lens's ST-maps; and,
to check it, the same CG rendered straight through the lens by the NeuroLens engine.

    python scripts/stmap_walkthrough.py [--samples N]

Writes docs/images/stmap_{plate,undistorted,cg,comp}.png and prints how well the distorted
CG's silhouette matches the one the lens renders (intersection over union of their alpha).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DEMO = ROOT / "presets" / "scenes" / "demo.blend"
LENS = "wide_20mm_f2_8"
IMAGES = ROOT / "docs" / "images"


def _cli(*args):
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", *map(str, args)],
                       cwd=ROOT, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(p.stderr[-2000:])
    return p


def _rgba(path: Path) -> np.ndarray:
    """Combined RGBA of an EXR, rows from the bottom."""
    from testdata.engine_scenes import read_exr
    ch = read_exr(path)
    key = "Combined" if "Combined.R" in ch else next(k.rsplit(".", 1)[0] for k in ch
                                                     if k.endswith(".R"))
    return np.stack([ch[f"{key}.{c}"] for c in "RGBA"], axis=-1)[::-1].astype(np.float64)


def _sample(img: np.ndarray, stmap: np.ndarray) -> np.ndarray:
    """img (rows from the bottom) read where each pixel of `stmap` points (R, G: its
    normalised position), bilinearly, as an STMap node reads it; nothing where A = 0."""
    h, w = img.shape[:2]
    u = stmap[..., 0] * w - 0.5
    v = stmap[..., 1] * h - 0.5
    ok = (stmap[..., 2] == 1) & (u > -0.5) & (v > -0.5) & (u < w - 0.5) & (v < h - 0.5)
    i0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    j0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = np.clip(u - i0, 0, 1)[..., None], np.clip(v - j0, 0, 1)[..., None]
    out = ((1 - a) * (1 - b) * img[j0, i0] + a * (1 - b) * img[j0, i0 + 1]
           + (1 - a) * b * img[j0 + 1, i0] + a * b * img[j0 + 1, i0 + 1])
    return np.where(ok[..., None], out, 0.0)


def _png(img: np.ndarray, path: Path) -> None:
    from PIL import Image
    rgb = np.clip(img[..., :3], 0.0, None)
    rgb = np.clip(rgb / (1.0 + rgb) * 1.6, 0.0, 1.0) ** (1 / 2.2)
    Image.fromarray((rgb[::-1] * 255 + 0.5).astype(np.uint8)).save(path)


def _cg_scene(path: Path, cg_only: bool) -> None:
    """The demo scene with a CG object added (an orange torus by the red sphere); with
    cg_only, everything else hidden from the render and the film transparent."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(DEMO))
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_torus_add(location=(0.42, 0.25, 0.22), major_radius=0.13,
                                     minor_radius=0.045, rotation=(1.1, 0.3, 0.0))
    torus = bpy.context.object
    from presets.scenes.make_demo_scene import principled
    torus.data.materials.append(principled("cg", (0.9, 0.35, 0.05), roughness=0.3))
    if cg_only:
        for ob in scene.objects:
            if ob.type == "MESH" and ob is not torus:
                ob.hide_render = True
        scene.render.film_transparent = True
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)


def _pinhole_render(blend: Path, out: Path, f_p: float, pupil_mm: float, overscan: float,
                    samples: int) -> None:
    """Blender's own perspective camera (no NeuroLens lens) at the lens's pinhole focal
    length, placed at its entrance pupil, the sensor and pixels grown by the overscan."""
    import bpy
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    cam = scene.camera
    for key in list(cam.data.keys()):
        if key.startswith("neurolens"):
            del cam.data[key]
    r = scene.render
    w, h = round(r.resolution_x * overscan), round(r.resolution_y * overscan)
    cam.data.sensor_width *= w / r.resolution_x
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    cam.data.lens = f_p
    cam.data.dof.use_dof = False
    view = cam.matrix_world.to_3x3() @ __import__("mathutils").Vector((0.0, 0.0, -1.0))
    cam.location = cam.location + view * (pupil_mm / 1000.0 / scene.unit_settings.scale_length)
    r.engine = "CYCLES"
    scene.cycles.samples = samples
    scene.cycles.device = "CPU"
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_mode = "RGBA"
    r.filepath = str(out)
    bpy.ops.render.render(write_still=True)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=32)
    args = ap.parse_args()
    from neurolens_addon.core.exr import read_exr as read_map
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        common = ("--lens", LENS, "--samples", args.samples, "--quiet")
        _cli(DEMO, *common, "--engine", "neurolens", "--out", tmp / "plate.exr")
        _cli(DEMO, "--lens", LENS, "--stmap", "undistort", "--out", tmp / "und.exr")
        meta = json.loads((tmp / "und.exr.json").read_text())
        overscan = math.ceil(meta["overscan_needed"] * 100.0) / 100.0
        _cli(DEMO, "--lens", LENS, "--stmap", "distort", "--overscan", overscan, "--out",
             tmp / "dis.exr")
        _cg_scene(tmp / "cg.blend", cg_only=True)
        _pinhole_render(tmp / "cg.blend", tmp / "cg.exr", meta["pinhole_focal_length_mm"],
                        meta["entrance_pupil_from_sensor_mm"], overscan, args.samples)
        # the check: the same CG through the lens itself
        _cli(tmp / "cg.blend", *common, "--engine", "neurolens", "--no-denoise", "--out",
             tmp / "cg_lens.exr")
        plate, cg, cg_lens = (_rgba(tmp / n) for n in ("plate.exr", "cg.exr", "cg_lens.exr"))
        und = np.stack([read_map(tmp / "und.exr")[0][c] for c in "RGA"], axis=-1)
        dis = np.stack([read_map(tmp / "dis.exr")[0][c] for c in "RGA"], axis=-1)
        flat = _sample(plate, und)
        cg_d = _sample(cg, dis)
        alpha = cg_d[..., 3:4]
        comp = cg_d[..., :4] + (1.0 - alpha) * plate
        a, b = cg_d[..., 3] > 0.5, cg_lens[..., 3] > 0.5
        iou = float((a & b).sum() / max((a | b).sum(), 1))
        IMAGES.mkdir(parents=True, exist_ok=True)
        for name, img in (("plate", plate), ("undistorted", flat), ("cg", cg),
                          ("comp", comp)):
            _png(img, IMAGES / f"stmap_{name}.png")
        print(json.dumps({"lens": LENS, "overscan": overscan,
                          "pinhole_focal_length_mm": meta["pinhole_focal_length_mm"],
                          "entrance_pupil_from_sensor_mm":
                              meta["entrance_pupil_from_sensor_mm"],
                          "silhouette_iou_against_the_lens_render": iou}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
