"""Two cameras never share state; user lens files are checked before use; picking a point
focuses the camera (and is refused nearer than the closest focus)."""

import shutil
from pathlib import Path

import bpy
import pytest
from mathutils import Vector

ROOT = Path(__file__).resolve().parents[2]
PRESET = ROOT / "presets" / "lenses" / "tessar_f4_5.toml"


def _key(spec):
    return (spec.model, spec.lens.name, spec.f_number, spec.focus_distance_m, spec.sensor_z_mm,
            repr(spec.aperture), spec.dispersion, spec.focal_mm)


def test_01_two_cameras_with_different_lenses_have_independent_specs(addon, scene,
                                                                      cycles_stub):
    """Two cameras, two lenses, different f-numbers, focus and apertures: each spec is its own
    camera's; editing one camera changes neither the other's spec nor what was applied to
    it, and each camera datablock received only its own specs."""
    sc, camera = scene
    a = camera("CamA", lens_id="double_gauss_50mm_f2", location=(0, 0, 0))
    b = camera("CamB", lens_id="telephoto_f5_6", location=(5, 0, 0))
    a.data.dof.aperture_fstop, a.data.dof.focus_distance = 2.8, 3.0
    b.data.dof.aperture_fstop, b.data.dof.focus_distance = 11.0, 20.0
    b.data.neurolens.aperture_shape = "BLADES"
    sa, sb = (addon.sync.camera_spec(o, sc) for o in (a, b))
    assert sa.lens.name != sb.lens.name and sa.f_number != sb.f_number
    assert sa.focus_distance_m == pytest.approx(3.0) and sb.focus_distance_m == pytest.approx(20)
    assert type(sa.aperture).__name__ == "CircularAperture"
    assert type(sb.aperture).__name__ == "PolygonAperture"
    before_b = _key(sb)
    # edit camera A in every way; B must not move
    a.data.neurolens.lens_id = "cooke_triplet_f4"
    a.data.dof.aperture_fstop = 5.6
    a.data.dof.focus_distance = 1.0
    a.data.neurolens.dispersion = False
    a.data.neurolens.model = "THIN"
    assert _key(addon.sync.camera_spec(b, sc)) == before_b
    assert addon.sync.camera_spec(a, sc).lens.name.startswith("Cooke")
    # everything applied to a datablock came from that camera's own settings
    assert {name for name, _spec in cycles_stub.applied} == {a.data.name, b.data.name}
    for name, spec in cycles_stub.applied:
        if name == b.data.name:
            assert spec.lens.name == sb.lens.name, spec
        else:
            assert spec.lens.name.startswith(("Double Gauss", "Cooke")), spec
    states = addon.sync._STATUS
    assert states[a.session_uid] is not states[b.session_uid]


def test_02_same_lens_on_two_cameras_shares_only_immutable_data(addon, scene):
    """Two cameras on the same preset share the cached, frozen lens entry (by content) but
    their f-numbers, focus and messages stay apart."""
    sc, camera = scene
    a, b = camera("Same1"), camera("Same2")
    a.data.dof.aperture_fstop = 1.0                 # clamped, with a message
    b.data.dof.aperture_fstop = 8.0
    sa, sb = (addon.camera_state.evaluate_camera(o, sc) for o in (a, b))
    assert sa.entry is sb.entry
    assert sa.f_number == pytest.approx(2.0) and sb.f_number == pytest.approx(8.0)
    assert sa.messages and not sb.messages
    import dataclasses
    with pytest.raises(dataclasses.FrozenInstanceError):
        sa.entry.lens.name = "changed"
    with pytest.raises(dataclasses.FrozenInstanceError):
        sa.entry.closest_focus_mm = 1.0


def test_03_loading_a_good_user_lens_file(addon, scene, tmp_path):
    """Load Lens File with a valid file: the camera uses it (source FILE, enabled), the spec
    has its lens, and with "Add to My Lenses" it is copied into the user lens folder (not the
    add-on folder) and listed in the picker."""
    sc, camera = scene
    obj = camera("User", enabled=False)
    mine = tmp_path / "my_tessar.toml"
    shutil.copyfile(PRESET, mine)
    with bpy.context.temp_override(object=obj, active_object=obj):
        assert bpy.ops.neurolens.load_lens_file(filepath=str(mine)) == {"FINISHED"}
    props = obj.data.neurolens
    assert props.enabled and props.source == "FILE" and Path(props.lens_file) == mine
    assert addon.sync.camera_spec(obj, sc).lens.path == str(mine.resolve())
    with bpy.context.temp_override(object=obj, active_object=obj):
        assert bpy.ops.neurolens.load_lens_file(filepath=str(mine),
                                                add_to_library=True) == {"FINISHED"}
    folder = addon.library.user_lenses_dir()
    assert props.source == "LIBRARY" and props.lens_id == "user:my_tessar.toml"
    assert (folder / "my_tessar.toml").is_file()
    assert addon.preferences.ADDON_ROOT not in folder.resolve().parents
    assert "user:my_tessar.toml" in [i.id for i in addon.library.items()]
    assert props.lens == "user:my_tessar.toml"
    (folder / "my_tessar.toml").unlink()


@pytest.mark.parametrize("text, expect", [
    ("name = 'x'\n", "missing"),
    ("this is = = not toml\n", "line 1"),
])
def test_04_malformed_lens_file_is_refused_and_camera_unchanged(addon, scene, tmp_path, text,
                                                                 expect):
    """A malformed file: the operator is cancelled with the core's LensError message (naming
    the file), the function raises LensError, and the camera's settings and spec are exactly
    as before."""
    sc, camera = scene
    obj = camera("Bad", lens_id="tessar_f4_5")
    obj.data.dof.aperture_fstop = 8.0
    props = obj.data.neurolens
    before = (props.source, props.lens_id, props.lens_file, props.enabled)
    spec_before = _key(addon.sync.camera_spec(obj, sc))
    bad = tmp_path / "broken.toml"
    bad.write_text(text)
    with pytest.raises(addon.errors.LensError) as err:
        addon.lensfile.load_lens(bad)
    core_message = str(err.value)
    assert "broken.toml" in core_message and expect in core_message.lower()
    with pytest.raises(addon.errors.LensError):
        addon.operators.load_lens_file(obj.data, bad)
    reports = []
    with bpy.context.temp_override(object=obj, active_object=obj):
        try:
            result = bpy.ops.neurolens.load_lens_file(filepath=str(bad))
        except RuntimeError as exc:       # bpy.ops raises ERROR reports in background mode
            reports.append(str(exc))
            result = {"CANCELLED"}
    assert result == {"CANCELLED"}
    assert reports and core_message in reports[0]
    assert (props.source, props.lens_id, props.lens_file, props.enabled) == before
    assert _key(addon.sync.camera_spec(obj, sc)) == spec_before


def test_05_missing_lens_file_keeps_last_camera_and_says_why(addon, scene, tmp_path,
                                                              cycles_stub):
    """A loaded file that later disappears: the spec is refused with a LensError naming it,
    nothing new is applied, and the panel state carries the message."""
    sc, camera = scene
    obj = camera("Vanish")
    path = tmp_path / "gone.toml"
    shutil.copyfile(PRESET, path)
    addon.operators.load_lens_file(obj.data, path)
    applied = len(cycles_stub.applied)
    path.unlink()
    with pytest.raises(addon.errors.LensError, match="gone.toml"):
        addon.sync.camera_spec(obj, sc)
    state = addon.sync.sync_camera(obj, sc, force=True)
    assert state.setup is None and "gone.toml" in state.messages[0][1]
    assert len(cycles_stub.applied) == applied


def test_06_focus_on_picked_point(addon, scene):
    """focus_on_point sets Blender's focus distance to the point's depth along the view axis,
    clears a focus object, and refuses (changing nothing) a point nearer than the closest
    focus or behind the camera; the operator does the same from a location."""
    sc, camera = scene
    obj = camera("Picker")
    dof = obj.data.dof
    dof.focus_distance = 10.0
    ctx = bpy.context
    depth = addon.operators.focus_on_point(ctx, obj, Vector((0.3, -0.2, -2.5)))
    assert depth == pytest.approx(2.5) and dof.focus_distance == pytest.approx(2.5)
    for point, words in (((0.0, 0.0, -0.2), "no closer than"), ((0.0, 0.0, 3.0), "behind")):
        with pytest.raises(addon.errors.FocusError, match=words):
            addon.operators.focus_on_point(ctx, obj, Vector(point))
        assert dof.focus_distance == pytest.approx(2.5)
    with bpy.context.temp_override(object=obj, active_object=obj):
        assert bpy.ops.neurolens.focus_pick(location=(0.0, 0.0, -4.0),
                                            use_location=True) == {"FINISHED"}
    assert dof.focus_distance == pytest.approx(4.0)
    target = bpy.data.objects.new("nl-hit", None)
    sc.collection.objects.link(target)
    target.location = (0.0, 1.0, -6.0)
    bpy.context.view_layer.update()
    try:
        addon.operators.focus_on_point(ctx, obj, Vector((0.0, 1.0, -5.5)), hit_object=target,
                                       track_object=True)
        assert dof.focus_object == target
        assert addon.sync.camera_spec(obj, sc).focus_distance_m == pytest.approx(6.0)
    finally:
        dof.focus_object = None
        bpy.data.objects.remove(target)


def test_07_pick_point_ray_casts_from_the_view_under_the_mouse(addon, scene):
    """pick_point turns a window position into a ray from the 3D Viewport region under it
    (view3d_utils) and ray-casts the scene: the first surface and its object come back; a
    position outside every 3D Viewport, or one that hits nothing, gives None."""
    from types import SimpleNamespace as NS

    from mathutils import Matrix
    sc, camera = scene
    cam = camera("PickCam")
    mesh = bpy.data.meshes.new("nl-wall")
    mesh.from_pydata([(-1, -1, -5), (1, -1, -5), (1, 1, -5), (-1, 1, -5)], [],
                     [(0, 1, 2, 3)])
    wall = bpy.data.objects.new("nl-wall", mesh)
    sc.collection.objects.link(wall)
    bpy.context.view_layer.update()
    try:
        near, far, f = 0.1, 100.0, 2.0          # a view at the origin looking down -Z
        proj = Matrix(((f, 0, 0, 0), (0, f, 0, 0),
                       (0, 0, (far + near) / (near - far), 2 * far * near / (near - far)),
                       (0, 0, -1, 0)))
        rv3d = NS(is_perspective=True, view_matrix=Matrix.Identity(4),
                  perspective_matrix=proj @ Matrix.Identity(4))
        region = NS(type="WINDOW", x=100, y=50, width=200, height=200, data=rv3d)
        area = NS(type="VIEW_3D", regions=[NS(type="HEADER", x=0, y=0, width=1, height=1,
                                                 data=None), region])
        ctx = NS(window=NS(screen=NS(areas=[NS(type="PROPERTIES", regions=[]), area])),
                 scene=sc, evaluated_depsgraph_get=bpy.context.evaluated_depsgraph_get)
        hit = addon.operators.pick_point(ctx, 200, 150)            # the region's centre
        assert hit is not None
        location, obj = hit
        assert obj.name == "nl-wall" and location.z == pytest.approx(-5.0)
        assert addon.operators.pick_point(ctx, 20, 20) is None     # outside the 3D view
        assert addon.operators.pick_point(ctx, 295, 245) is None   # misses the wall
        depth = addon.operators.focus_on_point(bpy.context, cam, location, hit_object=obj)
        assert depth == pytest.approx(5.0) and cam.data.dof.focus_distance == pytest.approx(5.0)
    finally:
        bpy.data.objects.remove(wall)
        bpy.data.meshes.remove(mesh)
