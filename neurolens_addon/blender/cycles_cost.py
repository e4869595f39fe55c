"""What a camera ray costs in Cycles through the exact and the learned OSL camera of a lens
model, measured on this machine in one run (model.json "costs"."cycles", where model choice,
neural.choice, reads it; benchmarks/model_costs.py records it for the shipped models, the
engine's figure beside it from trainer.cost).

Cost: wall-clock microseconds per camera ray, all of Cycles' threads: the extra time per
camera ray of the exact and the learned camera over Blender's perspective camera, rendering
SIZE at SAMPLES samples against an empty sky (no geometry: the camera shader is the work),
each net of a one-sample render (scene sync and OSL compilation), best of REPEATS,
interleaved:
    cost = ((t_lens - t1_lens) - (t_persp - t1_persp)) / (W H (samples - 1)),
floored at COST_FLOOR_US (the exact shader of a short lens is within the noise of nothing).
The lens is focused where the model is measured (core.focus.evaluation_focus_mm).
It renders in this process's bpy: the session's file is replaced by an empty factory scene.
"""

from __future__ import annotations

import math
import time

SIZE = (160, 120)
SAMPLES = 64
REPEATS = 3
COST_FLOOR_US = 0.001


def _empty_cycles_scene(width: int, height: int):
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    world = bpy.data.worlds.new("sky")
    scene.world = world
    world.node_tree.nodes["Background"].inputs[0].default_value = (0.5, 0.6, 0.8, 1.0)
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    cam = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene, cam


def render_seconds(scene, samples: int, path: str) -> float:
    """Wall-clock seconds of one render of `scene` at `samples` samples (not written)."""
    import bpy
    scene.cycles.samples = samples
    scene.render.filepath = path
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    return time.perf_counter() - t0


def use_camera(camera_data, spec) -> None:
    """Make the camera run `spec`'s OSL camera, or Blender's perspective camera for None."""
    from .cycles_camera import apply_lens_camera, clear_lens_camera
    if spec is None:
        clear_lens_camera(camera_data)
    else:
        apply_lens_camera(camera_data, spec)


def cycles_cost(model_dir, lens, size=SIZE, samples: int = SAMPLES,
                repeats: int = REPEATS) -> dict:
    """{"exact_us", "learned_us"} of Cycles' OSL cameras (module docstring); a model Cycles
    cannot render (a learned anamorphic lens) raises its CameraSpecError."""
    import tempfile
    from pathlib import Path

    from ..core.focus import evaluation_focus_mm, focus_sensor_z
    from ..cycles import CameraSpec
    from ..neural.modelfile import read_header
    from .cycles_camera import ensure_osl_query_path

    ensure_osl_query_path()
    z_s = focus_sensor_z(lens, evaluation_focus_mm(lens, read_header(model_dir).sensor_z_range))
    width, height = size
    scene, cam = _empty_cycles_scene(width, height)
    sensor_w = 36.0                              # the full-frame film the scene's camera has
    specs = {m: CameraSpec(m, lens=lens, model_dir=str(model_dir), sensor_z_mm=z_s,
                           sensor_width_mm=sensor_w, sensor_height_mm=sensor_w * height / width)
             for m in ("exact", "learned")}

    names = ("perspective", "exact", "learned")
    net = {n: math.inf for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "cost.exr")
        for n in names:                          # first sync, first OSL compilation
            use_camera(cam.data, specs.get(n))
            render_seconds(scene, 1, path)
        for _ in range(repeats):
            for n in names:
                use_camera(cam.data, specs.get(n))
                one = render_seconds(scene, 1, path)
                net[n] = min(net[n], render_seconds(scene, samples, path) - one)
    rays = width * height * (samples - 1)
    return {f"{m}_us": max(COST_FLOOR_US, 1e6 * (net[m] - net["perspective"]) / rays)
            for m in ("exact", "learned")}
