"""The exact lens inside Cycles: camera rays per second of the generated OSL camera, for every
preset (the 'exact trace, OSL inside Cycles' entry of the speed-accuracy comparison).

Each preset's exact OSL camera (neurolens_addon.cycles, set by blender.cycles_camera) renders
an empty scene (a plain world: every camera ray goes straight to the background, so the camera
is nearly all the work) at RES and SPP on the CPU, against Blender's perspective camera in the
same run. Net time = render time - a 1-sample render's (scene sync and OSL compilation);
OSL camera rays/s = camera rays / (net exact - net perspective), the rate at which Cycles runs
our lens on top of what any camera costs.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from .common import md_table, preset_paths

W, H = 160, 120
SPP = 64


def _seconds(scene, spp, path):
    import bpy
    scene.cycles.samples = spp
    scene.render.filepath = path
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    return time.perf_counter() - t0


def run() -> tuple[str, dict]:
    import bpy

    from neurolens_addon.blender.camera_values import film_settings
    from neurolens_addon.blender.cycles_camera import (apply_lens_camera, clear_lens_camera,
                                                       ensure_osl_query_path)
    from neurolens_addon.core.film import film_from_settings
    from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.cycles import CameraSpec
    ensure_osl_query_path()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = W, H
    scene.render.resolution_percentage = 100
    world = bpy.data.worlds.new("w")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[0].default_value = (0.5, 0.5, 0.5, 1.0)
    scene.world = world
    data = bpy.data.cameras.new("cam")
    cam = bpy.data.objects.new("cam", data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    figs, rows = {}, []
    rays = W * H * SPP
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "o.exr")
        clear_lens_camera(data)
        _seconds(scene, 1, path)
        persp = _seconds(scene, SPP, path) - _seconds(scene, 1, path)
        for lens_path in preset_paths():
            lens = load_lens(lens_path)
            w, h = film_from_settings(film_settings(data, scene)).size_mm
            focus = max(2000.0, closest_focus_mm(lens))      # (a long telephoto: its closest)
            spec = CameraSpec("exact", lens=lens, sensor_z_mm=focus_sensor_z(lens, focus),
                              f_number=lens.f_number, sensor_width_mm=w, sensor_height_mm=h)
            apply_lens_camera(data, spec)
            _seconds(scene, 1, path)                                   # compile once
            net = _seconds(scene, SPP, path) - _seconds(scene, 1, path)
            extra = max(net - persp, 1e-9)
            figs[lens_path.stem] = {"net_s": net, "perspective_net_s": persp,
                                    "osl_camera_rays_per_s": rays / extra}
            rows.append([lens_path.stem, f"{net:.2f}", f"{persp:.2f}",
                         f"{rays / extra / 1e6:.2f}"])
            print(f"  {lens_path.stem}: {rays / extra / 1e6:.2f} M camera rays/s", flush=True)
            clear_lens_camera(data)
    text = "\n".join([
        "## The exact lens inside Cycles (OSL camera rays per second)",
        "",
        f"Empty scene, {W}x{H}, {SPP} spp, CPU; net = minus a 1-sample render (sync, OSL "
        "compilation). Rate = camera rays / (net exact - net perspective).",
        "",
        md_table(["preset", "exact net s", "perspective net s", "OSL M camera rays/s"], rows)])
    return text, figs
