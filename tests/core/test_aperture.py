"""Aperture shapes (normalised stop coordinates) and f-number handling."""

import math

import numpy as np
import pytest

from neurolens_addon.core.aperture import (
    ApertureError,
    CircularAperture,
    ImageMaskAperture,
    PolygonAperture,
    aperture_from_settings,
    clamp_f_number,
    stop_radius_for_f_number,
)
from neurolens_addon.core.np_compat import trapezoid


def _grid(n=801, r=1.05):
    x, y = np.meshgrid(np.linspace(-r, r, n), np.linspace(-r, r, n))
    return x.ravel(), y.ravel()


def _hexagon_inside(x, y, rot_deg=0.0):
    """Analytic regular hexagon of circumradius 1 with a vertex at angle rot: |p.n_k| <= cos30."""
    ok = np.ones_like(x, dtype=bool)
    for k in range(6):
        ang = math.radians(rot_deg) + math.pi / 6 + k * math.pi / 3
        ok &= x * math.cos(ang) + y * math.sin(ang) <= math.cos(math.pi / 6)
    return ok


def _chi2_uniform(ap, n=200_000, cells=20, seed=0):
    """Chi-square of sample counts over the grid cells lying fully inside the shape."""
    rng = np.random.default_rng(seed)
    x, y = ap.sample(rng.random(n), rng.random(n))
    edges = np.linspace(-1, 1, cells + 1)
    counts, _, _ = np.histogram2d(x, y, [edges, edges])
    cx, cy = np.meshgrid(edges, edges, indexing="ij")
    full = (ap.inside(cx[:-1, :-1], cy[:-1, :-1]) & ap.inside(cx[1:, :-1], cy[1:, :-1])
            & ap.inside(cx[:-1, 1:], cy[:-1, 1:]) & ap.inside(cx[1:, 1:], cy[1:, 1:]))
    cell_area = (2.0 / cells) ** 2
    expected = n * cell_area / ap.area()
    obs = counts[full]
    chi2 = np.sum((obs - expected) ** 2 / expected)
    dof = obs.size - 1
    return chi2, dof, x, y


def test_01_circle_inside_area_and_samples():
    """The circle: inside is the unit disc, area pi, concentric samples inside and uniform."""
    ap = CircularAperture()
    x, y = _grid()
    assert np.array_equal(ap.inside(x, y), x * x + y * y <= 1.0)
    assert ap.area() == math.pi and ap.bounding_radius() == 1.0
    chi2, dof, sx, sy = _chi2_uniform(ap)
    assert np.all(ap.inside(sx, sy))
    assert chi2 < dof + 5 * math.sqrt(2 * dof)


def test_02_hexagon_inside_matches_analytic():
    """6 blades, no curvature: inside() equals the analytic hexagon (vertex on +x)."""
    ap = PolygonAperture(6)
    x, y = _grid()
    ref = _hexagon_inside(x, y)
    got = ap.inside(x, y)
    # allow disagreement only within 1e-9 of an edge (rounding on the boundary itself)
    normals = math.pi / 6 + np.arange(6) * math.pi / 3
    dist = np.min([np.abs(x * math.cos(a) + y * math.sin(a) - math.cos(math.pi / 6))
                   for a in normals], axis=0)
    assert np.array_equal(got[dist > 1e-9], ref[dist > 1e-9])


def test_03_hexagon_area():
    """The hexagon's area is 3 sqrt(3) / 2 for circumradius 1."""
    assert PolygonAperture(6).area() == pytest.approx(3 * math.sqrt(3) / 2, rel=1e-14)
    for n in (3, 5, 9, 16):
        assert PolygonAperture(n).area() == pytest.approx(0.5 * n * math.sin(2 * math.pi / n),
                                                          rel=1e-14)


@pytest.mark.parametrize("blades,curv", [(6, 0.0), (5, 0.4), (3, 0.8), (9, 1.0)])
def test_04_polygon_samples_uniform_and_inside(blades, curv):
    """Polygon samples all lie inside and are uniform (chi-square over grid cells, fixed seed)."""
    ap = PolygonAperture(blades, rotation_deg=17.0, curvature=curv)
    chi2, dof, sx, sy = _chi2_uniform(ap)
    assert np.all(ap.inside(sx, sy))
    assert chi2 < dof + 5 * math.sqrt(2 * dof), (chi2, dof)


def test_05_rotation_rotates():
    """Rotating the iris by t degrees rotates inside() by t degrees."""
    t = math.radians(23.0)
    x, y = _grid(401)
    a = PolygonAperture(5, rotation_deg=0.0, curvature=0.3)
    b = PolygonAperture(5, rotation_deg=23.0, curvature=0.3)
    xr, yr = x * math.cos(t) - y * math.sin(t), x * math.sin(t) + y * math.cos(t)
    assert np.mean(a.inside(x, y) != b.inside(xr, yr)) < 1e-4
    vb = b.vertices()
    assert np.allclose(np.degrees(np.arctan2(vb[0, 1], vb[0, 0])), 23.0)
    hexa = PolygonAperture(6, rotation_deg=30.0).inside(x, y)
    assert np.mean(hexa != _hexagon_inside(x, y, 30.0)) < 1e-4


def test_06_curvature_one_is_the_circle():
    """Curvature 1 gives the circle: area pi and the same inside() as the unit disc."""
    for n in (3, 6, 8):
        ap = PolygonAperture(n, curvature=1.0)
        assert ap.area() == pytest.approx(math.pi, rel=1e-12)
        x, y = _grid(401)
        assert np.mean(ap.inside(x, y) != (x * x + y * y <= 1)) < 1e-4


def test_07_curved_area_exact_and_monotone():
    """Curved-blade area matches a fine quadrature to 1e-9 and grows with curvature."""
    prev = 0.0
    for c in (0.0, 1e-8, 0.2, 0.5, 0.8, 1.0):
        ap = PolygonAperture(7, curvature=c)
        x, y = _grid(1001, 1.0)
        counted = ap.inside(x, y).mean() * (2 + 2 / 1000) ** 2
        assert abs(ap.area() - counted) < 5e-3
        beta = np.linspace(-math.pi / 7, math.pi / 7, 200_001)
        r = ap._r_max(beta)
        quad = 7 * trapezoid(0.5 * r * r, beta)
        assert abs(ap.area() - quad) < 1e-9
        assert ap.area() >= prev
        prev = ap.area()


def _ring(n=256, r_out=0.8, r_in=0.4):
    c = -1 + (2 * np.arange(n) + 1) / n
    x, y = np.meshgrid(c, -c)  # row 0 at the top (y = +1)
    r = np.hypot(x, y)
    return ((r <= r_out) & (r >= r_in)).astype(np.float32)


def test_08_mask_ring_area_and_inside():
    """A synthetic ring mask: area ~ pi (R^2 - r^2) and inside() right away from the edges."""
    ap = ImageMaskAperture(_ring())
    assert ap.area() == pytest.approx(math.pi * (0.8 ** 2 - 0.4 ** 2), rel=0.01)
    x, y = _grid(501, 1.0)
    r = np.hypot(x, y)
    far = (np.abs(r - 0.8) > 0.02) & (np.abs(r - 0.4) > 0.02)
    ref = (r <= 0.8) & (r >= 0.4)
    assert np.array_equal(ap.inside(x, y)[far], ref[far])
    assert 0.8 <= ap.bounding_radius() <= 0.8 + 2 * math.sqrt(2) / 256


def test_09_mask_samples_on_the_ring():
    """Mask samples fall on the ring (>= 99.5 % inside), spread evenly over its angle."""
    ap = ImageMaskAperture(_ring())
    rng = np.random.default_rng(9)
    x, y = ap.sample(rng.random(100_000), rng.random(100_000))
    assert np.mean(ap.inside(x, y)) > 0.995
    r = np.hypot(x, y)
    assert np.all((r > 0.4 - 0.012) & (r < 0.8 + 0.012))
    counts, _ = np.histogram(np.arctan2(y, x), np.linspace(-np.pi, np.pi, 9))
    assert np.all(np.abs(counts / counts.mean() - 1) < 0.03)


def test_10_mask_orientation_and_soft_transmittance():
    """Row 0 is the top (+y); transmittance interpolates soft values bilinearly."""
    m = np.zeros((4, 4))
    m[0, 3] = 1.0  # top-right pixel
    ap = ImageMaskAperture(m)
    assert ap.inside(0.75, 0.75) and not ap.inside(0.75, -0.75) and not ap.inside(-0.75, 0.75)
    soft = ImageMaskAperture(np.array([[0.0, 1.0]]))
    assert soft.transmittance(0.0, 0.0) == pytest.approx(0.5)
    assert soft.transmittance(-0.5, 0.0) == 0.0 and soft.transmittance(0.5, 0.3) == 1.0
    assert soft.transmittance(1.5, 0.0) == 0.0


def test_11_nan_is_outside():
    """NaN or infinite coordinates are never inside, for every shape."""
    bad_x = np.array([np.nan, 0.0, np.inf, np.nan])
    bad_y = np.array([0.0, np.nan, 0.0, np.nan])
    for ap in (CircularAperture(), PolygonAperture(6), PolygonAperture(5, 10, 0.5),
               ImageMaskAperture(_ring(32, 1.0, 0.0))):
        assert not np.any(ap.inside(bad_x, bad_y))
        assert np.all(ap.transmittance(bad_x, bad_y) == 0.0)


def test_12_f_number_stop_radius():
    """Stopping down scales the stop radius by design_N / N."""
    assert stop_radius_for_f_number(10.0, 2.0, 4.0) == pytest.approx(5.0)
    assert stop_radius_for_f_number(10.0, 2.0, 2.0) == pytest.approx(10.0)


def test_13_f_number_too_wide_message():
    """An f-number wider than the design raises ValueError naming both; clamp returns a message."""
    with pytest.raises(ValueError, match=r"f/1\.4.*f/2") as exc:
        stop_radius_for_f_number(10.0, 2.0, 1.4)
    assert isinstance(exc.value, ApertureError)
    value, msg = clamp_f_number(1.4, 2.0)
    assert value == 2.0 and "1.4" in msg and "2" in msg
    assert clamp_f_number(5.6, 2.0) == (5.6, None)


def test_14_factory():
    """aperture_from_settings builds each shape and rejects bad settings with ValueError."""
    assert isinstance(aperture_from_settings("CIRCLE", 0, 0, 0), CircularAperture)
    poly = aperture_from_settings("polygon", 7, 12.0, 0.25)
    assert isinstance(poly, PolygonAperture) and poly.blades == 7 and poly.curvature == 0.25
    with pytest.raises(ValueError, match="blades"):
        aperture_from_settings("polygon", 2, 0, 0)
    with pytest.raises(ValueError, match="curvature"):
        aperture_from_settings("polygon", 6, 0, 1.5)
    with pytest.raises(ValueError, match="shape"):
        aperture_from_settings("star", 6, 0, 0)


def test_15_factory_mask_file(tmp_path):
    """A PNG mask is read as luminance; a missing or invalid file raises ValueError naming it."""
    import matplotlib.image as mpimg

    rgb = np.zeros((64, 64, 3))
    rgb[..., 1] = _ring(64)  # pure green ring: luminance 0.7152 > 0.5
    path = tmp_path / "ring.png"
    mpimg.imsave(path, rgb)
    ap = aperture_from_settings("image", 0, 0, 0, mask_path=str(path))
    assert isinstance(ap, ImageMaskAperture)
    assert ap.inside(0.6, 0.0) and not ap.inside(0.0, 0.0)
    assert ap.area() == pytest.approx(0.7152 * math.pi * (0.8 ** 2 - 0.4 ** 2), rel=0.03)
    bad = tmp_path / "not_an_image.png"
    bad.write_text("hello")
    for p in (bad, tmp_path / "missing.png"):
        with pytest.raises(ValueError, match=p.name):
            aperture_from_settings("image", 0, 0, 0, mask_path=str(p))
    with pytest.raises(ValueError, match="black"):
        ImageMaskAperture(np.zeros((8, 8)))
