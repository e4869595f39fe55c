"""The live viewport's update loop, headless: what it would draw after N steps."""

from __future__ import annotations


import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.slow          # engine renders

from neurolens_addon.blender.camera_reader import lens_setup  # noqa: E402
from neurolens_addon.engine.frame_setup import build_renderer  # noqa: E402
from neurolens_addon.engine.settings import RenderSettings  # noqa: E402
from neurolens_addon.engine.viewport import ViewportSession  # noqa: E402
from testdata import engine_scenes as scenes  # noqa: E402


class _Sink:
    def write_tile(self, tile, passes):
        pass

    def progress(self, fraction, text):
        pass

    def should_stop(self):
        return False


def _state(focus=2.0):
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 40, 24
    scene.render.resolution_percentage = 100
    cam = scene.camera
    cam.data.dof.focus_distance = focus
    dg = bpy.context.evaluated_depsgraph_get()
    setup = lens_setup(cam, scene, dg)
    settings = RenderSettings(samples=8, tile_size=16, max_bundle_rays=2048, denoise=False)
    key = (setup.key, tuple(map(tuple, cam.matrix_world)), 40, 24)
    return key, (lambda sink: build_renderer(scene, dg, cam, setup, settings, sink))


def test_01_refines_to_the_render_and_restarts_on_a_change():
    """Small time budgets refine the image step by step; once complete it equals a render of
    the same samples exactly; the same state does not restart, a new focus does (from zero
    samples, and the image changes)."""
    scenes.reset()
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.0, 0.0, -2.0))
    scenes.checker_plane(-3.0, 4.0, 8)
    scenes.camera(focus=2.0, fstop=2.0, sensor_width=24.0, model="exact")
    session = ViewportSession()
    key, build = _state()
    assert session.update(key, build) and session.restarts == 1
    assert not session.step(1e-6) and 0 < session.samples_done < 40 * 24 * 8
    assert not session.update(key, build)                       # same state: keeps going
    steps = 1
    while not session.step(0.01):
        steps += 1
    assert steps > 2 and session.samples_done == 40 * 24 * 8
    shown = session.image()
    renderer, _setup, materials = build(_Sink())
    renderer.run()
    materials.close()
    np.testing.assert_array_equal(shown, renderer.film.image("Combined"))
    key2, build2 = _state(focus=0.8)
    assert session.update(key2, build2) and session.restarts == 2
    assert session.samples_done == 0
    while not session.step(0.05):
        pass
    assert np.abs(session.image() - shown).max() > 0.05          # refocused: another image
    session.close()
    assert session.image() is None


def test_02_the_viewport_film_keeps_the_camera_frame_fitted_to_the_region():
    """viewport_setup: the camera's frame shape (and sensor extent) at half the pixels of the
    largest fit into the region; the lens set-up is otherwise the one the render uses."""
    from neurolens_addon.blender.render_engine import VIEWPORT_SCALE, viewport_setup
    scenes.reset()
    scenes.camera(focus=2.0, fstop=2.0, sensor_width=36.0, model="exact")
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = 1920, 1080
    setup = lens_setup(scene.camera, scene, bpy.context.evaluated_depsgraph_get())
    vp = viewport_setup(setup, 1000, 1000)
    assert (vp.film.width_px, vp.film.height_px) == (int(1920 * VIEWPORT_SCALE * 1000 / 1920),
                                                     int(1080 * VIEWPORT_SCALE * 1000 / 1920))
    assert vp.film.width_mm == pytest.approx(setup.film.width_mm)
    assert vp.film.height_mm == pytest.approx(setup.film.height_mm, rel=2e-3)   # whole pixels
    assert vp.sensor_z_mm == setup.sensor_z_mm and vp.lens is setup.lens


def test_03_the_viewport_shows_the_lamps_flare():
    """A point lamp in the dark with ghosts on: camera rays never meet it, so the film stays
    black, and the viewport shows the lamp's flare (engine.flare, traced once at
    PREVIEW_FLARE_SAMPLES samples' worth of rays): the image is that flare layer."""
    from neurolens_addon.engine.flare import frame_flare
    from neurolens_addon.engine.viewport import PREVIEW_FLARE_SAMPLES
    from testdata import flare_scenes
    scenes.reset()
    flare_scenes.point_lamp()
    bpy.context.scene.render.engine = "NEUROLENS"
    session = ViewportSession()
    key, build = _state(focus=6.0)
    session.update(key, build)
    while not session.step(0.05):
        pass
    shown = session.image()
    assert session.renderer.film.image("Combined")[..., :3].max() == 0.0
    renderer, _setup, materials = build(_Sink())
    flare, _layer = frame_flare(renderer, PREVIEW_FLARE_SAMPLES)
    materials.close()
    assert flare.sum() > 0
    np.testing.assert_allclose(shown[..., :3], flare.reshape(24, 40, 3), rtol=1e-5, atol=1e-7)
    session.close()
