"""The NEUROLENS render engine: a bpy.types.RenderEngine running the paper's pipeline.

render(depsgraph) reads the camera's lens (lens_setup), the render settings (settings), builds
the camera-ray generator, the scene caster, materials, lights and world once, then runs the
progressive tile loop (renderer) with this engine as its sink:
  write_tile   begin_result(x, y, w, h) -> every pass's rect (foreach_set) -> update_result ->
               end_result
               (a later pass over the same tile simply replaces it: samples accumulate on the
               engine's film, the result shows their running mean);
  progress     update_progress + update_stats;
  should_stop  test_break (Esc), polled between bundles and between chunks of ray casts.
Passes: Combined, Depth (Z), Normal (XYZ), Vignetting (X) and Lens Uncertainty (X), added to
the result with add_pass and registered for the compositor in update_render_passes. The image
is written by Blender's own writer (write_still / Image.save_render), e.g. multilayer OpenEXR.
Errors in the camera's lens set-up end the render with a message (error_set / report).
"""

from __future__ import annotations

import traceback

import bpy
import numpy as np

from ..core.errors import NeuroLensError
from .camera_rays import CameraRayGenerator, film_geometry, make_evaluator
from .film import PASSES, Film
from .lens_setup import _mm_per_unit, lens_from_camera
from .lights import scene_lights, scene_world
from .materials import SceneMaterials
from .renderer import FrameRenderer, RenderStats
from .scene_cast import SceneCaster
from .settings import from_scene
from .shading import Shader

ENGINE_ID = "NEUROLENS"
#: statistics of the most recent render in this process (tests, benchmark, command line)
LAST = {"stats": None, "config": None}


def frame_size(scene) -> tuple[int, int]:
    r = scene.render
    pct = r.resolution_percentage / 100.0
    return max(1, int(r.resolution_x * pct)), max(1, int(r.resolution_y * pct))


def build_renderer(scene, depsgraph, camera_obj, settings, sink, *, width=None, height=None):
    """Everything a frame needs, set up once: (FrameRenderer, LensConfig, SceneMaterials)."""
    import time
    t0 = time.perf_counter()
    stats = RenderStats()
    config = lens_from_camera(camera_obj, scene)
    stats.notes.extend(config.notes)
    W, H = (width, height) if width else frame_size(scene)
    cam_eval = camera_obj.evaluated_get(depsgraph)
    cd = cam_eval.data
    film_geo = film_geometry(W, H, cd.sensor_width, cd.sensor_height, cd.sensor_fit,
                             cd.shift_x, cd.shift_y)
    evaluator = make_evaluator(config, providers=settings.providers(),
                               threads=settings.threads or None)
    mm = _mm_per_unit(scene)
    gen = CameraRayGenerator(evaluator, film_geo, cam_eval.matrix_world, mm, seed=settings.seed,
                             wavelength_method=settings.wavelength_method,
                             dispersion=settings.dispersion)
    if evaluator.learned is not None:
        dom = evaluator.learned.domain
        if film_geo.radius_mm > float(dom["film_radius_mm"]) * 1.0001:
            stats.notes.append(f"the film's half diagonal {film_geo.radius_mm:.1f} mm exceeds the "
                               f"learned lens's domain ({float(dom['film_radius_mm']):.1f} mm): "
                               "its corners stay dark")
    caster = SceneCaster(scene, depsgraph, should_stop=sink.should_stop)
    materials = SceneMaterials(depsgraph)
    world = scene_world(scene, stats.notes)
    shader = Shader(caster, materials, scene_lights(depsgraph), world, bounces=settings.bounces,
                    seed=settings.seed, camera_position=gen.position, view_axis=gen.view_axis,
                    transparent=scene.render.film_transparent)
    film = Film(W, H, transparent=scene.render.film_transparent)
    stats.lens = config.describe()
    stats.provider = evaluator.provider
    stats.seconds["setup"] = time.perf_counter() - t0
    return FrameRenderer(gen, shader, film, settings, sink, stats), config, materials


class NeuroLensEngineMixin:
    """The engine's behaviour, kept apart from the registered class: Blender cannot register
    a subclass of a registered RenderEngine, so a variant (a test's simulated Esc) combines
    this mixin with bpy.types.RenderEngine itself."""

    _layer = ""

    # -- sink for renderer.FrameRenderer

    def should_stop(self) -> bool:
        return bool(self.test_break())

    def write_tile(self, tile, passes: dict):
        result = self.begin_result(tile.x, tile.y, tile.w, tile.h, layer=self._layer)
        layer = result.layers[0]
        for p in layer.passes:
            data = passes.get(p.name)
            if data is not None:           # foreach_set: ~100x faster than `p.rect = data`
                p.rect.foreach_set(np.ascontiguousarray(data, dtype=np.float32).ravel())
        self.update_result(result)
        self.end_result(result)

    def progress(self, fraction: float, text: str):
        self.update_progress(float(fraction))
        self.update_stats("NeuroLens", text)

    # -- Blender's entry points

    def render(self, depsgraph):
        scene = depsgraph.scene
        if self.is_preview:
            return
        self._layer = depsgraph.view_layer.name
        for name, channels, chan_id in PASSES[1:]:
            self.add_pass(name, channels, chan_id, layer=self._layer)
        camera = self.camera_override or scene.camera
        try:
            settings = from_scene(scene)
            renderer, config, materials = build_renderer(scene, depsgraph, camera, settings,
                                                         self)
        except (NeuroLensError, ValueError) as e:
            self._fail(str(e))
            return
        LAST["config"] = config
        for note in renderer.stats.notes:
            self.report({"WARNING"}, note)
        try:
            stats = renderer.run()
        except Exception as e:          # anything unexpected: say it, keep what is rendered
            self._fail(f"NeuroLens render failed: {e}")
            traceback.print_exc()
            return
        finally:
            materials.close()
        stats.notes.extend(n for n in materials.notes if n not in stats.notes)
        LAST["stats"] = stats
        LAST["recorded"] = renderer.shader.caster.recorded
        self.update_stats("NeuroLens", ("Cancelled | " if stats.cancelled else "Done | ")
                          + stats.summary())

    def _fail(self, message: str):
        self.error_set(message)
        self.report({"ERROR"}, message)
        LAST["stats"] = None
        LAST["error"] = message

    def update_render_passes(self, scene=None, renderlayer=None):
        kinds = {"Combined": "COLOR", "Normal": "VECTOR"}
        for name, channels, chan_id in PASSES:
            self.register_pass(scene, renderlayer, name, channels, chan_id,
                               kinds.get(name, "VALUE"))


class NeuroLensRenderEngine(NeuroLensEngineMixin, bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "NeuroLens"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_shading_nodes_custom = False
    bl_use_eevee_viewport = True
