"""camera.resolve_camera, the one resolver, without Blender: the clamps and their messages,
the aperture, the model and its fall-backs, the sensor position, the film."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from neurolens_addon.camera import ApertureSettings, CameraSettings, resolve_camera, traced
from neurolens_addon.camera.lenses import PRESET_MODELS_DIR, PRESETS_DIR, load_lens_entry
from neurolens_addon.core.aperture import ImageMaskAperture
from neurolens_addon.core.errors import LensError, ModelError
from neurolens_addon.core.film import FilmSettings
from neurolens_addon.core.focus import focus_sensor_z

DG = "double_gauss_50mm_f2"
PATH = str(PRESETS_DIR / f"{DG}.toml")
ENTRY = load_lens_entry(PATH)


def settings(**kw) -> CameraSettings:
    base = dict(camera="Cam", lens_path=PATH, lens_id=DG, model="exact", f_number=4.0,
                focus_distance_mm=3000.0)
    base.update(kw)
    return CameraSettings(**base)


def texts(setup) -> str:
    return " | ".join(t for _level, t in setup.messages)


@pytest.mark.parametrize("asked, used, warned", [
    (4.0, 4.0, False), (2.0, 2.0, False), (1.0, 2.0, True), (2.0 * (1 - 1e-7), 2.0, False),
    (float("nan"), 2.0, True), (-3.0, 2.0, True), (16.0, 16.0, False),
    (1024.0, 1024.0, False), (3.4028234663852886e+38, 1024.0, True), (2000.0, 1024.0, True)])
def test_f_number_is_clamped_to_the_lens_range_with_a_message(asked, used, warned):
    """Wider than the lens: its widest; no f-number: the widest; narrower than f/1024 (a
    .blend holding Blender's largest float, issue 27): f/1024. Each said."""
    s = resolve_camera(settings(f_number=asked))
    assert s.f_number == used
    assert s.stop_radius_mm == pytest.approx(ENTRY.lens.stop_radius_mm * 2.0 / used)
    said = texts(s)
    assert any(w in said for w in ("wider than this lens", "not usable", "narrower than")) \
        == warned


@pytest.mark.parametrize("ghost, expect, said", [
    (dict(intensity=float("nan")), dict(intensity=1.0), "intensity nan"),
    (dict(share=float("nan")), dict(share=0.25), "share nan"),
    (dict(intensity=3.4028234663852886e+38), dict(intensity=1e4), "intensity 3.40282e+38"),
    (dict(count=1000), dict(count=64), "1000 ghosts"),
    (dict(coating="chrome"), dict(coating="single"), "coating 'chrome'"),
    (dict(intensity=2.0, count=4), dict(intensity=2.0, count=4), None)])
def test_ghost_settings_a_render_cannot_use_are_fixed_and_said(ghost, expect, said):
    """Ghost settings read from a .blend (NaN, Blender's largest float, too many ghosts, an
    unknown coating) are made usable and the change is among the set-up's messages (issue
    27: the messages were frozen before the ghosts' were added, so the fix went unsaid)."""
    from neurolens_addon.camera.settings import GhostSettings
    s = resolve_camera(settings(ghosts=GhostSettings(enabled=True, **ghost)))
    for name, value in expect.items():
        assert getattr(s.ghosts, name) == value, name
    if said is None:
        assert "Ghosts" not in texts(s)
    else:
        assert said in texts(s), texts(s)


@pytest.mark.parametrize("asked_mm", [10.0, 0.0, float("nan"), 300.0])
def test_focus_nearer_than_the_closest_focus_focuses_there_and_says_so(asked_mm):
    s = resolve_camera(settings(focus_distance_mm=asked_mm))
    assert s.focus_mm == ENTRY.closest_focus_mm
    assert "focuses no closer" in texts(s)
    assert s.sensor_z_mm == pytest.approx(
        focus_sensor_z(ENTRY.lens, ENTRY.closest_focus_mm, stop_radius=s.stop_radius_mm))


@pytest.mark.parametrize("distance_mm", [600.0, 2000.0, math.inf])
def test_the_sensor_focuses_the_distance_at_the_stop_used(distance_mm):
    s = resolve_camera(settings(focus_distance_mm=distance_mm, f_number=2.8))
    assert s.focus_mm == distance_mm and not s.messages
    assert s.sensor_z_mm == pytest.approx(
        focus_sensor_z(ENTRY.lens, distance_mm, stop_radius=s.stop_radius_mm), abs=1e-9)


def test_apertures_blades_masks_and_a_missing_mask():
    blades = resolve_camera(settings(aperture=ApertureSettings("blades", 5, 12.0, 0.3)))
    assert type(blades.aperture).__name__ == "PolygonAperture"
    assert blades.aperture_key == ("polygon", 5, 12.0, 0.3)
    yy, xx = np.mgrid[-1:1:8j, -1:1:8j]
    mask = ImageMaskAperture((xx ** 2 + yy ** 2 < 0.8).astype(float), source="m")
    masked = resolve_camera(settings(aperture=ApertureSettings("mask", mask=mask,
                                                               mask_key=("m", "abc"))))
    assert masked.aperture is mask and masked.aperture_key == mask.key
    assert mask.key[:3] == ("mask", 8, 8)
    # the key is the mask's content: the same pixels, the same key; other pixels, another
    same = ImageMaskAperture((xx ** 2 + yy ** 2 < 0.8).astype(float), source="other name")
    other = ImageMaskAperture((xx ** 2 + yy ** 2 < 0.5).astype(float), source="m")
    assert same.key == mask.key and other.key != mask.key
    missing = resolve_camera(settings(aperture=ApertureSettings("mask", mask_problem="gone")))
    assert type(missing.aperture).__name__ == "CircularAperture"
    assert "gone; using a round aperture" in texts(missing)
    two = resolve_camera(settings(aperture=ApertureSettings("blades", 2)))
    assert two.aperture_key == ("circle",)


def test_learned_uses_the_lens_model_and_falls_back_to_exact_with_a_reason(tmp_path):
    own = str(PRESET_MODELS_DIR / f"{DG}.neurolens")
    found = resolve_camera(settings(model="learned", model_candidates=(own, str(PRESET_MODELS_DIR))))
    assert found.model == "learned" and found.model_dir == own
    assert "film radius" not in texts(found)          # the presets' models cover full frame
    # a 48 mm wide film reaches beyond the model's film radius: said once, by the resolver
    wide = resolve_camera(settings(model="learned", model_candidates=(own,),
                                   film=FilmSettings(sensor_width=48.0)))
    assert "beyond the learned model's film radius" in texts(wide)
    small = resolve_camera(settings(model="learned", model_candidates=(own,),
                                    film=FilmSettings(sensor_width=24.0)))
    assert "film radius" not in texts(small)
    none = resolve_camera(settings(model="learned", model_candidates=(str(tmp_path),)))
    assert none.model == "exact" and "No trained NeuroLens model" in texts(none)
    other = str(PRESET_MODELS_DIR / "cooke_triplet_f4.neurolens")
    with pytest.raises(ModelError, match="another lens"):
        resolve_camera(settings(model="learned", model_dir=other))


def test_a_model_trained_for_a_narrower_stop_gives_way_to_the_exact_trace(tmp_path):
    model = tmp_path / "narrow.neurolens"
    shutil.copytree(PRESET_MODELS_DIR / f"{DG}.neurolens", model)
    meta = json.loads((model / "model.json").read_text())
    meta["domain"]["stop_radius_mm"] = 0.5 * ENTRY.lens.stop_radius_mm     # trained at f/4
    (model / "model.json").write_text(json.dumps(meta))
    within = resolve_camera(settings(model="learned", model_dir=str(model), f_number=5.6))
    assert within.model == "learned"
    wide = resolve_camera(settings(model="learned", model_dir=str(model), f_number=2.0))
    assert wide.model == "exact" and "wider than the learned model" in texts(wide)


def test_the_thin_lens_is_traced_exactly_by_ray_tracers():
    thin = resolve_camera(settings(model="thin"))
    assert thin.model == "thin" and thin.sensor_z_mm == 0.0
    exact = traced(thin)
    assert exact.model == "exact" and exact.sensor_z_mm == resolve_camera(settings()).sensor_z_mm
    assert "traces this lens exactly" in texts(exact)


def test_the_film_and_errors_name_what_is_wrong(tmp_path):
    s = resolve_camera(settings(film=FilmSettings(36.0, 24.0, "VERTICAL", 1000, 500, 50.0)))
    assert (s.film.width_px, s.film.height_px, s.film.height_mm) == (500, 250, 24.0)
    with pytest.raises(LensError, match="cannot read the lens file"):
        resolve_camera(settings(lens_path=str(tmp_path / "none.toml")))
    with pytest.raises(ModelError, match="lens model must be one of"):
        resolve_camera(settings(model="fast"))


def test_equal_settings_give_equal_setups_and_keys():
    a, b = resolve_camera(settings()), resolve_camera(settings())
    assert a.as_dict() == b.as_dict() and a.key == b.key
    assert resolve_camera(settings(f_number=5.6)).key != a.key
    assert resolve_camera(settings(film=FilmSettings(sensor_width=35.0))).key != a.key


def test_a_single_precision_f_number_of_the_widest_is_the_widest():
    """Blender stores f/0.95 as 0.9499999: the Noct opens to f/0.95 without a warning."""
    noct = str(PRESETS_DIR / "noct_58mm_f0_95_aspheric.toml")
    s = resolve_camera(settings(lens_path=noct, lens_id=None, f_number=float(np.float32(0.95))))
    assert s.f_number == 0.95 and not s.f_number_clamped and "wider" not in texts(s)
    wider = resolve_camera(settings(lens_path=noct, lens_id=None, f_number=0.94))
    assert wider.f_number == 0.95 and wider.f_number_clamped and "wider" in texts(wider)


def test_animated_focus_and_f_number_give_the_range_to_follow():
    """Animated values give the follow range, clamped as each frame clamps (nearer than the
    closest focus: the closest; wider than the lens: its widest; 0 is the closest focus);
    values that never change give none; a learned model that does not cover the whole range
    gives way to the exact trace."""
    near = ENTRY.closest_focus_mm
    pull = resolve_camera(settings(animated_focus_mm=(100.0, 3000.0),
                                   animated_f_numbers=(1.0, 2.8, 8.0)))
    assert pull.follow.focus_mm == pytest.approx((near, 3000.0))
    assert pull.follow.f_numbers == pytest.approx((ENTRY.f_number, 8.0))
    anywhere = resolve_camera(settings(animated_focus_mm=(0.0, math.inf)))
    assert anywhere.follow.focus_mm == (pytest.approx(near), math.inf)
    assert resolve_camera(settings()).follow is None
    still = resolve_camera(settings(focus_distance_mm=2000.0, animated_focus_mm=(2000.0,),
                                    animated_f_numbers=(4.0,), f_number=4.0))
    assert still.follow is None
    own = str(PRESET_MODELS_DIR / f"{DG}.neurolens")
    learned = resolve_camera(settings(model="learned", model_candidates=(own,),
                                      film=FilmSettings(sensor_width=24.0),
                                      animated_f_numbers=(2.0, 8.0)))
    assert learned.model == "learned" and learned.follow is not None
    pull = resolve_camera(settings(model="learned", model_candidates=(own,),
                                   film=FilmSettings(sensor_width=24.0),
                                   animated_focus_mm=(1000.0, 3000.0)))
    assert pull.model == "learned" and pull.follow.focus_mm == (1000.0, 3000.0)
    # at its closest focus and f/4 the sensor sits just past the model's trained range
    too_near = resolve_camera(settings(model="learned", model_candidates=(own,),
                                       film=FilmSettings(sensor_width=24.0),
                                       animated_focus_mm=(near, 3000.0)))
    assert too_near.model == "exact" and "outside the learned model's range" in texts(too_near)


def test_a_lens_with_a_focusing_group_moves_it_and_keeps_the_sensor(tmp_path):
    """Internal focusing: the set-up's lens has its group moved for the focus distance (the
    Cycles camera and the engine trace setup.lens), the sensor keeps only a small residual,
    and a learned model (trained at infinity) gives way to the exact trace away from it."""
    from neurolens_addon.core.variable_gaps import focus_position, lens_at
    from neurolens_addon.cycles import CameraSpec
    from testdata.focusing_lenses import CLOSE_MM, rear_focusing_double_gauss, write
    path = write(tmp_path / "rear_focus.toml")
    lens = rear_focusing_double_gauss()
    far = resolve_camera(settings(lens_path=path, lens_id=None, focus_distance_mm=math.inf))
    assert far.focus_group == 0.0 and far.lens == load_lens_entry(path).lens
    near = resolve_camera(settings(lens_path=path, lens_id=None, focus_distance_mm=3000.0))
    assert near.focus_group == pytest.approx(focus_position(lens, 3000.0))
    assert near.lens == lens_at(lens, focus=near.focus_group)
    assert near.lens.surfaces[5].thickness_mm < lens.surfaces[5].thickness_mm
    unit = resolve_camera(settings(focus_distance_mm=3000.0))
    assert abs(near.sensor_z_mm - far.sensor_z_mm) < 0.1 * abs(unit.sensor_z_mm
                                                               - far.sensor_z_mm)
    assert CameraSpec.from_setup(near).lens == near.lens
    closest = resolve_camera(settings(lens_path=path, lens_id=None, focus_distance_mm=500.0))
    assert closest.focus_mm == CLOSE_MM and closest.focus_group == pytest.approx(1.0)
    assert "focuses no closer" in texts(closest)
    # a learned model of this lens (the preset's graphs, relabelled) knows it at infinity
    model = tmp_path / "rear.neurolens"
    shutil.copytree(PRESET_MODELS_DIR / f"{DG}.neurolens", model)
    meta = json.loads((model / "model.json").read_text())
    meta["lens"]["content_hash"] = lens.content_hash()
    (model / "model.json").write_text(json.dumps(meta))
    at_inf = resolve_camera(settings(lens_path=path, lens_id=None, model="learned",
                                     model_dir=str(model), focus_distance_mm=math.inf,
                                     f_number=2.0))
    assert at_inf.model == "learned"
    moved = resolve_camera(settings(lens_path=path, lens_id=None, model="learned",
                                    model_dir=str(model), focus_distance_mm=3000.0,
                                    f_number=2.0))
    assert moved.model == "exact" and "moves this lens's focusing groups" in texts(moved)


def test_a_zoom_lens_takes_blenders_focal_length_within_its_range(tmp_path):
    """The camera's focal length sets a zoom lens's gaps (core.variable_gaps.zoom_position):
    the set-up's lens and focal length follow it, the Cycles camera traces that lens, and a
    focal length outside the range is clamped with a message."""
    from neurolens_addon.core.paraxial import paraxial_data
    from neurolens_addon.core.variable_gaps import lens_at, zoom_position
    from neurolens_addon.cycles import CameraSpec
    from testdata.focusing_lenses import write_zoom, zooming_double_gauss
    path = write_zoom(tmp_path / "zoom.toml")
    lens = zooming_double_gauss()
    wide = resolve_camera(settings(lens_path=path, lens_id=None, zoom_mm=50.0))
    assert wide.lens == load_lens_entry(path).lens and not wide.messages
    mid = resolve_camera(settings(lens_path=path, lens_id=None, zoom_mm=55.0))
    assert mid.lens == lens_at(lens, zoom=zoom_position(lens, 55.0))
    assert mid.entry.efl_mm == pytest.approx(paraxial_data(mid.lens).efl_mm)
    assert wide.entry.efl_mm < mid.entry.efl_mm
    assert CameraSpec.from_setup(mid).lens == mid.lens
    far = resolve_camera(settings(lens_path=path, lens_id=None, zoom_mm=85.0))
    assert "zooms from 50 to 60 mm: 85 mm is used as 60 mm" in texts(far)
    assert far.lens == lens_at(lens, zoom=1.0)


def test_a_zoom_preset_uses_each_tabulated_focal_lengths_model_and_the_exact_trace_between():
    """A zoom preset ships a model per tabulated focal length (scripts/train_presets.py); at
    each (given as Blender's float32 focal length) the learned lens is that position's model
    (its most accurate), between two the exact trace, saying why."""
    stem = "zoom_70_200mm_f2_8"
    path = str(PRESETS_DIR / f"{stem}.toml")
    lens = load_lens_entry(path).lens
    candidates = (str(PRESET_MODELS_DIR),)
    for k, f in enumerate(lens.zoom_gaps.positions):
        blender_mm = float(np.float32(f))
        setup = resolve_camera(settings(lens_path=path, lens_id=stem, zoom_mm=blender_mm,
                                        model="learned", model_candidates=candidates))
        assert setup.model == "learned", texts(setup)
        tag = "" if k == 0 else f".zoom{f:g}mm"
        # that position's most accurate model (the full or the sparse one)
        from neurolens_addon.neural.modelfile import read_header
        want = min((d for d in (PRESET_MODELS_DIR / f"{stem}{tag}.neurolens",
                                PRESET_MODELS_DIR / f"{stem}{tag}.sparse.neurolens")
                    if d.is_dir()), key=lambda d: read_header(d).image_error_um_p99).name
        assert setup.model_dir.endswith(want)
    lo, hi = lens.zoom_gaps.positions[0], lens.zoom_gaps.positions[1]
    between = resolve_camera(settings(lens_path=path, lens_id=stem, zoom_mm=0.5 * (lo + hi),
                                      model="learned", model_candidates=candidates))
    assert between.model == "exact" and "No trained NeuroLens model" in texts(between)
    # the way to a model there: train that focal length (not the file's wide end)
    assert f"trainer fit LENS --zoom {0.5 * (lo + hi):g} --out" in texts(between)


def test_a_zoom_animation_note_concerns_the_cycles_camera_alone():
    """An animated zoom is followed by re-making the Cycles camera every frame: that note is
    the set-up's Cycles message (the panel and the command line show it where Cycles renders),
    not one the NeuroLens engine reports on every frame."""
    path = str(PRESETS_DIR / "zoom_rf_24_70mm_f2_8.toml")
    setup = resolve_camera(settings(lens_path=path, lens_id=None, zoom_mm=30.0,
                                    zoom_animated=True))
    cycles = " ".join(t for _l, t in setup.cycles_messages)
    assert "re-making the Cycles camera every frame" in cycles
    assert "Cycles camera" not in texts(setup)



def test_an_anamorphic_lens_uses_its_cartesian_model_in_the_engine_and_exact_in_cycles(tmp_path):
    """A learned model of an anamorphic lens (cartesian frame: the shipped model of the
    attachment preset, copied under another name into a user models folder) is found by the
    lens's content hash like any other: LEARNED and AUTO's candidates use it; the Cycles
    camera, which has no shader for that frame, traces the lens exactly instead of failing.
    (A shipped model rather than one trained here: the add-on's tests run without the
    trainer, under Blender 5.2's Python too.)"""
    from neurolens_addon.cycles import CameraSpec
    from neurolens_addon.neural.modelfile import read_header
    stem = "anamorphic_attachment_speed_panchro_50mm_f2"
    models = tmp_path / "models"
    shutil.copytree(PRESET_MODELS_DIR / f"{stem}.neurolens", models / "anamorphic.neurolens")
    assert read_header(models / "anamorphic.neurolens").frame == "cartesian"
    path = str(PRESETS_DIR / f"{stem}.toml")
    setup = resolve_camera(settings(lens_path=path, lens_id=None, model="learned",
                                    model_candidates=(str(models),),
                                    focus_distance_mm=math.inf))
    assert setup.model == "learned" and setup.model_dir == str(models / "anamorphic.neurolens")
    assert setup.squeeze > 1.2
    spec = CameraSpec.from_setup(setup)
    assert spec.model == "exact" and spec.model_dir is None and spec.squeeze == setup.squeeze


@pytest.mark.parametrize("case", ["anamorphic", "ghosts", "focus groups"])
def test_what_a_shader_cannot_follow_is_re_made_per_frame(case, tmp_path):
    """An animated focus of an anamorphic lens, of a camera with ghosts on, or of a lens whose
    groups move, gives no follow range (the Cycles camera is re-made every frame instead: its
    pupil normalisation, ghost plan or group positions are solved per focus) and says why;
    the Cycles camera of that set-up builds. The same pull on the double Gauss, ghosts off, is
    followed by the shader."""
    from neurolens_addon.camera.settings import GhostSettings
    from neurolens_addon.cycles.spec import CameraSpec
    from neurolens_addon.core.lensfile import dump_lens
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    pull = dict(animated_focus_mm=(1500.0, 4000.0))
    kw = {"anamorphic": dict(lens_path=str(tmp_path / "ana.toml"), lens_id=None, f_number=4.0),
          "ghosts": dict(ghosts=GhostSettings(enabled=True)),
          "focus groups": dict(lens_path=str(PRESETS_DIR / "tele_135mm_f2_if.toml"),
                               lens_id="tele_135mm_f2_if")}[case]
    (tmp_path / "ana.toml").write_text(dump_lens(cylinder_attachment_lens()))
    setup = resolve_camera(settings(**pull, **kw))
    assert setup.follow is None
    reason = {"anamorphic": "This lens is anamorphic", "ghosts": "Ghosts are on",
              "focus groups": "This lens focuses by moving groups"}[case]
    cycles = " | ".join(t for _level, t in setup.cycles_messages)     # Cycles' alone
    assert f"{reason}: an animated focus or f-number is followed by re-making" in cycles
    spec = CameraSpec.from_setup(setup)
    assert spec.follow is None and (spec.ghosts is not None) == (case == "ghosts")
    assert resolve_camera(settings(**pull)).follow is not None


def test_an_anamorphic_camera_is_judged_on_the_lens_film_and_desqueezed_by_its_nominal_squeeze():
    """The 2x preset behind the user guide's 4-perf set-up (a 42.1 mm sensor, 2260 x 1000):
    the lens's own film is 1 / 1.92 as wide, so its corners (14.4 mm from the axis) lie inside
    the learned model's film and Automatic's budget is the lens-side pixel (9.7 um wide, not
    the frame's 18.6 um); focused at 1 m its squeeze is 1.67, yet the frame is desqueezed by
    the nominal 1.92 the panel shows (a front anamorphic's close-ups come out wider)."""
    from neurolens_addon.camera.model_choice import region_needs
    from neurolens_addon.core.paraxial import squeeze
    from neurolens_addon.core.scene_needs import RenderNeeds
    stem = "anamorphic_2x_60mm_f1_9"
    film = FilmSettings(sensor_width=42.1, sensor_fit="HORIZONTAL", resolution_x=2260,
                        resolution_y=1000)
    entry = load_lens_entry(PRESETS_DIR / f"{stem}.toml")
    needs = RenderNeeds.from_film(film, f_numbers=(2.8,), focus_distances_m=(2.0,))
    on_lens = region_needs(needs, entry)
    s_nominal = entry.squeeze
    assert on_lens.squeeze == s_nominal == pytest.approx(1.92, abs=0.01)
    half_h = 0.5 * 42.1 * 1000 / 2260
    assert on_lens.film_radii_mm()[1] == pytest.approx(math.hypot(21.05 / s_nominal, half_h))
    assert on_lens.error_budget_um() == pytest.approx(needs.error_budget_um() / s_nominal)
    setup = resolve_camera(settings(lens_path=str(PRESETS_DIR / f"{stem}.toml"), lens_id=stem,
                                    model="learned", f_number=2.8, focus_distance_mm=2000.0,
                                    film=film, model_candidates=(str(PRESET_MODELS_DIR),)))
    assert setup.model == "learned" and "corners" not in texts(setup)
    close = resolve_camera(settings(lens_path=str(PRESETS_DIR / f"{stem}.toml"), lens_id=stem,
                                    f_number=2.8, focus_distance_mm=1000.0, film=film))
    assert squeeze(close.lens) == pytest.approx(1.674, abs=0.005)
    assert close.squeeze == s_nominal
