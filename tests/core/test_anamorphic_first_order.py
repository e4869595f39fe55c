"""First-order data of anamorphic lenses whose surfaces are turned by different angles (the
x and y meridians couple: core.paraxial.first_order) against real rays through core.trace,
and the aligned lenses' figures unchanged.

Real rays here: rays parallel to the axis at heights +-H from the axis (central differences),
traced exactly; their slopes (dx/dp, dy/dp; p = -z the travel coordinate) where they leave
the lens give the linear map height -> slope, from the scene (the power matrix: slopes
-Phi h) or from the film side (the field angles a film displacement sees)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.camera.lenses import PRESETS_DIR
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data, squeeze
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.surfaces import Biconic, Cylinder, Toroidal
from neurolens_addon.core.trace import trace
from neurolens_addon.core.variable_gaps import focus_position, lens_at
from testdata.anamorphic_lenses import cylinder_attachment_lens, turned_attachment_lens

INF = math.inf
D = 587.5618
H = 1e-3                        # mm: the near-axis rays' heights (third-order terms ~1e-9)
GLASS = Material.from_abbe(1.5168, 64.17)


def crossed_cylinders(first_deg: float, second_deg: float) -> Lens:
    """Two plano-convex cylinders 15 mm apart, one powered in y, one in x, turned by the
    given angles (all the lens's power is theirs)."""
    air = Material.air()
    return Lens("crossed cylinders", "tests", 60.0, 4.0, (
        Surface(INF, 2.0, air, 6.0, stop=True),
        Surface(shape=Cylinder.make(40.0, "x", 0.0, first_deg), thickness_mm=4.0,
                material=GLASS, semi_diameter_mm=8.0),
        Surface(INF, 15.0, air, 8.0),
        Surface(shape=Cylinder.make(30.0, "y", 0.0, second_deg), thickness_mm=4.0,
                material=GLASS, semi_diameter_mm=8.0),
        Surface(INF, 40.0, air, 8.0)))


TURNED = {"attachment 0/30": lambda: turned_attachment_lens(0.0, 30.0),
          "crossed cylinders 0/30": lambda: crossed_cylinders(0.0, 30.0),
          "crossed cylinders 20/70": lambda: crossed_cylinders(20.0, 70.0)}


def real_slope_map(lens: Lens, from_sensor: bool, azimuths_deg=(0.0, 90.0)) -> np.ndarray:
    """(2, k): the leaving slope per mm of height of real rays parallel to the axis entering
    at unit directions of the given azimuths, by central differences at +-H."""
    phi = np.radians(np.asarray(azimuths_deg, dtype=np.float64))
    e = np.vstack([np.cos(phi), np.sin(phi)])
    k = e.shape[1]
    z = float(lens.vertex_z[-1]) - 5.0 if from_sensor else float(lens.vertex_z[0]) + 5.0
    o = np.vstack([np.hstack([H * e, -H * e]), np.full(2 * k, z)])
    d = np.tile(np.array([[0.0], [0.0], [1.0 if from_sensor else -1.0]]), (1, 2 * k))
    res = trace(lens, Rays(o, d, np.full(2 * k, D)), from_sensor=from_sensor,
                sensor_z=None)
    assert res.valid.all()
    slope = res.rays.d[:2] / -res.rays.d[2]
    return (slope[:, :k] - slope[:, k:]) / (2.0 * H)


def condition(m: np.ndarray) -> float:
    s = np.linalg.svd(m, compute_uv=False)
    return float(s[0] / s[-1])


@pytest.mark.parametrize("name", TURNED)
def test_01_the_squeeze_of_turned_cylinders_is_read_along_the_film(name):
    """With its cylinders turned by different angles the lens's principal axes are not x and
    y. The squeeze stays what the renderers can undo, a desqueeze along the film's x: f_y /
    f_x, the film's focal lengths (field angle per mm of film along x and along y, real rays
    traced from the film side), which equalises the desqueezed frame's angular scales along x
    and y and minimises the ratio of its largest to smallest one. (The meridians' f_y / f_x,
    the squeeze before the coupled trace, is off by 0.5 % to 9 % here.)"""
    lens = TURNED[name]()
    g = real_slope_map(lens, from_sensor=True)          # film (x, y) -> field angle
    f_x, f_y = 1.0 / np.linalg.norm(g[:, 0]), 1.0 / np.linalg.norm(g[:, 1])
    s = squeeze(lens)
    assert s == pytest.approx(f_y / f_x, rel=1e-6)
    frame = condition(g @ np.diag([1.0 / s, 1.0]))
    assert frame > 1.2                                  # the x desqueeze cannot undo it all
    for other in (0.97, 0.995, 1.005, 1.03):
        assert condition(g @ np.diag([1.0 / (s * other), 1.0])) > frame


@pytest.mark.parametrize("name", TURNED)
def test_02_turned_cylinders_principal_focal_lengths_follow_real_rays(name):
    """first_order's figures against real rays: the power matrix (rays from the scene), the
    film focal lengths (from the film side: the transpose, as the Lagrange invariant has
    it), the principal focal lengths as the extremes over the entrance azimuth of |slope| /
    height (|slope|^2 / H^2 = A + B cos 2 phi + C sin 2 phi, fitted), their axes, the twist
    (rays entering along a principal axis leave turned by it) and what the desqueeze leaves
    of the anamorphosis."""
    from neurolens_addon.core.paraxial import first_order
    lens = TURNED[name]()
    fo = first_order(lens)
    phi_real = -real_slope_map(lens, from_sensor=False)
    np.testing.assert_allclose(fo.power_matrix, phi_real, rtol=0, atol=1e-6 * abs(phi_real).max())
    assert not fo.aligned
    g = real_slope_map(lens, from_sensor=True)
    np.testing.assert_allclose(g, phi_real.T, rtol=0, atol=1e-6 * abs(phi_real).max())
    assert fo.f_x_mm == pytest.approx(1.0 / np.linalg.norm(g[:, 0]), rel=1e-6)
    assert fo.f_y_mm == pytest.approx(1.0 / np.linalg.norm(g[:, 1]), rel=1e-6)
    assert fo.squeeze == pytest.approx(fo.f_y_mm / fo.f_x_mm, rel=1e-12)

    az = np.arange(0.0, 180.0, 15.0)
    m = real_slope_map(lens, from_sensor=False, azimuths_deg=az)
    two = np.radians(2.0 * az)
    basis = np.vstack([np.ones_like(two), np.cos(two), np.sin(two)]).T
    (a, b, c), *_ = np.linalg.lstsq(basis, (m * m).sum(axis=0), rcond=None)
    strong, weak = math.sqrt(a + math.hypot(b, c)), math.sqrt(a - math.hypot(b, c))
    long_axis = math.degrees(0.5 * math.atan2(c, b)) + 90.0      # weakest slope: longest f
    f1, f2 = fo.principal_f_mm
    assert sorted([abs(f1), abs(f2)]) == pytest.approx([1.0 / strong, 1.0 / weak], rel=1e-6)
    assert -45.0 < fo.principal_axis_deg <= 45.0
    axis_of_long = fo.principal_axis_deg + (0.0 if abs(f1) > abs(f2) else 90.0)
    assert (axis_of_long - long_axis + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1e-5)
    e = np.radians(long_axis)
    out = -real_slope_map(lens, from_sensor=False, azimuths_deg=[long_axis])[:, 0]
    turned = math.degrees(math.atan2(out[1], out[0]) - e)
    assert (turned - fo.twist_deg + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1e-5)
    assert abs(fo.twist_deg) > 1.0
    frame = condition(g @ np.diag([1.0 / fo.squeeze, 1.0]))
    assert fo.frame_anamorphosis == pytest.approx(frame, rel=1e-6)


def test_03_coupled_meridians_trace_with_the_cross_curvature():
    """Cylinders turned by 20 and 70 degrees: a ray started in the x (y) meridian leaves it at
    the first and meets the second off the meridian, where the cross curvature c_xy bends it
    back into x (y). paraxial_data(meridian=m)'s focal length is the real rays' m component
    (-h / slope_m), which the trace without c_xy missed by 12 % (x) and 2 % (y)."""
    lens = crossed_cylinders(20.0, 70.0)
    phi_real = -real_slope_map(lens, from_sensor=False)
    assert paraxial_data(lens, meridian="x").efl_mm == pytest.approx(1.0 / phi_real[0, 0],
                                                                     rel=1e-6)
    assert paraxial_data(lens).efl_mm == pytest.approx(1.0 / phi_real[1, 1], rel=1e-6)


@pytest.mark.parametrize("shape", [Cylinder.make(40.0, "x", 0.0, 30.0),
                                   Cylinder.make(-25.0, "y", 0.0, -75.0),
                                   Biconic(60.0, -45.0, -0.5, 1.2, 17.0),
                                   Toroidal(35.0, -80.0, 0.3, 123.0)],
                         ids=["cylinder_30", "cylinder_-75", "biconic", "toroid"])
def test_04_the_curvature_tensor_is_the_sags_at_the_vertex(shape):
    """(c_xx, c_xy, c_yy) are the sag's second derivatives at the vertex (central
    differences at 0.01 mm: a toroid's sag cancels digits nearer the vertex)."""
    h = 1e-2
    s = lambda x, y: float(shape.sag(np.array(x), np.array(y)))   # noqa: E731
    sxx = (s(h, 0) - 2 * s(0, 0) + s(-h, 0)) / h ** 2
    syy = (s(0, h) - 2 * s(0, 0) + s(0, -h)) / h ** 2
    sxy = (s(h, h) - s(h, -h) - s(-h, h) + s(-h, -h)) / (4 * h ** 2)
    scale = max(abs(shape.paraxial_curvature), abs(shape.paraxial_curvature_x))
    assert shape.paraxial_curvature_x == pytest.approx(sxx, abs=1e-6 * scale)
    assert shape.paraxial_curvature == pytest.approx(syy, abs=1e-6 * scale)
    assert shape.paraxial_curvature_xy == pytest.approx(sxy, abs=1e-6 * scale)
    assert abs(shape.paraxial_curvature_xy) > 1e-3 * scale


#: (stem, focus distance mm) -> (squeeze, f_x, f_y) as core.paraxial gave them before the
#: coupled trace (the x and y meridians traced apart), to the last digit
ALIGNED = {
    ("anamorphic_2x_60mm_f1_9", INF): (1.9231232141835888, 31.487617838469323,
                                       60.55456882450163),
    ("anamorphic_2x_60mm_f1_9", 1000.0): (1.673777125091085, 36.17839431352387,
                                          60.55456882450163),
    ("anamorphic_attachment_speed_panchro_50mm_f2", INF): (1.92291437158622, 25.98702581365368,
                                                           49.970825411856744),
    ("anamorphic_attachment_speed_panchro_50mm_f2", 1000.0): (1.6961976511737782,
                                                              29.460496763025613,
                                                              49.970825411856744),
}


@pytest.mark.parametrize("key", ALIGNED, ids=lambda k: f"{k[0]}@{k[1]:g}")
def test_05_aligned_presets_keep_their_figures(key):
    """Every anamorphic surface of the presets is turned by a multiple of 90 degrees: the
    power matrix is diagonal, the principal axes are x and y, and the squeeze and focal
    lengths are those the separate meridians gave (to 1e-12 relative)."""
    from neurolens_addon.core.paraxial import first_order
    stem, distance = key
    lens = load_lens(PRESETS_DIR / f"{stem}.toml")
    lens = lens_at(lens, focus=focus_position(lens, distance))
    fo = first_order(lens)
    s, f_x, f_y = ALIGNED[key]
    assert fo.aligned and fo.principal_axis_deg == 0.0 and fo.twist_deg == 0.0
    assert squeeze(lens) == pytest.approx(s, rel=1e-12)
    assert (fo.f_x_mm, fo.f_y_mm) == pytest.approx((f_x, f_y), rel=1e-12)
    assert fo.principal_f_mm == pytest.approx((f_x, f_y), rel=1e-12)
    assert fo.frame_anamorphosis == pytest.approx(1.0, abs=1e-12)
    assert paraxial_data(lens, meridian="x").efl_mm == pytest.approx(f_x, rel=1e-12)
    assert paraxial_data(lens).efl_mm == pytest.approx(f_y, rel=1e-12)


def test_06_aligned_and_revolution_lenses():
    """The test attachment (cylinders unturned) keeps squeeze 1.2951 and its real rays' focal
    lengths; a lens of revolution (a preset, and the attachment's singlet alone) has squeeze
    1 exactly and f_x = f_y = its paraxial EFL on both principal axes."""
    from neurolens_addon.core.paraxial import first_order
    lens = cylinder_attachment_lens()
    fo = first_order(lens)
    assert fo.squeeze == pytest.approx(1.2951045580235852, rel=1e-12)
    phi_real = -real_slope_map(lens, from_sensor=False)
    assert (fo.f_x_mm, fo.f_y_mm) == pytest.approx((1.0 / phi_real[0, 0],
                                                    1.0 / phi_real[1, 1]), rel=1e-6)
    assert turned_attachment_lens(90.0, 90.0).anamorphic
    assert first_order(turned_attachment_lens(90.0, 90.0)).aligned
    for plain in (lens.with_surfaces(lens.surfaces[4:]),
                  load_lens(PRESETS_DIR / "cinema_speed_panchro_50mm_f2.toml"),
                  load_lens(PRESETS_DIR / "aspheric_50mm_f1_2.toml")):
        assert not plain.anamorphic
        fo = first_order(plain)
        efl = paraxial_data(plain).efl_mm
        assert squeeze(plain) == 1.0 and fo.squeeze == 1.0
        assert fo.f_x_mm == fo.f_y_mm == efl
        assert fo.principal_f_mm == (efl, efl)
        assert fo.aligned and fo.twist_deg == 0.0 and fo.frame_anamorphosis == 1.0
