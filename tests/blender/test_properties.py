"""Camera properties: they exist, keyframes on focus and f-number drive the spec, the f-number
is clamped to the lens's widest with a message, Blender's own aperture settings stay in sync,
and nearer-than-closest focus is refused."""

import math

import bpy
import pytest


def _spec(addon, obj, scene, depsgraph=None):
    return addon.sync.camera_spec(obj, scene, depsgraph)


def test_01_camera_has_real_lens_properties(addon, scene):
    """camera.data.neurolens has the lens source/picker, model, aperture shape, curvature,
    mask and dispersion settings with the documented choices and defaults."""
    _sc, camera = scene
    props = camera("Props", enabled=False).data.neurolens
    assert props.enabled is False                       # a new camera is left alone
    assert props.source == "LIBRARY" and props.lens_id == "double_gauss_50mm_f2"
    assert props.lens == "double_gauss_50mm_f2"
    rna = props.bl_rna.properties
    assert [i.identifier for i in rna["model"].enum_items] == ["AUTO", "EXACT", "LEARNED",
                                                               "THIN"]
    # files saved before AUTO existed stored EXACT/LEARNED/THIN as 0/1/2: still the same
    assert [i.value for i in rna["model"].enum_items] == [3, 0, 1, 2]
    assert [i.identifier for i in rna["aperture_shape"].enum_items] == ["CIRCLE", "BLADES",
                                                                       "MASK"]
    assert rna["blade_curvature"].is_animatable
    assert rna["mask_image"].fixed_type.identifier == "Image"
    assert props.dispersion is True and props.model == "AUTO"
    ids = [i[0] for i in addon.properties.lens_items(props, bpy.context)]
    assert len(ids) >= 12 and "tessar_f4_5" in ids


def test_02_keyframed_focus_and_f_number_drive_the_spec(addon, scene):
    """Keyframes on Blender's own F-Stop and focus distance: after a frame change the spec has
    that frame's f-number, focus distance and the sensor position that focuses it; the blade
    curvature is keyframable too, and an animated camera is told to lock the interface
    while rendering unless it is."""
    sc, camera = scene
    obj = camera("Keyed")
    dof = obj.data.dof
    for frame, fstop, dist in ((1, 2.8, 1.5), (10, 8.0, 12.0)):
        dof.aperture_fstop, dof.focus_distance = fstop, dist
        dof.keyframe_insert("aperture_fstop", frame=frame)
        dof.keyframe_insert("focus_distance", frame=frame)
    curv = obj.data.neurolens
    curv.blade_curvature = 0.0
    curv.keyframe_insert("blade_curvature", frame=1)
    curv.blade_curvature = 0.5
    curv.keyframe_insert("blade_curvature", frame=10)
    lens = addon.lenses.load_lens_entry(addon.library.path_for("double_gauss_50mm_f2")).lens
    seen = {}
    for frame, fstop, dist in ((1, 2.8, 1.5), (10, 8.0, 12.0)):
        sc.frame_set(frame)
        spec = _spec(addon, obj, sc, bpy.context.evaluated_depsgraph_get())
        assert spec.f_number == pytest.approx(fstop, rel=1e-6)
        assert spec.focus_distance_m == pytest.approx(dist, rel=1e-6)
        r = addon.aperture.stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, fstop)
        z = addon.focus.focus_sensor_z(lens, dist * 1000.0, stop_radius=r)
        assert spec.sensor_z_mm == pytest.approx(z, abs=1e-6)
        seen[frame] = spec.sensor_z_mm
    assert seen[1] < seen[10]          # nearer focus moves the sensor back (-z, from the scene)
    assert obj.data.neurolens.blade_curvature == pytest.approx(0.5)
    # animated cameras are told to lock the interface (render-thread safety)
    sc.render.use_lock_interface = False
    assert any("Lock Interface" in t for _l, t in addon.camera_state.evaluate_camera(obj, sc).messages)
    sc.render.use_lock_interface = True
    assert not addon.camera_state.evaluate_camera(obj, sc).messages


def test_03_handler_reads_the_evaluated_camera_during_renders(addon, scene, cycles_stub):
    """frame_change_post with a depsgraph reads the evaluated (animated) focus even when the
    original datablock still holds another value, as during an animation render."""
    sc, camera = scene
    obj = camera("Evaluated")
    dof = obj.data.dof
    dof.focus_distance = 2.0
    dof.keyframe_insert("focus_distance", frame=1)
    dof.focus_distance = 9.0
    dof.keyframe_insert("focus_distance", frame=5)
    sc.frame_set(5)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    dof.focus_distance = 4.0                  # the original now disagrees with the animation
    state = addon.sync.sync_camera(obj, sc, depsgraph)
    assert state.focus_m == pytest.approx(9.0)
    assert cycles_stub.applied[-1][1].focus_distance_m == pytest.approx(9.0)


def test_04_f_number_wider_than_the_lens_is_clamped_with_a_message(addon, scene):
    """F/1.4 on an F/2 lens: the spec uses f/2, the panel state carries the core's clamp
    message, and Blender's own F-Stop keeps the user's (keyframable) value."""
    sc, camera = scene
    obj = camera("Wide")
    obj.data.dof.aperture_fstop = 1.4
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.f_number == pytest.approx(2.0)
    assert _spec(addon, obj, sc).f_number == pytest.approx(2.0)
    texts = [t for level, t in state.messages if level == "WARNING"]
    assert any("wider than this lens allows" in t and "f/2" in t for t in texts), texts
    assert obj.data.dof.aperture_fstop == pytest.approx(1.4)
    obj.data.dof.aperture_fstop = 4.0
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.f_number == pytest.approx(4.0) and not state.messages


def test_05_aperture_shape_follows_blender_blades_both_ways(addon, scene):
    """Blades and rotation are Blender's own dof settings: choosing BLADES sets a blade count,
    CIRCLE sets Blender's blades to 0, and Blender's blade count alone switches the shape;
    the spec's polygon has the blades, rotation and our curvature."""
    sc, camera = scene
    obj = camera("Iris")
    props, dof = obj.data.neurolens, obj.data.dof
    assert props.aperture_shape == "CIRCLE" and dof.aperture_blades == 0
    props.aperture_shape = "BLADES"
    assert dof.aperture_blades == 6
    dof.aperture_blades = 5
    dof.aperture_rotation = math.radians(30.0)
    props.blade_curvature = 0.25
    ap = _spec(addon, obj, sc).aperture
    assert (ap.blades, ap.rotation_deg, ap.curvature) == (5, pytest.approx(30.0), 0.25)
    props.aperture_shape = "CIRCLE"
    assert dof.aperture_blades == 0
    assert type(_spec(addon, obj, sc).aperture).__name__ == "CircularAperture"
    dof.aperture_blades = 7                                  # set in Blender's DoF panel
    assert props.aperture_shape == "BLADES"
    assert _spec(addon, obj, sc).aperture.blades == 7


def test_06_image_mask_aperture_from_a_blender_image(addon, scene):
    """MASK with a Blender image: the spec's aperture is an image mask whose top rows are the
    image's top (Blender stores rows bottom-up); without an image a warning and a circle."""
    import numpy as np
    sc, camera = scene
    obj = camera("Mask")
    props = obj.data.neurolens
    props.aperture_shape = "MASK"
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert any("no image" in t for _lvl, t in state.messages)
    assert type(state.setup.aperture).__name__ == "CircularAperture"
    img = bpy.data.images.new("nl-mask", 8, 8, alpha=True)
    px = np.zeros((8, 8, 4), dtype=np.float32)
    px[4:, :, :] = 1.0                       # Blender rows 4..7 = the upper half
    img.pixels.foreach_set(px.ravel())
    try:
        props.mask_image = img
        ap = _spec(addon, obj, sc).aperture
        assert type(ap).__name__ == "ImageMaskAperture"
        assert ap.inside(0.0, 0.5) and not ap.inside(0.0, -0.5)
    finally:
        props.mask_image = None
        bpy.data.images.remove(img)


def test_07_focus_nearer_than_closest_is_refused(addon, scene):
    """Focus at 0.1 m on a lens that focuses no closer than ~0.44 m: the spec focuses at the
    closest focus, with a message naming both distances; 0 m is refused the same way."""
    sc, camera = scene
    obj = camera("Near")
    entry = addon.lenses.load_lens_entry(addon.library.path_for("double_gauss_50mm_f2"))
    for asked in (0.1, 0.0):
        obj.data.dof.focus_distance = asked
        state = addon.camera_state.evaluate_camera(obj, sc)
        assert state.focus_m == pytest.approx(entry.closest_focus_mm / 1000.0)
        assert state.setup.focus_m == pytest.approx(state.focus_m)
        msg = " ".join(t for _lvl, t in state.messages)
        assert "focuses no closer than" in msg and f"{state.focus_m:.3f} m" in msg
    obj.data.dof.focus_distance = 0.5
    assert not addon.camera_state.evaluate_camera(obj, sc).messages


def test_08_focus_object_drives_the_distance(addon, scene):
    """With a focus object, the distance is its depth along the camera's view axis (as in
    Blender), not its straight-line distance."""
    sc, camera = scene
    obj = camera("Tracking")
    target = bpy.data.objects.new("nl-target", None)
    sc.collection.objects.link(target)
    try:
        target.location = (1.5, 0.0, -4.0)          # camera at the origin looks down -Z
        obj.data.dof.focus_object = target
        bpy.context.view_layer.update()
        assert _spec(addon, obj, sc).focus_distance_m == pytest.approx(4.0)
    finally:
        obj.data.dof.focus_object = None
        bpy.data.objects.remove(target)


def test_09_focus_cache_makes_replays_cheap(addon, scene):
    """Replaying the same focus distances solves each focus once (cache by lens and
    distance), so scrubbing a keyframed focus does not re-trace."""
    sc, camera = scene
    obj = camera("Cache")
    stats = addon.lru.stats
    obj.data.dof.focus_distance = 2.345
    addon.camera_state.evaluate_camera(obj, sc)
    solves = stats["focus_solves"]
    for _ in range(5):
        obj.data.dof.focus_distance = 3.456
        addon.camera_state.evaluate_camera(obj, sc)
        obj.data.dof.focus_distance = 2.345
        addon.camera_state.evaluate_camera(obj, sc)
    assert stats["focus_solves"] == solves + 1


def test_10_field_of_view_on_the_sensor(addon, scene):
    """The field of view shown is what the lens gives on this camera's sensor: for a 50 mm
    lens on a 36 mm wide frame close to 2 atan(18/50) but not equal (real lens), it follows
    the sensor size, and a lens too small for the frame reports dark corners."""
    sc, camera = scene
    obj = camera("Fov")
    state = addon.camera_state.evaluate_camera(obj, sc, with_fov=True)
    h, v, d = state.fov_deg
    thin = 2.0 * math.degrees(math.atan(18.0 / state.entry.efl_mm))
    assert abs(h - thin) < 1.5 and h != pytest.approx(thin, abs=1e-3)
    assert v < h < d
    obj.data.sensor_width = 18.0
    h2 = addon.camera_state.evaluate_camera(obj, sc, with_fov=True).fov_deg[0]
    assert h2 == pytest.approx(2.0 * math.degrees(math.atan(9.0 / state.entry.efl_mm)),
                               abs=1.0) and h2 < h
    obj.data.sensor_width = 36.0
    obj.data.neurolens.lens_id = "petzval_f1_4"            # covers only a small image circle
    state = addon.camera_state.evaluate_camera(obj, sc, with_fov=True)
    assert state.fov_deg[2] is None
    assert any("image circle" in t for _lvl, t in state.messages)


def test_11_thin_model_uses_blender_thin_lens_values(addon, scene):
    """THIN: the spec is the thin lens with the lens's focal length and the clamped f-number,
    no exact focus solve (sensor at 0)."""
    sc, camera = scene
    obj = camera("Thin")
    obj.data.neurolens.model = "THIN"
    obj.data.dof.aperture_fstop = 1.0
    spec = _spec(addon, obj, sc)
    assert spec.model == "thin" and spec.sensor_z_mm == 0.0
    assert spec.f_number == pytest.approx(2.0)
    assert spec.focal_mm == pytest.approx(50.358, abs=0.01)
