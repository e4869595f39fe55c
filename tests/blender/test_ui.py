"""Preferences, lens-picker thumbnails, the panel's drawing and the learned-lens fallbacks."""

import importlib
import os
from pathlib import Path

import bpy
import pytest

from .conftest import PACKAGE, USER_RESOURCES


def _under(path, folder) -> bool:
    path, folder = Path(path).resolve(), Path(folder).resolve()
    return path == folder or folder in path.parents


def test_01_user_directories_default_to_the_extension_user_path(addon, tmp_path):
    """Lenses, models and thumbnails default to bpy.utils.extension_path_user(package) inside
    this session's Blender user folder, never the add-on folder; a folder chosen in the
    preferences is used instead, except one inside the add-on folder."""
    prefs = addon.preferences
    for kind in ("lenses", "models", "thumbnails"):
        path = prefs.user_directory(kind)
        assert path == Path(bpy.utils.extension_path_user(PACKAGE, path=kind))
        assert path.is_dir() and _under(path, USER_RESOURCES)
        assert not _under(path, prefs.ADDON_ROOT)
    ap = prefs.addon_preferences()
    try:
        ap.models_directory = str(tmp_path / "my models")
        assert prefs.user_directory("models") == (tmp_path / "my models").resolve()
        assert (tmp_path / "my models").is_dir()
        ap.models_directory = str(prefs.ADDON_ROOT / "presets")
        assert not _under(prefs.user_directory("models"), prefs.ADDON_ROOT)
    finally:
        ap.models_directory = ""


def test_02_picker_items_carry_thumbnails_focal_length_and_f_number(addon, scene):
    """Every preset in the picker has a cross-section thumbnail (a PNG cached under the user
    thumbnails folder and loaded as a preview icon) and shows its designed focal length and
    f-number."""
    _sc, camera = scene
    props = camera("Picker", enabled=False).data.neurolens
    items = addon.properties.lens_items(props, bpy.context)
    by_id = {i[0]: i for i in items}
    dg = by_id["double_gauss_50mm_f2"]
    assert "50.36 mm f/2" in dg[1] and "50.36 mm f/2" in dg[2]
    pcoll = addon.thumbnails.collection()
    for item in addon.library.items():
        if item.entry is None:
            continue
        png = addon.thumbnails.thumbnail_path(item.entry.content_hash)
        assert png.is_file() and _under(png, USER_RESOURCES)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert item.entry.content_hash in pcoll
        assert by_id[item.id][3] == pcoll[item.entry.content_hash].icon_id
    assert not any(_under(p, addon.preferences.ADDON_ROOT)
                   for p in USER_RESOURCES.rglob("*.png"))


def test_03_cross_section_drawing_shows_the_lens(addon):
    """The thumbnail shows glass (its colour fills part of the picture), the sensor at the
    left and rays; a different lens gives a different picture."""
    import numpy as np
    cs = addon.crosssection
    dg = addon.lenses.load_lens_entry(addon.library.path_for("double_gauss_50mm_f2")).lens
    tele = addon.lenses.load_lens_entry(addon.library.path_for("telephoto_f5_6")).lens
    a = cs.cross_section_rgba(dg, 128, 64)
    b = cs.cross_section_rgba(tele, 128, 64)
    assert a.shape == (64, 128, 4)
    glass = np.all(np.abs(a - np.array(cs._GLASS)) < 1e-6, axis=-1).mean()
    sensor = np.all(np.abs(a - np.array(cs._SENSOR)) < 1e-6, axis=-1)
    assert 0.02 < glass < 0.6
    assert sensor[:, :16].any() and not sensor[:, 64:].any()
    assert np.abs(a - b).mean() > 0.01


class _Recorder:
    """A stand-in for a UILayout (the panel needs no window) that records every call and
    checks it against Blender's real UILayout API: the function exists, its keyword
    arguments are real parameters, the properties drawn exist on their data and the
    operators drawn are registered."""

    def __init__(self, log):
        self.log = log
        self.active = True
        self.enabled = True
        self.use_property_split = False
        self.use_property_decorate = False

    def __getattr__(self, name):
        fn = bpy.types.UILayout.bl_rna.functions.get(name)
        assert fn is not None, f"UILayout has no function {name}"
        params = [p.identifier for p in fn.parameters if not p.is_output]

        def call(*args, **kwargs):
            assert len(args) <= len(params), (name, args)
            unknown = set(kwargs) - set(params)
            assert not unknown, (name, unknown)
            bound = dict(zip(params, args), **kwargs)
            for key in ("property", "search_property"):
                if key in bound:
                    owner = bound["data"] if key == "property" else bound["search_data"]
                    assert bound[key] in owner.bl_rna.properties, (name, bound[key])
            if name == "operator":
                ident = bound["operator"]
                family, op = ident.split(".")
                getattr(getattr(bpy.ops, family), op).get_rna_type()   # raises if unknown
            self.log.append((name, args, kwargs))
            if name == "panel":
                return _Recorder(self.log), _Recorder(self.log)
            if name == "operator":
                return _OpProps()
            return _Recorder(self.log)
        return call


class _OpProps:
    pass


def _draw(addon, obj, scene, prefs=None):
    log = []
    addon.panel.draw_panel(_Recorder(log), scene, obj, obj.data, prefs)
    texts = [kw.get("text", "") for name, _a, kw in log if name == "label"]
    props = [(a[0].__class__.__name__, a[1]) for name, a, _kw in log if name == "prop"]
    return log, texts, props


def test_04_panel_draws_every_section_and_the_osl_note(addon, scene):
    """The Real Lens panel draws the lens picker with thumbnails, the model switch, Blender's
    focus distance/object with the pick operator, Blender's F-Stop as the f-number, the
    aperture shape and dispersion, the field of view, the clamp message and the note that
    OSL cameras need the CPU or OptiX."""
    sc, camera = scene
    obj = camera("Panel")
    obj.data.dof.aperture_fstop = 1.2
    log, texts, props = _draw(addon, obj, sc)
    names = [p[1] for p in props]
    for needed in ("source", "lens", "model", "focus_object", "focus_distance",
                   "aperture_fstop", "aperture_shape", "dispersion"):
        assert needed in names, needed
    assert any(n == "template_icon_view" for n, _a, _k in log)
    ops = [a[0] for n, a, _k in log if n == "operator"]
    assert "neurolens.focus_pick" in ops and "neurolens.load_lens_file" in ops
    joined = " | ".join(texts)
    assert "CPU" in joined and "OptiX" in joined
    assert "Horizontal" in joined and "Diagonal" in joined
    assert "Designed: 50.36 mm  f/2" in joined
    assert "wider than this lens allows" in joined
    obj.data.neurolens.aperture_shape = "BLADES"
    _log, _texts, props = _draw(addon, obj, sc)
    names = [p[1] for p in props]
    assert {"aperture_blades", "aperture_rotation", "blade_curvature"} <= set(names)
    obj.data.neurolens.aperture_shape = "MASK"
    log, _texts, _props = _draw(addon, obj, sc)
    assert any(n == "template_ID" and a[1] == "mask_image" for n, a, _k in log)
    obj.data.neurolens.source = "FILE"
    log, texts, _props = _draw(addon, obj, sc)
    assert "No lens file loaded" in texts
    assert any("no lens file loaded" in t.lower() and "Load Lens File" in t for t in texts)


def test_05_a_lens_missing_from_the_library_is_reported(addon, scene):
    """A camera whose library lens is gone (renamed file): the picker shows nothing
    selected, the spec is refused with a LensError naming the lens, the panel says so."""
    sc, camera = scene
    obj = camera("Gone")
    obj.data.neurolens.lens_id = "user:renamed.toml"
    assert obj.data.neurolens.lens == ""
    with pytest.raises(addon.errors.LensError, match="renamed.toml"):
        addon.sync.camera_spec(obj, sc)
    _log, texts, _props = _draw(addon, obj, sc)
    assert any("renamed.toml" in t for t in texts)


def test_06_panel_warns_about_gpu_backends_without_osl(addon, scene):
    """Cycles on a GPU with a backend other than OptiX: the panel says to switch to the CPU
    or OptiX; on the CPU it does not."""
    sc, camera = scene
    obj = camera("Gpu")
    sc.render.engine = "CYCLES"

    class Prefs:
        class _Cycles:
            class preferences:
                compute_device_type = "CUDA"
        addons = {"cycles": _Cycles}

    sc.cycles.device = "GPU"
    _log, texts, _p = _draw(addon, obj, sc, Prefs)
    assert any("CUDA" in t for t in texts)
    sc.cycles.device = "CPU"
    _log, texts, _p = _draw(addon, obj, sc, Prefs)
    assert not any("CUDA" in t for t in texts)


def test_07_learned_lens_without_onnxruntime_falls_back_with_the_message(addon, scene,
                                                                         monkeypatch):
    """LEARNED when onnxruntime cannot be imported: the spec uses the exact trace and the
    panel state says 'onnxruntime not available: learned lens disabled; exact and thin
    work'; exact and thin specs are unaffected."""
    sc, camera = scene
    obj = camera("NoOrt")
    obj.data.neurolens.model = "LEARNED"
    monkeypatch.setattr(addon.models, "_ORT", [(False, addon.models.ONNXRUNTIME_MISSING)])
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.setup.model == "exact"
    assert any("onnxruntime not available: learned lens disabled; exact and thin work" in t
               for _lvl, t in state.messages)
    obj.data.neurolens.model = "THIN"
    assert addon.sync.camera_spec(obj, sc).model == "thin"


def test_08_learned_lens_finds_the_preset_model(addon, scene):
    """LEARNED with onnxruntime: the spec names the preset's trained model directory (whose
    lens hash matches) and keeps dispersion when the model was trained with it; a user lens
    without a model falls back to exact, saying where models are looked for."""
    pytest.importorskip("onnxruntime")
    sc, camera = scene
    obj = camera("Learned")
    obj.data.neurolens.model = "LEARNED"
    obj.data.dof.focus_distance = 5.0
    spec = addon.sync.camera_spec(obj, sc)
    assert spec.model == "learned"
    assert Path(spec.model_dir).name == "double_gauss_50mm_f2.neurolens"
    assert spec.dispersion is True
    user = addon.library.user_lenses_dir() / "edited.toml"
    text = (addon.library.PRESETS_DIR / "double_gauss_50mm_f2.toml").read_text()
    user.write_text(text.replace("thickness = 3.76", "thickness = 3.80", 1))
    try:
        obj.data.neurolens.lens_id = "user:edited.toml"
        state = addon.camera_state.evaluate_camera(obj, sc)
        assert state.setup.model == "exact"
        assert any("No trained NeuroLens model" in t for _lvl, t in state.messages)
    finally:
        os.remove(user)


def test_09_learned_model_range_is_respected(addon, scene, monkeypatch):
    """A focus that puts the sensor outside the learned model's trained sensor range falls
    back to the exact trace with a message naming the range; a model without dispersion
    turns dispersion off with a note; frame corners beyond its film radius are flagged."""
    pytest.importorskip("onnxruntime")
    import dataclasses
    sc, camera = scene
    obj = camera("Range")
    obj.data.neurolens.model = "LEARNED"
    real = addon.models.read_header(addon.lenses.PRESET_MODELS_DIR /
                                     "double_gauss_50mm_f2.neurolens")
    narrow = dataclasses.replace(real, sensor_z_range=(-0.5, 0.1), dispersion=False,
                                 film_radius_mm=15.0)
    monkeypatch.setattr(addon.resolve, "find_model", lambda content_hash, candidates: narrow)
    obj.data.dof.focus_distance = 1.0                      # sensor near z = -2.6 mm
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.sensor_z_mm < -0.5
    assert state.setup.model == "exact" and state.setup.model_dir is None
    assert any("outside the learned model's range [-0.500, 0.100]" in t
               for _lvl, t in state.messages)
    obj.data.dof.focus_distance = 100.0                    # sensor near z = +0.03 mm
    state = addon.camera_state.evaluate_camera(obj, sc, with_fov=True)
    assert state.setup.model == "learned" and state.setup.dispersion is False
    assert any("without dispersion" in t for _lvl, t in state.messages)
    assert any("film radius 15.0 mm" in t for _lvl, t in state.messages)


def test_10_a_zoom_lens_shows_blenders_focal_length_and_its_range(addon, scene, tmp_path):
    """A lens with a [zoom] table: the panel draws Blender's own (keyframable) focal length
    with the lens's range, and the set-up follows it."""
    import importlib
    from testdata.focusing_lenses import write_zoom
    sc, camera = scene
    obj = camera("Zoom")
    lens_file = importlib.import_module(addon.root + ".blender.operators.lens_file")
    lens_file.load_lens_file(obj.data, write_zoom(tmp_path / "zoom.toml"))
    obj.data.lens = 55.0
    _log, texts, props = _draw(addon, obj, sc)
    assert ("Camera", "lens") in props
    assert any("Zooms 50-60 mm" in t for t in texts)
    setup = addon.camera_reader.lens_setup(obj, sc)
    wide = addon.lenses.load_lens_entry(str(tmp_path / "zoom.toml"))
    assert setup.entry.efl_mm > wide.efl_mm          # zoomed in from the 50 mm end
    # an animated focal length: the set-up says how Cycles follows it (a Cycles message: the
    # panel shows it where Cycles renders)
    obj.data.keyframe_insert("lens", frame=1)
    obj.data.lens = 60.0
    obj.data.keyframe_insert("lens", frame=10)
    sc.frame_start, sc.frame_end = 1, 10
    animated = addon.camera_reader.lens_setup(obj, sc)
    assert any("focal length of this zoom lens is animated" in t
               for _l, t in animated.cycles_messages)


def test_11_the_picker_groups_by_kind_and_focal_length_and_searches(addon, scene):
    """The library lists lenses by kind (zoom, fisheye, wide angle, normal, telephoto), then
    focal length; the search field finds them by words of name, focal length or kind, and a
    result picked becomes the camera's lens."""
    from bl_ext.user_default.neurolens.neurolens_addon.camera.lens_kinds import KINDS
    items = [i for i in addon.library.items() if not i.is_user and i.entry is not None]
    order = [(KINDS.index(i.kind), i.entry.focal_length_mm) for i in items]
    assert order == sorted(order)
    assert {i.kind for i in items} >= {"Fisheye", "Wide angle", "Normal", "Telephoto"}
    sc, camera = scene
    obj = camera("Find")
    props = obj.data.neurolens
    props_module = importlib.import_module(addon.root + ".blender.properties")
    found = props_module._search_lenses(props, bpy.context, "gauss normal")
    assert found and all("Gauss" in f and "Normal" in f for f in found)
    assert props_module._search_lenses(props, bpy.context, "fisheye")
    assert not props_module._search_lenses(props, bpy.context, "no such lens")
    props.lens_search = next(iter(props_module._search_lenses(props, bpy.context, "takumar")))
    assert props.lens_id == "double_gauss_f1_4_takumar" and props.lens_search == ""
    _log, _texts, drawn = _draw(addon, obj, sc)
    assert ("NEUROLENS_PG_camera", "lens_search") in drawn


def test_12_an_anamorphic_lens_says_its_squeeze(addon, scene, tmp_path):
    """A lens file with cylinders: the panel says it is anamorphic and by how much the frame
    is desqueezed; the set-up carries the same squeeze; a lens of revolution says nothing."""
    import importlib
    from testdata.anamorphic_lenses import write_attachment
    sc, camera = scene
    obj = camera("Anamorphic")
    lens_file = importlib.import_module(addon.root + ".blender.operators.lens_file")
    lens_file.load_lens_file(obj.data, write_attachment(tmp_path / "anamorphic.toml"))
    _log, texts, _props = _draw(addon, obj, sc)
    assert any("Anamorphic: 1.3x squeeze" in t for t in texts), texts
    setup = addon.camera_reader.lens_setup(obj, sc)
    assert setup.squeeze == pytest.approx(1.2951, abs=1e-4)
    plain = camera("Plain")
    _log, texts, _props = _draw(addon, plain, sc)
    assert not any("Anamorphic" in t for t in texts)


def test_04b_a_ray_table_lens_in_the_lens_folder_is_picked_and_drawn(addon, scene, tmp_path):
    """The model of a lens known only from a ray table, put in the user's lens folder, is a
    lens of the picker ("known only from a ray table" in its summary, its measured focal length
    and f-number); a camera set to it renders through that model (whatever the model switch
    says), and the panel says so, with the focus it was taken at and its field of view."""
    import shutil

    from testdata.table_lens import MODEL
    pytest.importorskip("onnxruntime")
    shutil.copytree(MODEL, tmp_path / MODEL.name)
    ap = addon.preferences.addon_preferences()
    ap.lenses_directory = str(tmp_path)
    addon.library.clear_cache()
    try:
        items = {i.id: i for i in addon.library.items()}
        item = items[f"user:{MODEL.name}"]
        assert item.entry is not None and item.entry.table, item.error
        assert "known only from a ray table" in item.summary
        assert item.summary.startswith(f"{item.entry.focal_length_mm:.4g} mm f/4.5")
        sc, camera = scene
        obj = camera("Table", lens_id=f"user:{MODEL.name}")
        obj.data.neurolens.model = "EXACT"
        state = addon.camera_state.evaluate_camera(obj, sc, with_fov=True)
        assert state.setup.model == "learned" and state.setup.entry.table
        assert state.fov_deg[0] is not None and 10.0 < state.fov_deg[0] < 25.0
        _log, texts, _props = _draw(addon, obj, sc)
        joined = " | ".join(texts)
        assert "Measured:" in joined and "Focused at" in joined
        assert "Known only from a ray table" in joined
        assert "Horizontal" in joined
    finally:
        ap.lenses_directory = ""
        addon.library.clear_cache()


def test_04c_load_lens_file_takes_a_ray_tables_model(addon, scene, tmp_path):
    """Load Lens File on the model.json of a ray table's model makes its directory the
    camera's lens; with Add to My Lenses the directory is copied into the lens folder (not
    over another) and the picker lists it."""
    from testdata.table_lens import MODEL
    pytest.importorskip("onnxruntime")
    load = importlib.import_module(f"{addon.root}.blender.operators.lens_file").load_lens_file
    sc, camera = scene
    obj = camera("Loaded")
    entry = load(obj.data, MODEL / "model.json")
    assert entry.table and obj.data.neurolens.source == "FILE"
    assert Path(obj.data.neurolens.lens_file) == MODEL
    ap = addon.preferences.addon_preferences()
    ap.lenses_directory = str(tmp_path)
    addon.library.clear_cache()
    try:
        load(obj.data, MODEL / "model.json", add_to_library=True)
        assert obj.data.neurolens.lens_id == f"user:{MODEL.name}"
        assert (tmp_path / MODEL.name / "model.json").is_file()
        again = load(obj.data, MODEL / "model.json", add_to_library=True)
        assert again.table and obj.data.neurolens.lens_id == f"user:{MODEL.name}"
        assert sorted(p.name for p in tmp_path.iterdir()) == [MODEL.name]
    finally:
        ap.lenses_directory = ""
        addon.library.clear_cache()


def test_04d_write_st_maps_writes_the_cameras_maps_as_blender_exr(addon, scene, tmp_path):
    """Write ST-Maps (the panel's Field of View section): the camera's undistort and distort
    maps as 32-bit float EXR written by Blender, equal to core.stmap's for its lens at its
    focus on its film, each with its lens data beside it; a camera with lens shift is refused
    in one line and writes nothing."""
    import json

    import numpy as np
    import OpenEXR

    from neurolens_addon.core.stmap import MapFrame, chief_ray_table, st_map
    sc, camera = scene
    sc.render.resolution_x, sc.render.resolution_y = 96, 64
    obj = camera("Maps", lens_id="wide_20mm_f2_8")
    obj.data.dof.focus_distance = 2.0
    draw_log, _texts, _props = _draw(addon, obj, sc)
    assert any(n == "operator" and a[0] == "neurolens.write_st_maps" for n, a, _k in draw_log)
    st = importlib.import_module(f"{addon.root}.blender.operators.st_maps")
    paths = st.write_st_maps(obj, sc, tmp_path, overscan=1.05)
    assert [p.name for p in paths] == ["Maps_undistort.exr", "Maps_distort.exr"]
    setup = addon.camera_state.evaluate_camera(obj, sc).setup
    f = setup.film
    frame = MapFrame(f.width_px, f.height_px, f.width_mm, 1.05)
    table = chief_ray_table(setup.lens, setup.sensor_z_mm, frame.film_radius_mm)
    for path, direction in zip(paths, ("undistort", "distort")):
        with OpenEXR.File(str(path)) as exr:
            px = np.asarray(exr.channels()["RGBA"].pixels)[::-1]
        want = st_map(table, frame, direction)
        np.testing.assert_array_equal(px[..., 0], want[..., 0])
        np.testing.assert_array_equal(px[..., 3], want[..., 2])
        meta = json.loads(Path(f"{path}.json").read_text())
        assert meta["direction"] == direction and meta["overscan"] == 1.05
    obj.data.shift_x = 0.1
    shifted = tmp_path / "shifted"
    shifted.mkdir()
    with pytest.raises(addon.errors.NeuroLensError, match="lens shift"):
        st.write_st_maps(obj, sc, shifted)
    assert not any(shifted.iterdir())
