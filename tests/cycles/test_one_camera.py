"""Every renderer renders the camera the set-up resolved: for every preset at every tabulated
zoom position (and one between two), every tabulated focus position (or two distances for a
lens that focuses as a unit), wide open and stopped down, the stop radius, sensor plane and
centre irradiance the Cycles shader is generated with are the derived camera's (the constants
in its text: the stop test's 1 / R, the sensor plane the rays start on, the pupil weight's
1 / (E_0 dz^2)), and the NeuroLens engine's camera-ray generator uses the same values; the
stop radius is the one the configured lens's own design f-number gives (a zoom's iris opens as
it zooms: not the wide end's f-number scaled again)."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from neurolens_addon.camera import CameraSettings, resolve_camera
from neurolens_addon.camera.lenses import PRESETS_DIR
from neurolens_addon.core import pupil, pupil_slabs
from neurolens_addon.core.aperture import stop_radius_of
from neurolens_addon.core.film import FilmSettings
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.oslfmt import flt
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.cycles import CameraSpec, generate_osl
from neurolens_addon.cycles.follow import lens_state
from neurolens_addon.engine.camera_rays import CameraRayGenerator, make_evaluator

PRESETS = sorted(p.stem for p in PRESETS_DIR.glob("*.toml"))
#: a small frame: the film's size sets the pupil tables, not what is checked
FILM = FilmSettings(sensor_width=36.0, sensor_height=24.0, resolution_x=48, resolution_y=32)


def _positions(lens):
    """[(zoom focal length or nan, focus distance mm)] the preset is checked at."""
    zooms = [math.nan]
    if lens.zoom_gaps is not None:
        f = list(lens.zoom_gaps.positions)
        zooms = f + [0.5 * (f[0] + f[1])]                      # and one between positions
    if lens.focus_gaps is not None:
        focus = list(lens.focus_gaps.positions)                 # inf first, then nearer
    else:
        focus = [math.inf, 2000.0]
    return [(z, d) for z in zooms for d in focus]


def _setups(name):
    """The preset's set-ups: at each position wide open (an f-stop wider than the lens is
    clamped to its widest there) and stopped down 2.5 times."""
    path = str(PRESETS_DIR / f"{name}.toml")
    lens = load_lens(path)
    for zoom, focus in _positions(lens):
        settings = CameraSettings(camera="cam", lens_path=path, model="exact", f_number=0.5,
                                  focus_distance_mm=focus, zoom_mm=zoom, dispersion=False,
                                  film=FILM)
        wide = resolve_camera(settings)
        yield wide
        yield resolve_camera(dataclasses.replace(settings, f_number=2.5 * wide.f_number))


def _constant(src: str, pattern: str) -> str:
    found = re.findall(pattern, src)
    assert len(set(found)) == 1, (pattern, found[:3])
    return found[0]


@pytest.fixture(autouse=True)
def small_pupil_tables(monkeypatch):
    """Coarse slab tables and engine sampler grids: their size does not change which
    constants are written or which fields the generator reads."""
    monkeypatch.setattr(pupil_slabs, "BANDS", 4)
    monkeypatch.setattr(pupil_slabs, "GRID", 16)
    monkeypatch.setattr(pupil, "SAMPLER_BANDS", 4)
    monkeypatch.setattr(pupil, "SAMPLER_GRID", 16)
    monkeypatch.setattr(pupil, "SAMPLER_COARSE_GRID", 24)


@pytest.mark.slow
@pytest.mark.parametrize("name", PRESETS)
def test_the_cycles_shader_and_the_engine_use_the_derived_camera(name):
    """(Module docstring.) The engine's generator is built for the first and the last set-up
    of each preset (its pupil grids are costly; every generator reads the same fields)."""
    setups = list(_setups(name))
    for k, setup in enumerate(setups):
        c = setup.derived
        where = f"{name} at {setup.entry.efl_mm:.2f} mm, f/{setup.f_number:g}, " \
                f"{setup.focus_mm:g} mm"
        # the derived camera: the configured lens's own stop and design f-number
        assert c.lens.content_hash() == setup.lens.content_hash(), where
        assert c.design_f_number == setup.entry.f_number, where
        assert c.stop_radius_mm == pytest.approx(stop_radius_of(c.lens, setup.f_number),
                                                 rel=1e-12), where
        # Cycles: the spec copies it, the shader is written with it
        spec = CameraSpec.from_setup(setup)
        assert (spec.stop_radius, spec.sensor_z_mm, spec.normalisation) == (
            c.stop_radius_mm, c.sensor_z_mm, c.centre_irradiance), where
        src = generate_osl(spec)
        assert _constant(src, r"nl_inside_stop\(p\[0\] \* ([-\d.e+]+),") == \
            flt(1.0 / c.stop_radius_mm), where
        assert _constant(src, r"point p = point\(sx, sy, ([-\d.e+]+)\);") == \
            flt(c.sensor_z_mm), where
        head = re.search(r"stop radius ([\d.e+-]+) mm \(f/[\d.]+\), sensor z ([\d.e+-]+) mm, "
                         r"centre irradiance ([\d.e+-]+)", src)
        assert [float(v) for v in head.groups()] == pytest.approx(
            [c.stop_radius_mm, c.sensor_z_mm, c.centre_irradiance], rel=1e-8), where
        if c.lens.anamorphic:
            assert f"lw *= {flt(1.0 / c.centre_irradiance)};" in src, where
        else:
            table = lens_state(spec).table
            dz = table.plane_z - c.sensor_z_mm
            assert _constant(src, r"weight = area \* cz2 \* cz2 \* ([-\d.e+]+);") == \
                flt(1.0 / (c.centre_irradiance * dz * dz)), where
        # the engine: its generator takes the same camera
        if k not in (0, len(setups) - 1):
            continue
        gen = CameraRayGenerator(make_evaluator(c), np.eye(4), setup.mm_per_unit)
        assert gen.g0 == c.centre_irradiance and gen.sampler.sensor_z == c.sensor_z_mm, where
        assert gen.evaluator.camera.stop_radius_mm == c.stop_radius_mm, where


def test_a_zoom_wide_open_is_its_stated_f_number_at_every_tabulated_focal_length():
    """The RF 24-70 f/2.8 (stated F/2.91 at 24.72 / 44.86 / 67.89 mm): wide open, the derived
    camera's stop gives the paraxial f-number F/2.91 at each focal length (the fixed stop
    gave F/4.07 at the long end), and the Cycles shader clips with that stop."""
    path = str(PRESETS_DIR / "zoom_rf_24_70mm_f2_8.toml")
    for f in (24.72, 44.86, 67.89):
        setup = resolve_camera(CameraSettings(camera="cam", lens_path=path, model="exact",
                                              f_number=2.0, focus_distance_mm=math.inf,
                                              zoom_mm=f, dispersion=False, film=FILM))
        c = setup.derived
        pd = paraxial_data(c.lens)
        epd = pd.entrance_pupil.diameter_mm * c.stop_radius_mm / c.lens.stop_radius_mm
        assert pd.efl_mm / epd == pytest.approx(2.91, rel=0.005), f
        src = generate_osl(CameraSpec.from_setup(setup))
        assert _constant(src, r"nl_inside_stop\(p\[0\] \* ([-\d.e+]+),") == \
            flt(1.0 / c.stop_radius_mm), f


def test_a_following_camera_writes_its_derived_tables():
    """A camera whose focus and f-number are animated: the shader's tables are the derived
    camera's (the sensor plane and log(1 / E_0) at every focus and f-number, each the still
    camera's there), and its 1 / R is N / (R N) with R N the derived stop's."""
    from neurolens_addon.camera.setup import FocusFollow
    path = str(PRESETS_DIR / "double_gauss_50mm_f2.toml")
    setup = resolve_camera(CameraSettings(camera="cam", lens_path=path, model="exact",
                                          f_number=2.0, focus_distance_mm=1500.0,
                                          animated_focus_mm=(1000.0, 4000.0),
                                          animated_f_numbers=(2.0, 8.0), dispersion=False,
                                          film=FILM))
    assert setup.follow == FocusFollow((1000.0, 4000.0), (2.0, 8.0))
    tab = setup.derived.follow_tables
    still = resolve_camera(CameraSettings(camera="cam", lens_path=path, model="exact",
                                          f_number=float(tab.f_numbers[2]),
                                          focus_distance_mm=1.0 / float(tab.t[5]),
                                          dispersion=False, film=FILM)).derived
    assert tab.sensor_z[5, 2] == pytest.approx(still.sensor_z_mm, abs=1e-9)
    assert math.exp(tab.log_centre[5, 2]) == pytest.approx(still.centre_irradiance, rel=1e-9)
    src = generate_osl(CameraSpec.from_setup(setup))
    rn = float(tab.stop_radii[0] * tab.f_numbers[0])
    assert f"float nl_inv_R = nl_N * {flt(1.0 / rn)};" in src
    for name, values in (("NL_FOCUS_Z", tab.sensor_z), ("NL_LOG_NORM", -tab.log_centre)):
        block = src[src.index(name):].split(";", 1)[0]
        assert [float(v) for v in re.findall(r"-?[\d.]+(?:e[-+]?\d+)?", block.split("=", 1)[1])] \
            == [float(flt(v)) for v in np.ravel(values)], name


def test_a_large_mask_is_normalised_with_the_shape_the_shader_clips_with():
    """An aperture mask of 256 x 256 pixels (a fine star): the Cycles shader embeds it at 64 x
    64 (core.aperture.shader_shape), and the spec carries that shape and its own centre
    irradiance (the engine keeps the full mask and its E_0), so Cycles' image centre reads 1
    with the shape it clips with."""
    from neurolens_addon.camera.settings import ApertureSettings
    from neurolens_addon.core.aperture import ImageMaskAperture
    from neurolens_addon.core.pupil import centre_irradiance
    y, x = np.mgrid[1:-1:256j, -1:1:256j]
    star = (x * x + y * y < 0.9) & (np.abs(np.sin(12 * np.arctan2(y, x))) < 0.35)
    mask = ImageMaskAperture(star.astype(float), source="star")
    setup = resolve_camera(CameraSettings(
        camera="cam", lens_path=str(PRESETS_DIR / "double_gauss_50mm_f2.toml"),
        model="exact", f_number=2.8, focus_distance_mm=2000.0, dispersion=False, film=FILM,
        aperture=ApertureSettings("mask", mask=mask, mask_key=("star",))))
    c = setup.derived
    spec = CameraSpec.from_setup(setup)
    assert max(spec.aperture.mask.shape) == 64 and c.aperture is mask
    kw = dict(sensor_z=c.sensor_z_mm, stop_radius=c.stop_radius_mm)
    assert spec.normalisation == pytest.approx(
        centre_irradiance(c.lens, aperture=spec.aperture, **kw), rel=1e-12)
    assert c.centre_irradiance == pytest.approx(
        centre_irradiance(c.lens, aperture=mask, **kw), rel=1e-12)
    assert abs(spec.normalisation / c.centre_irradiance - 1.0) > 1e-3   # the shapes differ
