"""The engine's data passes through the real lens: Vector (motion), Position and UV.

The Vector pass is checked against the frames themselves: a small glowing ball, rendered at
the frames before, at and after the one with the pass, through the fisheye (strong
distortion) far off the axis; its image's centroid moves from frame to frame by what the pass
says at the ball (Cycles' convention: prev - now, now - next, x right, y up), where a pinhole
of the same focal length would be pixels off. The camera's own motion counts the same way.
Position and UV are checked against the plane they see (its depth, its UVs linear in x, y).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from testdata import engine_scenes as scenes

bpy = scenes.bpy
ROOT = Path(__file__).resolve().parents[2]
W, H = 192, 128


def _data_passes(*names):
    for vl in bpy.context.scene.view_layers:
        for n in names:
            setattr(vl, f"use_pass_{n}", True)


def _linear(ob, path, frames):
    """Keyframe `path` of `ob` at each (frame, value), linear between them."""
    for frame, value in frames:
        setattr(ob, path, value)
        ob.keyframe_insert(path, frame=frame)
    action = ob.animation_data.action
    curves = getattr(action, "fcurves", None)
    if curves is None:                                  # Blender 5's layered actions
        curves = [c for layer in action.layers for strip in layer.strips
                  for bag in strip.channelbags for c in bag.fcurves]
    for c in curves:
        for k in c.keyframe_points:
            k.interpolation = "LINEAR"


def _centroid(img):
    """(x right, y up) pixel position (centres at i + 0.5) of the bright blob of an image whose
    row 0 is the top."""
    w = np.where(img > 0.2 * img.max(), img, 0.0)
    rows, cols = np.indices(img.shape)
    x = (w * (cols + 0.5)).sum() / w.sum()
    y = (w * (img.shape[0] - rows - 0.5)).sum() / w.sum()
    return np.array([x, y])


def _render_frames(tmp_path, frames=(9, 10, 11), samples=16):
    """Combined luminance of each frame, and the data passes of the middle one."""
    scene = bpy.context.scene
    out = {}
    for f in frames:
        scene.frame_set(f)
        ch = scenes.render(tmp_path / f"f{f}.exr", W, H, samples)
        out[f] = ch
    return out


def _steps_match_the_pass(tmp_path, label, samples=16):
    """Render the frames before, at and after; the subject moves (over 5 px a step) and the
    pass at it gives both steps within 0.35 px. The measured steps."""
    measured, vec, _c = _check_vectors(_render_frames(tmp_path, samples=samples))
    print(f"{label}: steps {measured.round(3)}, pass {vec.round(3)}")
    assert np.abs(measured).max() > 5.0                     # it moves
    assert np.abs(vec - measured).max() < 0.35, (vec, measured)
    return measured


def _ball_scene(lens, sensor_width, camera_frames=None, ball_frames=None, focus=2.0,
                fstop=8.0):
    scenes.reset()
    ball = scenes.emitter_sphere((0.0, 0.0, -2.0), radius=0.03, strength=20.0)
    if ball_frames:
        _linear(ball, "location", ball_frames)
    cam = scenes.camera(lens=lens, focus=focus, fstop=fstop, sensor_width=sensor_width)
    cam.data.sensor_fit = "HORIZONTAL"
    if camera_frames:
        _linear(cam, "rotation_euler", camera_frames)
    _data_passes("vector", "position", "uv")
    return ball, cam


def _check_vectors(chs, centre_frame=10):
    """(measured centroid steps before/after, the pass's mean vector at the ball)."""
    lum = {f: ch["Combined.R"] + ch["Combined.G"] + ch["Combined.B"] for f, ch in chs.items()}
    c = {f: _centroid(v) for f, v in lum.items()}
    ch = chs[centre_frame]
    at = lum[centre_frame] > 0.2 * lum[centre_frame].max()
    wgt = lum[centre_frame][at]
    vec = np.array([(ch[f"Vector.{k}"][at] * wgt).sum() / wgt.sum() for k in "XYZW"])
    measured = np.concatenate([c[centre_frame - 1] - c[centre_frame],
                               c[centre_frame] - c[centre_frame + 1]])
    return measured, vec, c


@pytest.mark.slow
def test_01_a_moving_ball_moves_on_the_film_as_the_vector_pass_says(tmp_path):
    """The ball, 2 m away at about 55 degrees off the axis, moves 0.25 m a frame across and
    in depth: its image (fisheye, 24 mm film) moves about ten pixels a frame on a curve; the pass at
    the ball gives both steps within 0.35 px, where the pinhole of the lens's focal length,
    from the same entrance pupil, is more than 3 px off."""
    _ball_scene("fisheye_f4", 24.0,
                ball_frames=[(9, (-2.45, 1.2, -1.6)), (10, (-2.2, 1.3, -1.85)),
                             (11, (-1.95, 1.4, -2.1))])
    measured = _steps_match_the_pass(tmp_path, "fisheye, the ball moving")
    # the pinhole's vectors for the ball's centre (same focal length, same pupil)
    from neurolens_addon.core.focus import focus_sensor_z
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.stmap import chief_ray_table
    lens = load_lens(ROOT / "presets" / "lenses" / "fisheye_f4.toml")
    table = chief_ray_table(lens, focus_sensor_z(lens, 2000.0), 12.0)
    zc = table.axis_z[0] - focus_sensor_z(lens, 2000.0)      # pupil ahead of the sensor, mm

    def pinhole(p):
        x, y, z = (1000.0 * np.asarray(p))
        depth = -z * 1.0 - zc
        return np.array([W / 2 + table.f_p_mm * x / depth / (24.0 / W),
                         H / 2 + table.f_p_mm * y / depth / (24.0 / W)])
    pin = [pinhole(p) for p in ((-2.45, 1.2, -1.6), (-2.2, 1.3, -1.85), (-1.95, 1.4, -2.1))]
    pin_steps = np.concatenate([pin[0] - pin[1], pin[1] - pin[2]])
    print(f"the pinhole's steps {pin_steps.round(3)}")
    assert np.abs(pin_steps - measured).max() > 3.0


@pytest.mark.slow
def test_02_the_camera_turning_moves_a_still_ball_as_the_vector_pass_says(tmp_path):
    """The camera pans (5 degrees a frame), tilts and steps sideways; the ball stands still
    off the axis of the 14 mm ultrawide (full-frame width): the pass at the ball within
    0.35 px of its image's steps."""
    _ball, cam = _ball_scene("ultrawide_14mm_f2_8", 36.0,
                             camera_frames=[(9, (math.radians(-3.0), 0.0, math.radians(-5.0))),
                                            (11, (math.radians(3.0), 0.0, math.radians(5.0)))])
    _linear(cam, "location", [(9, (-0.2, 0.0, 0.0)), (11, (0.2, 0.1, 0.0))])
    bpy.context.scene.objects["Sphere"].location = (1.2, 0.5, -1.9)
    _steps_match_the_pass(tmp_path, "14 mm, the camera moving")


@pytest.mark.slow
def test_03_position_and_uv_are_the_plane_s_and_nothing_still_moves(tmp_path):
    """A plane 3 m ahead (10 m square, its UVs spanning it): Position z is -3 and the UVs are
    (x / 10 + 1/2, y / 10 + 1/2) of Position at every pixel (1e-4), UV's third channel 1; with
    nothing animated the Vector pass is 0 everywhere (1e-3 px); the passes are in the EXR with
    Blender's channel names."""
    scenes.reset()
    bpy.ops.mesh.primitive_plane_add(size=10.0, location=(0.0, 0.0, -3.0))
    bpy.context.object.data.materials.append(scenes.material("grey", emission=(1, 1, 1)))
    scenes.camera(lens="wide_20mm_f2_8", focus=3.0, fstop=4.0, sensor_width=36.0)
    _data_passes("vector", "position", "uv")
    bpy.context.scene.frame_set(10)
    ch = scenes.render(tmp_path / "plane.exr", 96, 64, 4)
    assert {"Vector.X", "Vector.W", "Position.Z", "UV.U", "UV.V", "UV.A"} <= set(ch)
    assert np.abs(ch["Position.Z"] + 3.0).max() < 1e-4
    assert np.abs(ch["UV.U"] - (ch["Position.X"] / 10.0 + 0.5)).max() < 1e-4
    assert np.abs(ch["UV.V"] - (ch["Position.Y"] / 10.0 + 0.5)).max() < 1e-4
    assert np.abs(ch["UV.A"] - 1.0).max() < 1e-6     # the plane covers every pixel
    # the frame sees more than a sliver of the plane: x spans metres
    assert np.ptp(ch["Position.X"]) > 3.0
    for k in "XYZW":
        assert np.abs(ch[f"Vector.{k}"]).max() < 1e-3


@pytest.mark.slow
def test_04_an_anamorphic_lens_s_vectors_are_its_own(tmp_path):
    """The 2x anamorphic (its mapping differs along x and y: placed by its chief-ray grid):
    a glowing square facing the camera (every point at one depth, so each moves on the film
    as its image's centroid does), 3 m away, moving across and down off the axis, moves on the
    desqueezed film as the pass says, within 0.35 px."""
    scenes.reset()
    bpy.ops.mesh.primitive_plane_add(size=0.24, location=(0.0, 0.0, -3.0))
    square = bpy.context.object
    square.data.materials.append(scenes.material("glow", (0, 0, 0), emission=(1, 1, 1),
                                                 strength=20.0))
    _linear(square, "location", [(9, (-0.5, 0.35, -3.0)), (11, (0.1, 0.05, -3.0))])
    scenes.camera(lens="anamorphic_2x_60mm_f1_9", focus=3.0, fstop=4.0, sensor_width=36.0)
    _data_passes("vector")
    # (its camera samples aim at the rear element's disc: few pass the stop, so more of them)
    _steps_match_the_pass(tmp_path, "anamorphic, the square moving", samples=64)


@pytest.mark.slow
@pytest.mark.parametrize("caster", ["EMBREE", "BLENDER"])
def test_04a_an_instanced_ball_moves_with_the_empty_that_instances_it(tmp_path, caster):
    """A collection instance: the ball lives in a collection outside the scene, an empty
    instances it and moves; its copy's image moves as the pass says (within 0.35 px), and the
    original, never rendered, does not stand in for it; through Embree (which names the copy
    by its triangles) and Blender's BVH (by the object and matrix its ray_cast returns)."""
    scenes.reset()
    coll = bpy.data.collections.new("Balls")
    ball = scenes.emitter_sphere((0.0, 0.0, 0.0), radius=0.03, strength=20.0)
    for c in list(ball.users_collection):
        c.objects.unlink(ball)
    coll.objects.link(ball)
    empty = bpy.data.objects.new("Carrier", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = coll
    bpy.context.scene.collection.objects.link(empty)
    _linear(empty, "location", [(9, (-0.6, 0.3, -2.0)), (11, (-0.1, 0.05, -2.2))])
    scenes.camera(lens="wide_20mm_f2_8", focus=2.0, fstop=8.0, sensor_width=24.0)
    _data_passes("vector")
    bpy.context.scene.neurolens_engine.intersector = caster
    _steps_match_the_pass(tmp_path, f"instance ({caster}), the carrier moving")


@pytest.mark.slow
def test_04b_a_lens_known_only_from_a_ray_table_places_points_by_its_model(tmp_path):
    """A ray-table lens has no stop, but its chief rays through its model (camera.table_lens)
    place the Vector pass's points: a ball crossing the table Tessar's field 8 m away steps
    on the film as the pass says, within 0.35 px."""
    from testdata.table_lens import MODEL
    scenes.reset()
    ball = scenes.emitter_sphere((0.0, 0.0, -8.0), radius=0.06, strength=20.0)
    _linear(ball, "location", [(9, (-0.5, 0.2, -8.0)), (11, (-0.2, 0.3, -8.0))])
    cam = scenes.camera(lens=str(MODEL), model="learned", focus=8.0, fstop=4.0,
                        sensor_width=36.0)
    cam.data.sensor_fit = "HORIZONTAL"
    _data_passes("vector", "position", "uv")
    _steps_match_the_pass(tmp_path, "ray table, the ball moving")


def test_05_the_view_layer_s_passes_panel_switches_them_for_the_engine():
    """View Layer > Passes shows the engine a Data panel with the three switches (Blender's
    own view-layer properties, the ones the render reads), and only for this engine."""
    from neurolens_addon.blender.engine_registration import NEUROLENS_PT_passes_data
    from neurolens_addon.blender.render_engine import data_passes_of
    scene = scenes.reset()
    assert NEUROLENS_PT_passes_data.is_registered
    parent = getattr(bpy.types, NEUROLENS_PT_passes_data.bl_parent_id)
    assert "NEUROLENS" in parent.COMPAT_ENGINES
    assert NEUROLENS_PT_passes_data.poll(bpy.context)
    layer = scene.view_layers[0]
    assert data_passes_of(layer) == ()
    layer.use_pass_uv = layer.use_pass_vector = True
    assert data_passes_of(layer) == ("Vector", "UV")
    scene.render.engine = "CYCLES"
    assert not NEUROLENS_PT_passes_data.poll(bpy.context)


def test_06_the_memory_estimate_counts_the_data_passes():
    """A frame with the three data passes needs 4 bytes a channel a pixel more in Blender's
    result (4 + 3 + 3) and in the film's sums (5 + 3 + 2 + 2)."""
    from neurolens_addon.engine.data_passes import DataLayout
    from neurolens_addon.engine.memory import estimate
    from neurolens_addon.engine.settings import RenderSettings
    s = RenderSettings()
    plain = estimate(640, 360, s)
    more = estimate(640, 360, s, data=DataLayout(("Vector", "Position", "UV")))
    p = 640 * 360
    assert more.parts["result"] - plain.parts["result"] == 4 * 10 * p
    assert more.parts["film"] - plain.parts["film"] == 4 * 12 * p     # + samples, hits
    with pytest.raises(ValueError, match="no such data pass"):
        DataLayout(("Motion",))
