"""Exact sequential trace: optical properties and stability at the extremes."""

import math

import numpy as np
import pytest

from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.core.trace import trace

from tests.core.lenses import INF, double_gauss, singlet


def parallel_rays(heights_x, z=500.0, wl=587.5618, heights_y=None):
    hx = np.asarray(heights_x, dtype=float)
    hy = np.zeros_like(hx) if heights_y is None else np.asarray(heights_y, dtype=float)
    o = np.stack([hx, hy, np.full_like(hx, z)])
    d = np.zeros_like(o)
    d[2] = -1.0
    return Rays(o, d, np.full(hx.size, float(wl)))


def sensor_rays(n, lens, seed=0, field=15.0, wl=(450.0, 650.0)):
    """Random rays from the sensor aimed at the rear element."""
    rng = np.random.default_rng(seed)
    o = np.zeros((3, n))
    o[0], o[1] = rng.uniform(-field, field, (2, n))
    r = np.sqrt(rng.random(n)) * lens.surfaces[-1].semi_diameter_mm
    ph = rng.random(n) * 2 * np.pi
    tgt = np.stack([r * np.cos(ph), r * np.sin(ph), np.full(n, lens.rear_vertex_z)])
    d = tgt - o
    d /= np.linalg.norm(d, axis=0)
    return Rays(o, d, rng.uniform(*wl, n))


def test_01_thin_singlet_matches_lensmakers_equation():
    """Paraxial EFL of a thin bi-convex singlet equals the thick-lens lensmaker's equation, and
    exact near-axis parallel rays cross the axis at the paraxial focus."""
    n, r, t = 1.5, 100.0, 0.5
    lens = singlet(radius=r, thickness=t, nd=n)
    f = 1.0 / ((n - 1) * (2.0 / r - (n - 1) * t / (n * r * r)))
    pd = paraxial_data(lens)
    assert pd.efl_mm == pytest.approx(f, rel=1e-12)
    assert pd.efl_mm == pytest.approx(r / (2 * (n - 1)), rel=5e-3)   # thin-lens limit
    res = trace(lens, parallel_rays([1e-3, -1e-3]), from_sensor=False, sensor_z=0.0)
    assert res.valid.all()
    np.testing.assert_allclose(res.rays.o[0], 0.0, atol=1e-8)


def test_02_forward_then_back_returns_to_start():
    """A ray traced sensor -> scene, reversed and traced scene -> sensor returns to its start."""
    lens = double_gauss()
    rays = sensor_rays(5000, lens)
    out = trace(lens, rays)
    v = out.valid
    assert v.mean() > 0.2
    back = Rays(out.rays.o[:, v], -out.rays.d[:, v], out.rays.wavelength[v])
    ret = trace(lens, back, from_sensor=False, sensor_z=0.0)
    assert ret.valid.all()
    np.testing.assert_allclose(ret.rays.o[:2], rays.o[:2, v], atol=1e-9)
    np.testing.assert_allclose(ret.rays.d, -rays.d[:, v], atol=1e-11)


def test_03_centre_ray_stays_on_axis():
    """The ray along the axis leaves along the axis, at every wavelength."""
    lens = double_gauss()
    wl = np.array([380.0, 587.56, 780.0])
    o = np.zeros((3, 3))
    d = np.zeros((3, 3))
    d[2] = 1.0
    res = trace(lens, Rays(o, d, wl))
    assert res.valid.all()
    np.testing.assert_array_equal(res.rays.o[:2], 0.0)
    np.testing.assert_array_equal(res.rays.d[:2], 0.0)
    np.testing.assert_allclose(res.rays.d[2], 1.0)


def test_04_symmetric_lens_gives_symmetric_spots():
    """Mirroring a ray bundle in x mirrors the image; rotating it by 90 degrees rotates it."""
    lens = double_gauss()
    rng = np.random.default_rng(3)
    n = 2000
    px, py = rng.uniform(-8, 8, (2, n))
    field = math.radians(12.0)
    def bundle(ax, ay, dx, dy):
        o = np.stack([ax, ay, np.full(n, 80.0)])
        d = np.stack([np.full(n, dx), np.full(n, dy), np.full(n, -1.0)])
        return Rays(o, d / np.linalg.norm(d, axis=0), np.full(n, 550.0))
    t = math.tan(field)
    a = trace(lens, bundle(px, py, 0.0, t), from_sensor=False)
    b = trace(lens, bundle(-px, py, 0.0, t), from_sensor=False)
    c = trace(lens, bundle(-py, px, -t, 0.0), from_sensor=False)
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_array_equal(a.valid, c.valid)
    v = a.valid
    assert v.sum() > 500
    np.testing.assert_allclose(b.rays.o[0, v], -a.rays.o[0, v], atol=1e-10)
    np.testing.assert_allclose(b.rays.o[1, v], a.rays.o[1, v], atol=1e-10)
    np.testing.assert_allclose(c.rays.o[0, v], -a.rays.o[1, v], atol=1e-10)
    np.testing.assert_allclose(c.rays.o[1, v], a.rays.o[0, v], atol=1e-10)


def test_05_invalid_rays_are_flagged_never_nan():
    """NaN, infinite, zero-length, backward and wild rays come back flagged, with finite zeros."""
    lens = double_gauss()
    rng = np.random.default_rng(5)
    n = 20000
    o = rng.normal(0, 50, (3, n))
    d = rng.normal(0, 1, (3, n))
    wl = rng.uniform(300, 900, n)
    o[0, :100] = np.nan
    d[1, 100:200] = np.inf
    d[:, 200:300] = 0.0
    wl[300:400] = np.nan
    d[2, 300:400] = np.abs(d[2, 300:400]) + 0.1   # otherwise fine: only the wavelength is bad
    d[2, 400:500] = -1.0          # pointing away from the lens
    res = trace(lens, Rays(o, d, wl))
    assert np.isfinite(res.rays.o).all() and np.isfinite(res.rays.d).all()
    assert np.isfinite(res.rays.wavelength).all()
    assert not res.valid[:500].any()
    assert (res.status[:300] == RayStatus.BAD_INPUT).all()
    assert (res.status[300:400] == RayStatus.BAD_WAVELENGTH).all()
    assert (res.status[~res.valid] != 0).all()
    assert (res.status[res.valid] == 0).all()
    np.testing.assert_allclose(np.linalg.norm(res.rays.d[:, res.valid], axis=0), 1.0, atol=1e-12)


def test_06_grazing_incidence_is_finite():
    """Rays grazing a steep surface either refract or are flagged; none gives NaN."""
    lens = singlet(radius=21.0, thickness=8.0, nd=1.9, sd=20.0, stop_radius=20.0)
    h = np.linspace(-20.0, 20.0, 4001)
    res = trace(lens, parallel_rays(h), from_sensor=False)
    assert np.isfinite(res.rays.o).all()
    assert res.valid.any() and not res.valid.all()
    assert set(np.unique(res.status)) <= {0, RayStatus.CLIPPED_APERTURE,
                                          RayStatus.TOTAL_INTERNAL_REFLECTION,
                                          RayStatus.MISSED_SURFACE, RayStatus.CLIPPED_STOP}


def test_07_ray_exactly_at_semi_diameter_passes_and_beyond_is_clipped():
    """A ray hitting a flat surface exactly at its semi-diameter is kept; 1e-9 mm more is not."""
    glass = Material.from_abbe(1.5, None)
    lens = Lens("slab", "tests", 1e9, 1.0, (
        Surface(INF, 1.0, Material.air(), 10.0, stop=True),
        Surface(INF, 5.0, glass, 10.0), Surface(INF, 10.0, Material.air(), 10.0)))
    res = trace(lens, parallel_rays([10.0, 10.0 + 1e-9, -10.0]), from_sensor=False)
    assert res.valid.tolist() == [True, False, True]
    assert res.status[1] in (RayStatus.CLIPPED_APERTURE, RayStatus.CLIPPED_STOP)


def test_08_total_internal_reflection_is_flagged():
    """A ray inside glass meeting a flat exit face beyond the critical angle is flagged TIR."""
    glass = Material.from_abbe(1.5, None)
    # One glass-to-air face at z = 10 (glass below it); rays start in the glass at z = 5 and
    # meet the face at 30 deg (refracts) and 50 deg (beyond the critical 41.8 deg).
    ang = np.radians([30.0, 50.0])
    o = np.stack([np.zeros(2), np.zeros(2), np.full(2, 5.0)])
    d = np.stack([np.sin(ang), np.zeros(2), np.cos(ang)])
    face = Lens("face", "tests", 1e9, 1.0, (Surface(INF, 10.0, glass, 100.0, stop=True),))
    res = trace(face, Rays(o, d, np.full(2, 550.0)))
    assert res.valid.tolist() == [True, False]
    assert res.status[1] == RayStatus.TOTAL_INTERNAL_REFLECTION
    assert np.sin(np.arccos(res.rays.d[2, 0])) == pytest.approx(1.5 * np.sin(ang[0]), rel=1e-12)


def test_09_closed_down_stop_passes_only_central_rays():
    """With the stop closed to a 0.5 mm radius (about F/25) only rays through it pass."""
    lens = double_gauss()
    rays = sensor_rays(50000, lens, seed=9, field=2.0)
    full = trace(lens, rays)
    tiny = trace(lens, rays, stop_radius=0.5)
    assert 0 < tiny.valid.sum() < 0.02 * full.valid.sum()
    assert (tiny.valid <= full.valid).all()
    assert np.isfinite(tiny.rays.o).all()


def test_10_extreme_wavelengths_focus_where_dispersion_says():
    """At 380 and 780 nm the trace is valid and a positive crown singlet focuses blue nearer."""
    lens = singlet(radius=50.0, thickness=4.0, nd=1.5168, vd=64.17)
    def focus_z(wl):
        h = np.array([1e-3])
        res = trace(lens, parallel_rays(h, wl=wl), from_sensor=False)
        assert res.valid.all()
        x, dxz = res.rays.o[0, 0], res.rays.d[0, 0] / res.rays.d[2, 0]
        return -x / dxz
    z380, z587, z780 = focus_z(380.0), focus_z(587.5618), focus_z(780.0)
    assert z380 > z587 > z780          # +z is towards the lens: blue focus is nearer the lens
    assert abs(z587) < 1e-3


def test_11_conic_surface_focuses_axial_bundle_perfectly():
    """A refracting ellipsoid with k = -1/n^2 images a parallel bundle to one point (the conic
    intersection and its normal are exact)."""
    n, r = 1.8, 20.0
    glass = Material.from_abbe(n, None)
    f_inside = n * r / (n - 1)
    lens = Lens("cartesian", "tests", f_inside, 1.0, (
        Surface(r, f_inside, glass, 15.0, conic=-1.0 / n ** 2, stop=True),))
    res = trace(lens, parallel_rays(np.linspace(-14, 14, 57)), from_sensor=False)
    assert res.valid.all()
    np.testing.assert_allclose(res.rays.o[0], 0.0, atol=1e-9)


def test_12_aspheric_intersection_matches_bisection():
    """Newton's aspheric hit point lies on the surface: its ray parameter agrees with a
    bisection root of s(t) - sag(rho(t)) to 1e-9 mm, across the aperture and at an angle."""
    from neurolens_addon.core.trace import intersect, sag
    glass = Material.from_abbe(1.6, 40.0)
    lens = Lens("asphere", "tests", 50.0, 4.0, (
        Surface(30.0, 45.0, glass, 12.0, conic=-0.7, aspheric=((4, 2e-5), (6, -3e-8), (8, 1e-10)),
                stop=True),))
    z1 = float(lens.vertex_z[0])
    hs = np.linspace(-11.0, 11.0, 45)
    angle = np.radians(7.0)
    o = np.stack([hs, np.zeros_like(hs), np.full_like(hs, 60.0)])
    d = np.stack([np.full_like(hs, np.sin(angle)), np.zeros_like(hs),
                  np.full_like(hs, -np.cos(angle))])
    t_newton, hit = intersect(lens, 0, Rays(o, d, np.full_like(hs, 550.0)))
    assert hit.all()
    for i in range(hs.size):
        def f(t):
            x = o[0, i] + t * d[0, i]
            s_ = z1 - (o[2, i] + t * d[2, i])
            return s_ - float(sag(lens, 0, abs(x)))
        lo, hi = 0.0, 100.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
        assert t_newton[i] == pytest.approx(lo, abs=1e-9)


def test_13_traced_rays_keep_unit_directions_and_wavelengths():
    """Valid output directions are unit vectors and wavelengths pass through unchanged."""
    lens = double_gauss()
    rays = sensor_rays(3000, lens, seed=13)
    res = trace(lens, rays)
    v = res.valid
    np.testing.assert_allclose(np.linalg.norm(res.rays.d[:, v], axis=0), 1.0, atol=1e-12)
    np.testing.assert_array_equal(res.rays.wavelength[v], rays.wavelength[v])
    assert (res.rays.d[2, v] > 0).all()


def test_14_threads_and_chunks_do_not_change_results():
    """Splitting the work into chunks and threads gives bit-identical rays."""
    lens = double_gauss()
    rays = sensor_rays(10000, lens, seed=14)
    a = trace(lens, rays, threads=1, chunk=100000)
    b = trace(lens, rays, threads=2, chunk=777)
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_array_equal(a.rays.o, b.rays.o)
    np.testing.assert_array_equal(a.status, b.status)


def test_15_ray_from_beyond_the_centre_of_curvature_hits_the_vertex_cap():
    """A ray starting farther from a concave surface than its centre of curvature still meets
    the cap through the vertex (the far quadratic root), at the distance the geometry gives."""
    from neurolens_addon.core.trace import intersect
    glass = Material.from_abbe(1.5, None)
    r = -14.5                                   # concave towards the scene, centre 14.5 mm in front
    lens = Lens("meniscus", "tests", 100.0, 4.0, (Surface(r, 40.0, glass, 8.0, stop=True),))
    zv = lens.vertex_z[0]
    h = np.array([0.0, 3.0, 7.0])
    start = zv + 26.0                           # beyond the centre at zv + 14.5
    o = np.stack([np.zeros(3), h, np.full(3, start)])
    d = np.zeros((3, 3))
    d[2] = -1.0
    t, hit = intersect(lens, 0, Rays(o, d, np.full(3, 550.0)))
    assert hit.all()
    sag = r - np.sign(r) * np.sqrt(r * r - h * h)     # exact sphere sag (negative: towards scene)
    np.testing.assert_allclose(start - t, zv - sag, atol=1e-12)


def test_16_polygonal_stop_clips_to_its_blades():
    """With a 6-blade stop, rays through the stop plane pass exactly when their point lies in
    the hexagon scaled to the stop radius (the f-number sets that radius)."""
    from neurolens_addon.core.aperture import PolygonAperture, stop_radius_for_f_number
    lens = double_gauss()
    r_stop = stop_radius_for_f_number(lens.stop_radius_mm, lens.f_number, 4.0)
    hexagon = PolygonAperture(6, rotation_deg=15.0)
    rng = np.random.default_rng(16)
    n = 20000
    z_stop = lens.vertex_z[lens.stop_index]
    px, py = rng.uniform(-1.2 * r_stop, 1.2 * r_stop, (2, n))
    # Rays from a point on the axis in front of the lens, aimed at points of the stop plane:
    # parallel to the axis between the stop and the front group they need no aiming, so trace
    # the rear part only (stop and behind) from the stop side.
    o = np.stack([px, py, np.full(n, z_stop + 1e-6)])
    d = np.zeros((3, n))
    d[2] = -1.0
    res = trace(lens, Rays(o, d, np.full(n, 550.0)), from_sensor=False, stop_radius=r_stop,
                aperture=hexagon, surfaces=(lens.stop_index, lens.stop_index + 1), sensor_z=None)
    expect = hexagon.inside(px / r_stop, py / r_stop)
    np.testing.assert_array_equal(res.valid, expect)
    assert 0.3 < expect.mean() < 0.7
    assert (res.status[~expect] == RayStatus.CLIPPED_STOP).all()
