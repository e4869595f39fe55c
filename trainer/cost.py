"""What a camera ray costs through a learned model and through the exact trace, per renderer,
measured on this machine in one run (`python -m trainer cost MODEL --lens LENS --record`
stores it in model.json's "costs", where model choice, neural.choice, reads it).

Cost: wall-clock microseconds per camera ray, all the renderer's threads.
* neurolens (the engine's lens stage): COST_RAYS camera rays of the model's domain at its
  evaluation focus (trainer.evaluate.camera_rays_at_focus) in one batch, as the engine sends a
  bundle, through core.trace.trace (the compiled trace where numba is there, as the engine
  runs it) and through LearnedLens.trace_from_sensor (onnxruntime), best of REPEATS after a
  first call (compilation, session start).
* cycles: the extra time per camera ray of the exact and the learned OSL camera over
  Blender's perspective camera, rendering CYCLES_SIZE at CYCLES_SAMPLES samples against an
  empty sky (no geometry: the camera shader is the work), each net of a one-sample render
  (scene sync and OSL compilation), best of REPEATS, interleaved:
      cost = ((t_lens - t1_lens) - (t_persp - t1_persp)) / (W H samples),
  floored at COST_FLOOR_US (the exact shader of a short lens is within the noise of nothing).
"""

from __future__ import annotations

import math
import os
import platform
import sys
import time
from datetime import date

COST_RAYS = 1 << 16
REPEATS = 3
CYCLES_SIZE = (160, 120)
CYCLES_SAMPLES = 64
COST_FLOOR_US = 0.001
RENDERERS = ("neurolens", "cycles")


def machine() -> str:
    """The machine a cost was measured on, in words (its ratios travel; its values less)."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical cores"


def engine_cost(model_dir, lens, rays: int = COST_RAYS, repeats: int = REPEATS) -> dict:
    """{"exact_us", "learned_us", "provider"} of the engine's lens stage (module docstring)."""
    from neurolens_addon.core.trace import trace
    from neurolens_addon.neural.model import LearnedLens

    from .evaluate import camera_rays_at_focus, domain_of, evaluation_focus_mm

    model = LearnedLens.load(model_dir, lens=lens)
    domain = domain_of(model.meta)
    batch, z_s = camera_rays_at_focus(lens, domain, rays, evaluation_focus_mm(lens, domain), 0)

    def exact():
        trace(lens, batch, from_sensor=True, stop_radius=domain.stop_radius_mm, sensor_z=z_s)

    def learned():
        model.trace_from_sensor(batch, z_s, stop_radius=domain.stop_radius_mm)

    best = {}
    for name, run in (("exact", exact), ("learned", learned)):
        run()                                    # compilation, session start: not a ray's cost
        best[name] = math.inf
    for _ in range(repeats):
        for name, run in (("exact", exact), ("learned", learned)):
            t0 = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - t0)
    return {"exact_us": 1e6 * best["exact"] / rays, "learned_us": 1e6 * best["learned"] / rays,
            "provider": model.provider}


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


def _render_seconds(scene, samples: int, path: str) -> float:
    import bpy
    scene.cycles.samples = samples
    scene.render.filepath = path
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    return time.perf_counter() - t0


def cycles_cost(model_dir, lens, size=CYCLES_SIZE, samples: int = CYCLES_SAMPLES,
                repeats: int = REPEATS) -> dict:
    """{"exact_us", "learned_us"} of Cycles' OSL cameras (module docstring). It renders in
    this process's bpy: the session's file is replaced by an empty factory scene."""
    import tempfile
    from pathlib import Path

    from neurolens_addon.blender.cycles_camera import (
        apply_lens_camera,
        clear_lens_camera,
        ensure_osl_query_path,
    )
    from neurolens_addon.cycles import CameraSpec

    from .evaluate import domain_of, evaluation_focus_mm
    from neurolens_addon.core.focus import focus_sensor_z
    from neurolens_addon.neural.modelfile import read_model_json

    ensure_osl_query_path()
    _d, meta, _g, _f = read_model_json(model_dir)
    domain = domain_of(meta)
    width, height = size
    scene, cam = _empty_cycles_scene(width, height)
    sensor_w = 36.0                              # the full-frame film the scene's camera has
    z_s = focus_sensor_z(lens, evaluation_focus_mm(lens, domain))
    specs = {m: CameraSpec(m, lens=lens, model_dir=str(model_dir), sensor_z_mm=z_s,
                           sensor_width_mm=sensor_w, sensor_height_mm=sensor_w * height / width)
             for m in ("exact", "learned")}

    def use(name):
        if name == "perspective":
            clear_lens_camera(cam.data)
        else:
            apply_lens_camera(cam.data, specs[name])

    names = ("perspective", "exact", "learned")
    net = {n: math.inf for n in names}
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "cost.exr")
        for n in names:                          # first sync, first OSL compilation
            use(n)
            _render_seconds(scene, 1, path)
        for _ in range(repeats):
            for n in names:
                use(n)
                one = _render_seconds(scene, 1, path)
                net[n] = min(net[n], _render_seconds(scene, samples, path) - one)
    rays = width * height * (samples - 1)
    return {f"{m}_us": max(COST_FLOOR_US, 1e6 * (net[m] - net["perspective"]) / rays)
            for m in ("exact", "learned")}


def cycles_missing() -> str | None:
    """Why this Python cannot measure Cycles (one line), or None."""
    import importlib.util
    if importlib.util.find_spec("bpy") is None:
        return (f"measuring Cycles needs the bpy module, which this Python ({sys.executable}) "
                "does not have")
    return None


def measure(model_dir, lens, renderers=RENDERERS, log=None) -> dict:
    """model.json's "costs" for the renderers asked (module docstring), each stamped with the
    date and machine. Cycles where this Python has no bpy or Cycles cannot render the model
    (a learned anamorphic lens): an error, or with `log`, said there and left out."""
    from neurolens_addon.core.errors import NeuroLensError
    stamp = {"date": date.today().isoformat(), "machine": machine()}
    out = {}
    if "neurolens" in renderers:
        out["neurolens"] = {**engine_cost(model_dir, lens), **stamp}
    if "cycles" in renderers:
        try:
            why = cycles_missing()
            if why is not None:
                raise NeuroLensError(why)
            out["cycles"] = {**cycles_cost(model_dir, lens), **stamp}
        except NeuroLensError as exc:       # no bpy, or a model Cycles cannot render
            if log is None:
                raise
            log(f"not measured in Cycles: {exc}")
    return out


def record_costs(model_dir, costs: dict) -> None:
    """Store the renderers' figures of `costs` in the model's model.json ("costs"; the other
    renderers' kept, with their own stamps), where model choice reads them; nothing measured,
    nothing written (a model.json rewritten would only make the add-on choose again)."""
    if not costs:
        return
    from .evaluate import update_model_json
    update_model_json(model_dir, lambda meta: meta.update(
        costs={**(meta.get("costs") or {}), **costs}))


def summary(costs: dict) -> str:
    parts = []
    for r in RENDERERS:
        c = costs.get(r)
        if c:
            parts.append(f"{r}: exact {c['exact_us']:.3g} us, learned {c['learned_us']:.3g} us "
                         f"a camera ray ({c['learned_us'] / c['exact_us']:.2f}x)")
    return "; ".join(parts) or "nothing measured"
