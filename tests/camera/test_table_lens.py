"""camera.table_lens: a lens known only from a ray table is rendered through its model, and the
camera reads from the model what a prescription would give. Checked against the Tessar whose
exact rays the table holds (testdata.table_lens: learned from the table by `trainer fit-table`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.camera import CameraSettings, resolve_camera
from neurolens_addon.camera.lenses import PRESET_MODELS_DIR, load_lens_entry
from neurolens_addon.camera.resolve import TABLE_WHY
from neurolens_addon.core.errors import LensError, ModelError
from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.pupil import RearPupilSampler, cached_centre_irradiance
from neurolens_addon.core.trace import trace
from testdata import table_lens

pytest.importorskip("onnxruntime")


@pytest.fixture(scope="module")
def model():
    return table_lens.MODEL


@pytest.fixture(scope="module")
def exact():
    """(lens, sensor z, E_0) of the Tessar the table was taken from."""
    lens = table_lens.lens()
    z = focus_sensor_z(lens, math.inf)
    return lens, z, cached_centre_irradiance(lens, sensor_z=z, stop_radius=lens.stop_radius_mm,
                                             aperture=None)


def test_01_the_model_measures_the_lens_it_learned(model, exact):
    """The f-number (from the centre irradiance), the focal length (from the field) and the
    focus (from where the centre's rays meet) read from the model are the Tessar's: its
    working f-number within 2 %, its paraxial focal length within 1 %, and focused so near
    infinity that the sensor would sit within 0.1 mm of the infinity plane."""
    lens, _z, e0 = exact
    entry = load_lens_entry(model)
    assert entry.table and entry.lens.table and entry.content_hash.startswith("table-")
    assert entry.name == table_lens.NAME
    n_exact = math.sqrt(math.pi / (4.0 * e0))
    assert entry.f_number == pytest.approx(n_exact, rel=0.02)
    f = paraxial_data(lens).efl_mm
    assert entry.efl_mm == pytest.approx(f, rel=0.01)
    focus = entry.closest_focus_mm
    assert focus > 10_000.0 and f * f / focus < 0.1


def test_02_its_camera_rays_light_the_film_as_the_lens_does(model, exact):
    """The camera-ray sampler over the model's passing rays, with the model's centre
    irradiance, gives the Tessar's relative illumination within 3 % from the centre to the
    full-frame corner, and E_0 within 2 % of the exact lens's."""
    lens, z, e0 = exact
    tl = load_lens_entry(model).lens
    assert tl.centre_irradiance == pytest.approx(e0, rel=0.02)
    mine = tl.sampler(21.6, bands=22, grid=48)
    theirs = RearPupilSampler(lens, 21.6, sensor_z=z, bands=22, grid=48)
    n = 40_000
    u = np.random.default_rng(3).random((3, n))
    wl = np.full(n, 587.5618)
    for h in (0.0, 0.7, 3.0, 8.0, 14.0, 21.0):
        s = mine.sample(np.full(n, h), np.zeros(n), u[0], u[1], u[2], wl)
        a = float(np.mean(s.weight * tl.passes(s.rays))) / tl.centre_irradiance
        s = theirs.sample(np.full(n, h), np.zeros(n), u[0], u[1], u[2], wl)
        b = float(np.mean(s.weight * trace(lens, s.rays, from_sensor=True).valid)) / e0
        assert a == pytest.approx(b, rel=0.03), h


def _settings(path, **kw):
    base = dict(camera="Cam", lens_path=str(path), lens_id=None, model="auto", f_number=2.0,
                focus_distance_mm=3000.0)
    base.update(kw)
    return CameraSettings(**base)


@pytest.mark.parametrize("asked", ["auto", "learned", "exact", "thin"])
def test_03_every_model_setting_renders_the_table_through_its_model_and_says_why(model,
                                                                                  asked):
    """Whatever model the camera asks for, the table lens resolves to its learned model at the
    table's focus and aperture, the choice says why (a ray table, whatever its cost), and the
    messages say that the camera's F-Stop and focus distance do not apply; asking for the
    exact or thin lens is a warning."""
    setup = resolve_camera(_settings(model, model=asked))
    assert setup.model == "learned" and setup.model_dir == str(model)
    assert setup.choice.reason.lower() == TABLE_WHY
    said = " | ".join(t for _level, t in setup.messages)
    assert "F-Stop (f/2)" in said and "focus distance does not change it" in said
    warned = any(level == "WARNING" and "ray table" in t for level, t in setup.messages)
    assert warned == (asked in ("exact", "thin"))
    entry = load_lens_entry(model)
    assert setup.f_number == entry.f_number and setup.focus_mm == entry.closest_focus_mm
    assert setup.sensor_z_mm == entry.lens.sensor_z
    assert setup.as_dict()["choice_why"].lower() == TABLE_WHY


def test_04_ghosts_need_surfaces_and_say_so(model):
    """Ghosts follow the lens's surfaces: on a ray table they are off, with a warning."""
    from neurolens_addon.camera.settings import GhostSettings
    setup = resolve_camera(_settings(model, ghosts=GhostSettings(enabled=True)))
    assert setup.ghosts is None
    assert any("Ghosts follow the lens's surfaces" in t for _l, t in setup.messages)


def test_05_a_model_of_a_lens_file_or_no_model_is_no_lens(tmp_path):
    """A model learned from a lens file is not a lens (its lens file is): one clear error
    naming it; a .neurolens folder without model.json is refused naming the folder."""
    shipped = PRESET_MODELS_DIR / "tessar_f4_5.neurolens"
    with pytest.raises(ModelError, match="learned from a lens file"):
        load_lens_entry(shipped)
    empty = tmp_path / "nothing.neurolens"
    empty.mkdir()
    with pytest.raises((LensError, ModelError), match="nothing.neurolens"):
        load_lens_entry(empty)


#: pixels a millimetre at 1920 px across a full-frame sensor (issue 32's accuracy figure)
PX_PER_MM = 1920.0 / 36.0


def test_06_its_chief_rays_are_the_lenss(model, exact):
    """With no stop to pass through, the table lens's chief ray from a film point is aimed at
    the centroid of that point's passing rays, through the model, and their angles smoothed
    by an odd polynomial in the film radius (the model's directions err by ~1e-4 rad, 0.55 px
    unsmoothed): its film radius for each field angle is the Tessar's chief ray's within
    0.1 px at 1920 px across 36 mm (measured 0.079 px), the pinhole's focal length (the
    paraxial limit of its chief rays) within 0.05 % of the exact table's (measured 0.016 %),
    and where its chief lines meet the axis (the entrance pupil, for parallax) within 1 mm
    over the field."""
    from neurolens_addon.core.stmap import chief_ray_table
    lens, z, _e0 = exact
    mine = load_lens_entry(model).lens.chief_ray_table(21.6)
    theirs = chief_ray_table(lens, z, 21.6)
    assert mine.r_max == pytest.approx(21.6)
    theta = np.linspace(0.0, min(mine.theta[-1], theirs.theta[-1]), 400)
    dr = np.interp(theta, mine.theta, mine.r_mm) - np.interp(theta, theirs.theta, theirs.r_mm)
    assert np.max(np.abs(dr)) * PX_PER_MM < 0.1
    assert mine.f_p_mm == pytest.approx(theirs.f_p_mm, rel=5e-4)
    pupil = np.interp(mine.r_mm, theirs.r_mm, theirs.axis_z)
    assert np.max(np.abs(mine.axis_z - pupil)) < 1.0


def test_07_a_table_lens_camera_writes_st_maps_and_lens_data(model, exact):
    """A camera on the table lens gets ST-maps (camera.stmaps, what the render command's
    --stmap and the panel write): its undistort map samples the lens image where the exact
    Tessar's does within 0.06 px over a 480x320 frame of 36 mm (measured 0.029 px; 0.12 px
    at 1920x1280), its distort map undoes it within 0.05 px, and its lens
    data give its measured focal length and working f-number, the pinhole's focal length
    and the entrance pupil from its chief rays (the exact Tessar's within 0.1 % and 1 mm),
    with the fitted distortion models."""
    from neurolens_addon.camera.stmaps import camera_maps, frame_lens_data
    from neurolens_addon.core.stmap import MapFrame, chief_ray_table, st_map
    lens, z, _e0 = exact
    from neurolens_addon.core.film import FilmSettings
    setup = resolve_camera(_settings(model, film=FilmSettings(resolution_x=480,
                                                               resolution_y=320)))
    und, header, meta = camera_maps(setup, "undistort")
    dist, _h, _m = camera_maps(setup, "distort")
    frame = MapFrame(480, 320, 36.0)
    want = st_map(chief_ray_table(lens, z, frame.film_radius_mm), frame, "undistort")
    ok = (und[..., 2] > 0) & (want[..., 2] > 0)
    assert ok.mean() > 0.99
    err = np.hypot((und[..., 0] - want[..., 0]) * 480, (und[..., 1] - want[..., 1]) * 320)
    assert np.max(err[ok]) < 0.06
    # round trip: the distort map read at where the undistort map points
    h, w = und.shape[:2]
    x = und[..., 0] * w - 0.5
    y = und[..., 1] * h - 0.5
    inside = ok & (x > 1) & (x < w - 2) & (y > 1) & (y < h - 2)
    i, j = np.floor(x[inside]).astype(int), np.floor(y[inside]).astype(int)
    fx, fy = x[inside] - i, y[inside] - j

    def bilinear(c):
        a = dist[..., c]
        return ((1 - fx) * (1 - fy) * a[j, i] + fx * (1 - fy) * a[j, i + 1]
                + (1 - fx) * fy * a[j + 1, i] + fx * fy * a[j + 1, i + 1])
    yy, xx = np.nonzero(inside)
    back = np.hypot(bilinear(0) * w - (xx + 0.5), bilinear(1) * h - (yy + 0.5))
    assert np.max(back) < 0.05
    entry = load_lens_entry(model)
    assert meta["paraxial_focal_length_mm"] == pytest.approx(entry.efl_mm, rel=1e-9)
    assert meta["pinhole_focal_length_mm"] == pytest.approx(
        chief_ray_table(lens, z, 21.6).f_p_mm, rel=5e-4)
    pupil = paraxial_data(lens).entrance_pupil.z_mm - z
    assert meta["entrance_pupil_from_sensor_mm"] == pytest.approx(pupil, abs=1.0)
    assert meta["design_f_number"] == pytest.approx(setup.f_number)
    assert header["neurolens/lens"] == entry.name
    assert meta["distortion"]["brown_conrady"]["max_residual_px"] < 0.01
    data = frame_lens_data(setup)
    assert data["distortion"]["brown_conrady"]["k1"] == pytest.approx(
        meta["distortion"]["brown_conrady"]["k1"], rel=0.05, abs=1e-4)
