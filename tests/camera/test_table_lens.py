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
