"""Every shipped preset: first-order data as designed, and stability at the extremes."""

import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.field import field_beam, half_field_deg, image_height_mm
from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace
from neurolens_addon.core.variable_gaps import focus_position, lens_at

PRESETS = sorted((Path(__file__).resolve().parents[2] / "presets" / "lenses").glob("*.toml"))
IDS = [p.stem for p in PRESETS]


@pytest.fixture(scope="module", params=PRESETS, ids=IDS)
def lens(request):
    return load_lens(request.param)


def extreme_rays(lens, n=30000, seed=0):
    """Sensor rays at the extremes: aimed at the rim of every surface, beyond the field,
    grazing, and at 380 / 780 nm."""
    rng = np.random.default_rng(seed)
    zs = lens.vertex_z
    o = np.zeros((3, n))
    half = 2.0 * paraxial_data(lens).efl_mm
    o[0], o[1] = rng.uniform(-half, half, (2, n))
    o[2] = rng.uniform(-1.0, 0.0, n)
    k = rng.integers(0, len(lens.surfaces), n)
    sd = np.array([s.semi_diameter_mm for s in lens.surfaces])[k]
    phi = rng.uniform(0, 2 * np.pi, n)
    rim = sd * rng.choice([1.0, 1.0 - 1e-12, 1.0 + 1e-12, 0.5, 1.5], n)
    tgt = np.stack([rim * np.cos(phi), rim * np.sin(phi), zs[k]])
    # A third aimed through the stop, so that some rays pass even a fisheye's small stop.
    m = n // 3
    ps = lens.stop_index
    rr = lens.stop_radius_mm * np.sqrt(rng.random(m))
    tgt[:, :m] = np.stack([rr * np.cos(phi[:m]), rr * np.sin(phi[:m]), np.full(m, zs[ps])])
    o[:2, :m] *= 0.2
    d = tgt - o
    d[2, m: m + n // 10] = 1e-9     # grazing: almost parallel to the sensor
    wl = rng.choice([380.0, 780.0, 587.5618], n)
    return Rays(o, d, wl)


def test_01_first_order_data_match_the_design(lens):
    """Paraxial EFL within 2 % and f-number within 5 % of what the source states; the design
    image plane is at the paraxial focus within 1 % of the EFL. A preset whose source states
    its back focus (every one added to the library since) reproduces EFL, f-number and back
    focus within 1 %."""
    pd = paraxial_data(lens)
    tol = 0.02 if lens.back_focus_mm is None else 0.01
    assert pd.efl_mm == pytest.approx(lens.focal_length_mm, rel=tol)
    assert pd.f_number == pytest.approx(lens.f_number, rel=0.05 if tol == 0.02 else 0.01)
    if lens.back_focus_mm is not None:
        assert pd.bfd_mm == pytest.approx(lens.back_focus_mm, rel=0.01)
    assert abs(pd.rear_focal_z_mm) < 0.01 * pd.efl_mm


def test_02_extreme_rays_are_finite_or_flagged(lens):
    """Rays at every rim, grazing, beyond the field and at 380/780 nm give finite unit
    directions when valid and zeros when flagged; never NaN or inf."""
    res = trace(lens, extreme_rays(lens))
    assert np.isfinite(res.rays.o).all() and np.isfinite(res.rays.d).all()
    v = res.valid
    assert v.any()
    np.testing.assert_allclose(np.linalg.norm(res.rays.d[:, v], axis=0), 1.0, atol=1e-9)
    assert (res.status[~v] > 0).all()
    assert not res.rays.o[:, ~v].any()


def test_03_closed_down_stop_and_both_focus_limits(lens):
    """Focus at infinity and at the closest focus converge; at F/32 rays still pass, and the
    spot of an axial point at the closest focus is small at that sensor position."""
    z_inf = focus_sensor_z(lens, math.inf)
    near = closest_focus_mm(lens)
    if lens.focus_gaps is None:            # unit focusing: the sensor moves back
        z_near = focus_sensor_z(lens, near)
        assert z_near < z_inf
    else:                                  # moving groups focus; the sensor stays put
        moved = lens_at(lens, focus=focus_position(lens, near))
        z_near = focus_sensor_z(moved, near)
        assert abs(z_near - z_inf) < 0.01 * lens.focal_length_mm
    stop32 = lens.stop_radius_mm * lens.f_number / 32.0
    r_ep32 = 0.5 * paraxial_data(lens).entrance_pupil.diameter_mm * lens.f_number / 32.0
    res = trace(lens, field_beam(lens, 0.0, 2500, two_d=False, span=1.5 * r_ep32),
                from_sensor=False, sensor_z=z_inf, stop_radius=stop32)
    assert 0 < res.valid.sum() < 2500
    r = np.hypot(res.rays.o[0, res.valid], res.rays.o[1, res.valid])
    assert r.max() < 0.05            # F/32 spot at the infinity focus: under 50 um


def test_04_edge_of_field_reaches_the_image(lens):
    """A beam from 98 % of the lens's half field reaches the sensor, farther out than one from
    half the field (the image height grows over the whole field, fisheye edge included)."""
    hf = half_field_deg(lens)
    h_half = image_height_mm(lens, 0.5 * hf)
    h_edge = image_height_mm(lens, 0.98 * hf)
    assert math.isfinite(h_edge) and h_edge > h_half > 0


def test_05_wavelength_extremes_pass_and_disperse(lens):
    """At 380 and 780 nm a nearly closed stop (F/64) focuses, and the exact axial colour (the
    focus shift from 780 to 380 nm) matches the paraxial one within 3 % + 2 um: exact and
    first-order optics agree, and dispersion is modelled. An anamorphic lens's best focus lies
    midway between its two meridians' line foci (the circle of least confusion): the paraxial
    focus is their mean."""
    stop64 = lens.stop_radius_mm * lens.f_number / 64.0
    exact = [focus_sensor_z(lens, math.inf, wavelength_nm=wl, stop_radius=stop64)
             for wl in (380.0, 780.0)]
    meridians = ("y", "x") if lens.anamorphic else ("y",)
    parax = [np.mean([paraxial_data(lens, wl, meridian=m).rear_focal_z_mm for m in meridians])
             for wl in (380.0, 780.0)]
    shift, shift_p = exact[0] - exact[1], parax[0] - parax[1]
    assert abs(shift_p) > 1e-3
    assert abs(shift - shift_p) < 0.03 * abs(shift_p) + 0.002


def test_06_fisheye_covers_at_least_150_degrees():
    """The fisheye preset passes rays from 75 degrees off axis (150 degree full field)."""
    fish = [load_lens(p) for p in PRESETS if "fisheye" in p.stem]
    assert fish
    for lens in fish:
        assert lens.field_of_view_deg >= 150
        assert math.isfinite(image_height_mm(lens, 75.0))
