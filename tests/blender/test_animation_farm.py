"""An animated lens camera renders the same on a farm without the add-on (Cycles).

The scene: an emissive checker 2 m before the camera; the Real Lens camera (the exact double
Gauss) pulls focus from 1 m to 4 m and stops down from f/2 to f/8 over frames 1-3. It is
rendered in this process with the add-on (its frame handler running), saved, and rendered
again frame by frame in a fresh process whose Blender user folder has no add-on at all.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap

import bpy
import numpy as np
import pytest

from .conftest import ROOT

pytestmark = pytest.mark.slow          # renders animations

FRAMES = (1, 2, 3)
WIDTH, HEIGHT, SAMPLES = 40, 30, 16


def _read(path) -> np.ndarray:
    import OpenEXR
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        img = (np.asarray(ch["RGBA"].pixels, dtype=np.float32) if "RGBA" in ch else
               np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGBA"], -1))
    return img[..., :3]


def _checker(sc):
    """An 8 x 8 emissive checker, 2 m x 2 m, 2 m down the camera's -Z."""
    verts, faces = [], []
    for i in range(8):
        for j in range(8):
            if (i + j) % 2:
                continue
            x0, y0, k = -1.0 + 0.25 * i, -1.0 + 0.25 * j, len(verts)
            verts += [(x0, y0, -2.0), (x0 + 0.25, y0, -2.0), (x0 + 0.25, y0 + 0.25, -2.0),
                      (x0, y0 + 0.25, -2.0)]
            faces.append((k, k + 1, k + 2, k + 3))
    mesh = bpy.data.meshes.new("checker")
    mesh.from_pydata(verts, [], faces)
    mat = bpy.data.materials.new("glow")
    nt = mat.node_tree
    nt.nodes.clear()
    em = nt.nodes.new("ShaderNodeEmission")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs[0], out.inputs[0])
    mesh.materials.append(mat)
    ob = bpy.data.objects.new("checker", mesh)
    sc.collection.objects.link(ob)
    return ob


def _small_exr_frames(sc):
    """WIDTH x HEIGHT frames written as 32-bit OpenEXR."""
    sc.render.resolution_x, sc.render.resolution_y = WIDTH, HEIGHT
    sc.render.resolution_percentage = 100
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"


def _cycles_scene(sc, frames):
    """Cycles on the CPU, small, fixed seed, no denoising, 32-bit EXR, the checker wall."""
    from bl_ext.user_default.neurolens.neurolens_addon.blender.cycles_camera import \
        use_cycles_cpu
    use_cycles_cpu(sc)
    c = sc.cycles
    c.samples, c.seed, c.use_denoising, c.use_adaptive_sampling = SAMPLES, 3, False, False
    _small_exr_frames(sc)
    sc.render.threads_mode, sc.render.threads = "FIXED", 2
    sc.view_settings.view_transform = "Standard"
    sc.frame_start, sc.frame_end = frames[0], frames[-1]
    _checker(sc)


def _animated_scene(sc, camera, addon):
    _cycles_scene(sc, FRAMES)
    obj = camera("Pull", lens_id="double_gauss_50mm_f2")
    obj.data.neurolens.model = "EXACT"
    obj.data.neurolens.dispersion = False
    dof = obj.data.dof
    for frame, focus, fstop in ((1, 1.0, 2.0), (3, 4.0, 8.0)):
        dof.focus_distance, dof.aperture_fstop = focus, fstop
        dof.keyframe_insert("focus_distance", frame=frame)
        dof.keyframe_insert("aperture_fstop", frame=frame)
    return obj


@pytest.mark.real_cycles
def test_01_focus_pull_and_f_number_ramp_render_the_same_without_the_add_on(addon, scene,
                                                                          tmp_path):
    """Frame by frame, the render without the add-on equals the render with it (same shader,
    same seed: within 1e-5), and the frames really differ (focus and exposure follow)."""
    sc, camera = scene
    obj = _animated_scene(sc, camera, addon)
    with_addon = {}
    for f in FRAMES:
        sc.frame_set(f)
        state = addon.sync.sync_camera(obj, sc)
        assert state.setup.follow is not None
        assert state.setup.follow.focus_mm == pytest.approx((1000.0, 4000.0))
        assert state.setup.follow.f_numbers == pytest.approx((2.0, 8.0))
        sc.render.filepath = str(tmp_path / f"with_{f}.exr")
        bpy.ops.render.render(write_still=True, scene=sc.name)
        with_addon[f] = _read(tmp_path / f"with_{f}.exr")
    assert obj.data.dof.use_dof                 # turned on: Cycles then passes the values
    blend = tmp_path / "pull.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)

    script = textwrap.dedent(f"""
        import bpy, addon_utils
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r})
        assert not [m for m in addon_utils.modules() if "neurolens" in m.__name__]
        assert not any("neurolens" in getattr(h, "__module__", "")
                       for h in bpy.app.handlers.frame_change_post)
        sc = bpy.data.scenes[{sc.name!r}]
        for f in {FRAMES!r}:
            sc.frame_set(f)
            sc.render.filepath = {str(tmp_path)!r} + f"/without_{{f}}.exr"
            bpy.ops.render.render(write_still=True, scene=sc.name)
    """)
    env = dict(os.environ, BLENDER_USER_RESOURCES=tempfile.mkdtemp(prefix="nl-farm-"))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    for f in FRAMES:
        without = _read(tmp_path / f"without_{f}.exr")
        assert np.abs(without - with_addon[f]).max() < 1e-5, f
    # the focus pull and the ramp show: frame 1 (1 m, f/2: the wall far out of focus and the
    # full exposure of f/2) and frame 3 (4 m, f/8) differ
    assert np.abs(with_addon[1] - with_addon[3]).mean() > 0.05


@pytest.mark.real_cycles
def test_02_a_following_frame_renders_as_that_frame_baked(addon, scene, tmp_path):
    """Frame 2 of the pull through the following shader matches a still camera baked at frame
    2's focus and f-number: the means within 3 %, 5 x 5 pixel block means (where the sampling
    noise of the two cameras averages out) within 5 % of the mean."""
    sc, camera = scene
    obj = _animated_scene(sc, camera, addon)
    sc.cycles.samples = 64
    sc.frame_set(2)
    addon.sync.sync_camera(obj, sc)
    sc.render.filepath = str(tmp_path / "follow.exr")
    bpy.ops.render.render(write_still=True, scene=sc.name)
    follow = _read(tmp_path / "follow.exr")
    fc = obj.data.animation_data.action
    setup = addon.sync.last_state(obj).setup
    focus_m, fstop = obj.data.dof.focus_distance, obj.data.dof.aperture_fstop
    obj.data.animation_data_clear()
    del fc
    obj.data.dof.focus_distance, obj.data.dof.aperture_fstop = focus_m, fstop
    still = addon.sync.sync_camera(obj, sc, force=True)
    assert still.setup.follow is None and still.setup.sensor_z_mm == pytest.approx(
        setup.sensor_z_mm)
    sc.render.filepath = str(tmp_path / "still.exr")
    bpy.ops.render.render(write_still=True, scene=sc.name)
    baked = _read(tmp_path / "still.exr")
    assert abs(follow.mean() / baked.mean() - 1.0) < 0.03

    def blocks(img):
        g = img[..., 1]
        return g.reshape(HEIGHT // 5, 5, WIDTH // 5, 5).mean(axis=(1, 3))
    assert np.abs(blocks(follow) - blocks(baked)).mean() < 0.05 * baked.mean()


def test_03_depth_of_field_turned_on_for_the_animation_is_given_back(addon, scene):
    """An animated lens camera gets Depth of Field on (Cycles passes the values only then);
    turning the Real Lens off gives the user's setting (off) back."""
    sc, camera = scene
    obj = camera("Anim", lens_id="double_gauss_50mm_f2")
    obj.data.dof.use_dof = False
    dof = obj.data.dof
    for frame, focus in ((1, 1.0), (3, 4.0)):
        dof.focus_distance = focus
        dof.keyframe_insert("focus_distance", frame=frame)
    sc.frame_start, sc.frame_end = 1, 3
    state = addon.sync.sync_camera(obj, sc, force=True)
    assert state.setup.follow is not None and obj.data.dof.use_dof
    obj.data.neurolens.enabled = False
    addon.sync.sync_camera(obj, sc, force=True)
    assert not obj.data.dof.use_dof and addon.sync.DOF_KEY not in obj.data


@pytest.mark.real_cycles
def test_04_the_command_line_renders_an_animated_lens_with_depth_of_field_off(addon, scene,
                                                                           tmp_path):
    """The render command (`--engine cycles`) on a saved focus pull whose Depth of Field is off
    renders frame 3 as the same file with it on: the add-on, registered by the command, turns
    it on for the animated lens (without it the shader would render the range's far end at
    the widest f-number)."""
    sc, camera = scene
    obj = _animated_scene(sc, camera, addon)
    sc.frame_current = 3
    outs = {}
    for dof in (False, True):
        obj.data.dof.use_dof = dof
        blend = tmp_path / f"dof{dof}.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
        out = tmp_path / f"dof{dof}.exr"
        p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(blend),
                            "--scene", sc.name, "--engine", "cycles", "--samples", "8",
                            "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                           timeout=300)
        assert p.returncode == 0, p.stderr[-2000:]
        from testdata.engine_scenes import read_exr
        ch = read_exr(out)                          # the command writes a multilayer EXR
        outs[dof] = np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1)
    assert np.abs(outs[False] - outs[True]).max() < 1e-5


@pytest.mark.real_cycles
def test_04_a_zoom_animation_renders_each_frame_at_its_focal_length(addon, scene, tmp_path):
    """A zoom lens (a [zoom] table) whose focal length is keyframed 50 -> 60 mm: an animation
    render with the add-on (its frame handler re-making the Cycles camera, Lock Interface on)
    renders each frame as a still camera set to that frame's focal length does."""
    import importlib
    from testdata.focusing_lenses import write_zoom
    sc, camera = scene
    _cycles_scene(sc, (1, 2))
    sc.render.use_lock_interface = True
    obj = camera("Zoom")
    lens_file = importlib.import_module(addon.root + ".blender.operators.lens_file")
    lens_file.load_lens_file(obj.data, write_zoom(tmp_path / "zoom.toml"))
    obj.data.neurolens.model = "EXACT"
    obj.data.neurolens.dispersion = False
    obj.data.dof.focus_distance = 2.0
    for frame, f in ((1, 50.0), (2, 60.0)):
        obj.data.lens = f
        obj.data.keyframe_insert("lens", frame=frame)
    sc.frame_set(1)
    addon.sync.sync_camera(obj, sc, force=True)
    sc.render.filepath = str(tmp_path / "anim_#")
    bpy.ops.render.render(animation=True, scene=sc.name)
    anim = {f: _read(tmp_path / f"anim_{f}.exr") for f in (1, 2)}
    obj.data.animation_data_clear()
    for f, lens_mm in ((1, 50.0), (2, 60.0)):
        obj.data.lens = lens_mm
        addon.sync.sync_camera(obj, sc, force=True)
        sc.render.filepath = str(tmp_path / f"still_{f}.exr")
        bpy.ops.render.render(write_still=True, scene=sc.name)
        still = _read(tmp_path / f"still_{f}.exr")
        assert np.abs(anim[f] - still).max() < 1e-5, f
    assert np.abs(anim[1] - anim[2]).mean() > 0.01          # the zoom shows


@pytest.mark.real_cycles
def test_05_a_focus_pull_with_ghosts_renders_each_frame_as_its_still(addon, scene, tmp_path):
    """Ghosts on (their plan is solved per focus and f-number, so no shader follows them): a
    focus pull rendered as an animation with the add-on (its frame handler re-making the
    Cycles camera, Lock Interface on) renders each frame as a still camera focused there
    does, ghosts included."""
    sc, camera = scene
    _cycles_scene(sc, (1, 2))
    sc.render.use_lock_interface = True
    obj = camera("Ghosts", lens_id="double_gauss_50mm_f2")
    obj.data.neurolens.model = "EXACT"
    obj.data.neurolens.dispersion = False
    obj.data.neurolens.ghosts = True
    obj.data.neurolens.coating = "BARE"
    for frame, focus in ((1, 1.0), (2, 4.0)):
        obj.data.dof.focus_distance = focus
        obj.data.dof.keyframe_insert("focus_distance", frame=frame)
    sc.frame_set(1)
    addon.sync.sync_camera(obj, sc, force=True)
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.setup.follow is None and state.setup.derived.ghost_plan is not None
    assert "Ghosts are on: an animated focus" in " ".join(t for _l, t in state.messages)
    sc.render.filepath = str(tmp_path / "anim_#")
    bpy.ops.render.render(animation=True, scene=sc.name)
    anim = {f: _read(tmp_path / f"anim_{f}.exr") for f in (1, 2)}
    obj.data.animation_data_clear()
    for f, focus in ((1, 1.0), (2, 4.0)):
        obj.data.dof.focus_distance = focus
        sc.frame_set(f)
        addon.sync.sync_camera(obj, sc, force=True)
        sc.render.filepath = str(tmp_path / f"still_{f}.exr")
        bpy.ops.render.render(write_still=True, scene=sc.name)
        assert np.abs(anim[f] - _read(tmp_path / f"still_{f}.exr")).max() < 1e-5, f
    assert np.abs(anim[1] - anim[2]).mean() > 0.01          # the pull shows


def test_06_the_neurolens_engine_renders_an_animated_zoom_frame_by_frame(addon, scene,
                                                                          cycles_stub,
                                                                          tmp_path):
    """The NeuroLens engine with the RF 24-70 keyframed at 30 / 48 / 66 mm on frames 1-3
    (model Automatic, Lock Interface off, as a new user has it): an animation render frames
    each frame at its own focal length (each equals the still render of that frame to 1e-5,
    the same seed), also when it starts at frame 2, and the zoom shows (the checker's squares
    grow from frame to frame). The add-on's frame handler applies no Cycles camera while the
    engine renders (it used to, writing the camera mid-render: with a slow handler every frame
    came out at the first frame's focal length)."""
    sc, camera = scene
    sc.render.engine = "NEUROLENS"
    sc.render.use_lock_interface = False
    _small_exr_frames(sc)
    sc.neurolens_engine.samples = 16
    sc.neurolens_engine.denoise = False
    _checker(sc)
    obj = camera("Zoom", lens_id="zoom_rf_24_70mm_f2_8")
    assert obj.data.neurolens.model == "AUTO"
    obj.data.neurolens.dispersion = False
    obj.data.dof.focus_distance = 2.0
    focal = {1: 30.0, 2: 48.0, 3: 66.0}
    for frame, f in focal.items():
        obj.data.lens = f
        obj.data.keyframe_insert("lens", frame=frame)
    anim = {}
    for start in (1, 2):
        sc.frame_start, sc.frame_end = start, 3
        sc.frame_set(start)
        sc.render.filepath = str(tmp_path / f"anim{start}_#")
        applied = len(cycles_stub.applied)
        bpy.ops.render.render(animation=True, scene=sc.name)
        assert len(cycles_stub.applied) == applied          # nothing written mid-render
        anim[start] = {f: _read(tmp_path / f"anim{start}_{f}.exr") for f in range(start, 4)}
    stills = {}
    for f in focal:
        sc.frame_set(f)
        sc.render.filepath = str(tmp_path / f"still_{f}.exr")
        bpy.ops.render.render(write_still=True, scene=sc.name)
        stills[f] = _read(tmp_path / f"still_{f}.exr")
    for start, frames in anim.items():
        for f, img in frames.items():
            assert np.abs(img - stills[f]).max() < 1e-5, (start, f)
    # the checker's squares grow: fewer light-dark edges along the middle row and column
    def edges(img):
        lit = img.sum(axis=-1) > 0.5 * img.sum(axis=-1).max()
        return (np.count_nonzero(np.diff(lit[HEIGHT // 2])) +
                np.count_nonzero(np.diff(lit[:, WIDTH // 2])))
    count = {f: edges(img) for f, img in stills.items()}
    assert count[1] > count[2] > count[3], count
