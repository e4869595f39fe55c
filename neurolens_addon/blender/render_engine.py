"""The NEUROLENS render engine: a bpy.types.RenderEngine running the paper's pipeline.

render(depsgraph) reads the camera's lens set-up (camera_reader.lens_setup: the one reader and
resolver the panel and Cycles use), the render settings (engine.settings), builds the frame
once (engine.frame_setup), then runs the progressive tile loop (engine.renderer) with this
engine as its sink:
  write_tile   begin_result(x, y, w, h) -> every pass's rect (foreach_set) -> update_result ->
               end_result
               (a later pass over the same tile simply replaces it: samples accumulate on the
               engine's film, the result shows their running mean);
  progress     update_progress + update_stats;
  should_stop  test_break (Esc), polled between bundles and between chunks of ray casts.
Passes: Combined, Depth (Z), Normal (XYZ), Vignetting (X) and Lens Uncertainty (X), with
ghosts on Flare (RGB: the lights' ghosts, engine.flare, also in Combined), and the data passes
the view layer asks for (Vector, Position, UV: engine.data_passes; for Vector the scene is read
one frame before and after with frame_set), added to the result with add_pass and registered
for the compositor in update_render_passes. The image
is written by Blender's own writer (write_still / Image.save_render), e.g. multilayer OpenEXR.
Errors in the camera's lens set-up end the render with a message (error_set / report).
"""

from __future__ import annotations

import time
from dataclasses import replace

import bpy
import numpy as np

from ..core.errors import NeuroLensError, debug_traceback
from ..engine.camera_rays import rigid
from ..engine.data_passes import DATA_PASSES, SWITCHES, read_motion_step
from ..engine.denoise import denoised_frame
from ..engine.diffraction import diffracted_frame
from ..engine.film import PASSES
from ..engine.flare import FLARE_PASS, frame_flare
from ..engine.frame_setup import build_renderer
from ..engine.renderer import STOP_REQUESTED
from ..engine.viewport import ViewportSession
from ..engine.settings import from_scene
from . import camera_reader

ENGINE_ID = "NEUROLENS"
#: statistics of the most recent render in this process (tests, benchmark, command line)
LAST = {"stats": None, "config": None}
#: the command line prints the set-up's messages and the engine's notes itself: the engine
#: then does not report them too (Blender prints a background render's reports)
REPORTS = {"printed_by_caller": False}
#: what this animation has reported (a message says once what holds for every frame)
_REPORTED: set = set()


#: seconds of rendering between two viewport redraws
VIEWPORT_STEP_S = 0.05
#: the viewport renders at this fraction of its pixels (interactive speed)
VIEWPORT_SCALE = 0.5


def viewport_setup(setup, region_w: int, region_h: int):
    """The set-up with its film sized for a viewport region: the camera's frame shape, fitted
    into the region at VIEWPORT_SCALE of its pixels."""
    from ..core.film import FULL_FRAME, film_from_settings
    fs = setup.settings.film
    rx, ry = setup.film.width_px, setup.film.height_px
    k = VIEWPORT_SCALE * min(region_w / rx, region_h / ry)
    w, h = max(1, int(rx * k)), max(1, int(ry * k))
    film = film_from_settings(replace(fs, resolution_x=w, resolution_y=h, percentage=100.0,
                                      border=FULL_FRAME))
    return replace(setup, film=film)


def draw_image(engine, scene, region, image) -> None:
    """Draw an (H, W, 4) image centred in the region, fitted to it, through Blender's display
    transform (GPU drawing: interface sessions only)."""
    import gpu
    from gpu_extras.presets import draw_texture_2d
    h, w = image.shape[:2]
    k = min(region.width / w, region.height / h)
    dw, dh = int(w * k), int(h * k)
    x0, y0 = (region.width - dw) // 2, (region.height - dh) // 2
    buf = gpu.types.Buffer("FLOAT", w * h * 4, np.ascontiguousarray(image, np.float32).ravel())
    tex = gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf)
    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(scene)
    draw_texture_2d(tex, (x0, y0), dw, dh)
    engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")


class NeuroLensEngineMixin:
    """The engine's behaviour, kept apart from the registered class: Blender cannot register
    a subclass of a registered RenderEngine, so a variant (a test's simulated Esc) combines
    this mixin with bpy.types.RenderEngine itself."""

    _layer = ""

    # -- sink for renderer.FrameRenderer

    def should_stop(self) -> bool:
        return bool(self.test_break()) or STOP_REQUESTED.is_set()

    def write_tile(self, tile, passes: dict):
        result = self.begin_result(tile.x, tile.y, tile.w, tile.h, layer=self._layer)
        layer = result.layers[0]
        for p in layer.passes:
            data = passes.get(p.name)
            if data is not None:           # foreach_set: far faster than `p.rect = data`
                p.rect.foreach_set(np.ascontiguousarray(data, dtype=np.float32).ravel())
        self.update_result(result)
        self.end_result(result)

    def _write_combined(self, combined) -> None:
        """The post-processed (W H, 4) Combined into the frame's render result, in place
        (get_result): every other pass stays as the tiles wrote it, and no second frame-sized
        result is made (begin_result over the frame would allocate all twenty channels)."""
        self._write_pass("Combined", combined)

    def _write_pass(self, name: str, data) -> None:
        """A whole-frame pass (W H, channels) into the render result, in place (as
        _write_combined)."""
        result = self.get_result()
        layer = next((ly for ly in result.layers if ly.name == self._layer), result.layers[0])
        target = layer.passes.find_by_name(name, self.active_view_get()) \
            or layer.passes[name]                  # the view being rendered (stereo: one each)
        target.rect.foreach_set(np.ascontiguousarray(data, dtype=np.float32).ravel())

    def _motion_steps(self, depsgraph, camera):
        """The scene one frame before and one after (data_passes.MotionStep: the camera and
        every object's vertices), read by moving the render's depsgraph there and back, as
        Cycles reads motion; None when Esc was pressed meanwhile."""
        scene = depsgraph.scene
        frame, sub = scene.frame_current, scene.frame_subframe
        steps = []
        try:
            for offset in (-1, 1):
                self.frame_set(frame + offset, sub)
                if self.test_break():
                    return None
                matrix = rigid(camera.evaluated_get(depsgraph).matrix_world)
                steps.append(read_motion_step(depsgraph, matrix))
        finally:
            self.frame_set(frame, sub)
        return steps

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
        data_passes = data_passes_of(depsgraph.view_layer)
        for name, channels, chan_id in DATA_PASSES:
            if name in data_passes:
                self.add_pass(name, channels, chan_id, layer=self._layer)
        camera = self.camera_override or scene.camera
        try:
            settings = from_scene(scene)
            setup = camera_reader.lens_setup(camera, scene, depsgraph)
            steps = None
            if "Vector" in data_passes:
                steps = self._motion_steps(depsgraph, camera)
                if steps is None:               # Esc while the other frames were read
                    return
            renderer, config, materials = build_renderer(scene, depsgraph, camera, setup,
                                                         settings, self,
                                                         data_passes=data_passes,
                                                         motion_steps=steps)
        except (NeuroLensError, ValueError) as e:
            self._fail(str(e))
            return
        except Exception as e:  # noqa: BLE001 - a bug must end the render, not Blender
            debug_traceback()
            self._fail(f"NeuroLens could not set up the render ({e.__class__.__name__}: {e})")
            return
        LAST["config"] = config
        if setup.ghosts is not None:            # the lights' flare, a pass of its own
            self.add_pass(*FLARE_PASS, layer=self._layer)
        if not self.is_animation or scene.frame_current == scene.frame_start:
            _REPORTED.clear()
        for level, text in config.messages:     # the set-up's, with the panel's levels
            self._say(level, text)
        for note in renderer.stats.notes:
            self._say("WARNING", note)
        try:
            stats = renderer.run()
        except Exception as e:          # anything unexpected: say it, keep what is rendered
            self._fail(f"NeuroLens render failed: {e.__class__.__name__}: {e}")
            debug_traceback()
            return
        finally:
            materials.close()
        passes = None
        if settings.denoise and not stats.cancelled:
            t0 = time.perf_counter()
            passes = denoised_frame(renderer.film, stats.notes)
            if passes is not None:      # denoised: the summary line says so, with its time
                stats.add_time("denoise", time.perf_counter() - t0)
        flare = None
        if not stats.cancelled:
            t0 = time.perf_counter()
            made = frame_flare(renderer)
            if made is not None:
                # the lights' ghosts (light tracing), added to the finished frame and kept
                # as their own pass; diffracted with it (their light passes the stop too)
                flare = made[0]
                if passes is None:
                    passes = {"Combined": renderer.film.frame("Combined").copy()}
                passes["Combined"][:, :3] += flare
                stats.add_time("flare", time.perf_counter() - t0)
        if setup.diffraction and not stats.cancelled:
            # the stop's Fraunhofer pattern over the finished (denoised) frame
            t0 = time.perf_counter()
            passes = diffracted_frame(renderer.film, setup.diffraction_kernel, passes)
            stats.add_time("diffraction", time.perf_counter() - t0)
        if passes is not None:
            self._write_combined(passes["Combined"])
            del passes
        if flare is not None:
            self._write_pass("Flare", flare)
        for note in materials.notes:            # what the engine does not shade, once
            if note not in stats.notes:
                stats.notes.append(note)
                self._say("WARNING", note)
        LAST["stats"] = stats
        LAST["recorded"] = renderer.shader.caster.recorded
        self.update_stats("NeuroLens", ("Cancelled | " if stats.cancelled else "Done | ")
                          + stats.summary())

    # -- the rendered viewport (engine/viewport.py): refines through the real lens, restarts
    # on any change of lens, camera, viewport size or scene

    def _viewport_session(self):
        session = getattr(self, "_session", None)
        if session is None:
            session = self._session = ViewportSession()
            self._scene_changes = 0
        return session

    def view_update(self, context, depsgraph):
        session = self._viewport_session()
        scene = depsgraph.scene
        camera = scene.camera
        region = context.region
        if camera is None or region is None:
            return
        if any(not (isinstance(u.id, bpy.types.Object) and u.id.type == "CAMERA")
               for u in depsgraph.updates):
            self._scene_changes += 1
        try:
            setup = viewport_setup(camera_reader.lens_setup(camera, scene, depsgraph),
                                   region.width, region.height)
            settings = replace(from_scene(scene), denoise=False, tile_order="PROGRESSIVE")
        except (NeuroLensError, ValueError) as e:
            self.update_stats("NeuroLens", f"Viewport: {e}")
            return
        key = (setup.key, tuple(map(tuple, camera.matrix_world)), region.width, region.height,
               self._scene_changes)
        try:
            session.update(key, lambda sink: build_renderer(scene, depsgraph, camera, setup,
                                                            settings, sink, viewport=True))
        except (NeuroLensError, ValueError) as e:
            self.update_stats("NeuroLens", f"Viewport: {e}")

    def view_draw(self, context, depsgraph):
        session = self._viewport_session()
        try:
            done = session.step(VIEWPORT_STEP_S)
            image = session.image()
            if image is None:
                return
            draw_image(self, depsgraph.scene, context.region, image)
        except Exception as e:  # noqa: BLE001 - a drawing failure must not break the viewport
            debug_traceback()
            self.update_stats("NeuroLens", f"Viewport: {e.__class__.__name__}: {e}")
            return
        if not done:
            self.tag_redraw()

    def _say(self, level: str, text: str) -> None:
        """Report a message once an animation (unless the caller prints it)."""
        if REPORTS["printed_by_caller"] or (level, text) in _REPORTED:
            return
        _REPORTED.add((level, text))
        self.report({level}, text)

    def _fail(self, message: str):
        self.error_set(message)
        self.report({"ERROR"}, message)
        LAST["stats"] = None
        LAST["error"] = message

    def update_render_passes(self, scene=None, renderlayer=None):
        kinds = {"Combined": "COLOR", "Normal": "VECTOR", "Noisy Image": "COLOR",
                 "Flare": "COLOR",
                 "Denoising Albedo": "COLOR", "Denoising Normal": "VECTOR"}
        for name, channels, chan_id in PASSES + (FLARE_PASS,):
            self.register_pass(scene, renderlayer, name, channels, chan_id,
                               kinds.get(name, "VALUE"))
        asked = data_passes_of(renderlayer)
        for name, channels, chan_id in DATA_PASSES:
            if name in asked:
                self.register_pass(scene, renderlayer, name, channels, chan_id, "VECTOR")


def data_passes_of(view_layer) -> tuple:
    """The data passes (Vector, Position, UV) a view layer's switches ask for."""
    return tuple(name for name, _c, _i in DATA_PASSES
                 if getattr(view_layer, SWITCHES[name], False))


class NeuroLensRenderEngine(NeuroLensEngineMixin, bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "NeuroLens"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_shading_nodes_custom = False
    bl_use_eevee_viewport = True
