"""Ghost paths (core.ghosts) against an independent reflect-then-trace computation, and their
weights against the coatings' reflectances."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.coatings import Coating, fresnel_reflectance
from neurolens_addon.core.ghosts import Ghost, all_ghosts, ghost_energy, reflecting_surfaces
from neurolens_addon.core.glass import resolve_medium
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import intersect, trace

ROOT = Path(__file__).resolve().parents[2]


def lens(name):
    return load_lens(ROOT / "presets" / "lenses" / f"{name}.toml")


def reflect_at(L, k, o, d):
    """Move rays (3, N) to surface k and mirror them; the normal from central differences of
    the surface's sag (not the surface's own normal code). Returns (o, d, on the surface)."""
    rays = Rays(o, d, np.full(o.shape[1], 587.5618))
    t, ok = intersect(L, k, rays)
    p = o + t * d
    shape = L.surfaces[k].shape
    h = 1e-6
    sx = (shape.sag(p[0] + h, p[1]) - shape.sag(p[0] - h, p[1])) / (2 * h)
    sy = (shape.sag(p[0], p[1] + h) - shape.sag(p[0], p[1] - h)) / (2 * h)
    nrm = np.stack([sx, sy, np.ones_like(sx)])        # grad of z - z_v + sag(x, y)
    nrm /= np.linalg.norm(nrm, axis=0)
    d2 = d - 2.0 * (d * nrm).sum(axis=0) * nrm
    inside = ok & (p[0] ** 2 + p[1] ** 2 <= L.surfaces[k].semi_diameter_mm ** 2)
    return p, d2, inside


def forward_ghost(L, ghost, field_deg, n=4000, seed=1):
    """Light from a distant point `field_deg` off axis along the ghost, scene to sensor, by the
    core's ordinary traces and reflect_at: (entry directions, sensor points, arrival
    directions, valid)."""
    a, b = ghost.a, ghost.b
    rng = np.random.default_rng(seed)
    front = L.surfaces[0].semi_diameter_mm
    r = front * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    z0 = float(L.vertex_z[0]) + 5.0
    t = math.radians(field_deg)
    d_in = np.tile(np.array([[0.0], [-math.sin(t)], [-math.cos(t)]]), (1, n))
    o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, z0)])
    wl = np.full(n, 587.5618)
    res = trace(L, Rays(o, d_in, wl), from_sensor=False, surfaces=(0, b), sensor_z=None)
    ok = res.valid.copy()
    p, d, inside = reflect_at(L, b, res.rays.o, res.rays.d)
    ok &= inside
    if b - 1 >= a + 1:
        back = trace(L, Rays(p, d, wl), from_sensor=True, surfaces=(a + 1, b))
        ok &= back.valid
        p, d = back.rays.o, back.rays.d
    p, d, inside = reflect_at(L, a, p, d)
    ok &= inside
    out = trace(L, Rays(p, d, wl), from_sensor=False, surfaces=(a + 1, len(L.surfaces)),
                sensor_z=0.0)
    ok &= out.valid
    return d_in, out.rays.o, out.rays.d, ok


@pytest.mark.parametrize("name,pair,field", [
    ("double_gauss_50mm_f2", (0, 3), 0.0), ("double_gauss_50mm_f2", (2, 9), 4.0),
    ("cooke_triplet_f4", (1, 4), 6.0), ("tessar_f4_5", (0, 5), 2.0)])
def test_01_a_ghost_traced_from_the_camera_retraces_the_light_reflected_twice(name, pair,
                                                                             field):
    """Light from a distant point reflected at surfaces b then a on its way to the sensor
    (computed here with the ordinary trace and a mirror at the finite-difference normal)
    lands on the sensor; a camera ray started there, back along the arrival direction and
    traced along the ghost (a, b) by core.ghosts, leaves the lens towards that point
    (directions within 1e-8): the ghost's image is where the independent computation puts
    it."""
    L = lens(name)
    g = Ghost(*pair)
    d_in, p, d, ok = forward_ghost(L, g, field)
    assert ok.sum() > 50
    cam = Rays(p[:, ok], -d[:, ok], np.full(int(ok.sum()), 587.5618))
    res = trace(L, cam, ghost=g)
    assert res.valid.mean() > 0.97
    assert res.weight is None                   # no coating: no weights
    v = res.valid
    np.testing.assert_allclose(res.rays.d[:, v], -d_in[:, ok][:, v], atol=1e-8)
    # and not along the image's own path
    plain = trace(L, cam)
    moved = plain.valid & v
    if moved.any():
        assert np.abs(plain.rays.d[:, moved] + d_in[:, ok][:, moved]).max() > 1e-3


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("name,pair,field", [
    ("double_gauss_50mm_f2", (0, 3), 0.0), ("double_gauss_50mm_f2", (2, 9), 4.0),
    ("cooke_triplet_f4", (1, 4), 6.0)])
def test_01b_the_light_traced_along_a_ghost_lands_where_reflect_then_trace_puts_it(
        name, pair, field, kernels):
    """core.trace from the scene along a ghost (the light's own way: what the flare of a lamp
    follows) puts each ray on the sensor where the independent computation above does, with
    its arrival direction (1e-6 mm, 1e-8: the sag's finite differences), and passes the same
    rays; with a coating its weight is the camera-side ghost ray's from that sensor point back
    along it (Fresnel is reciprocal)."""
    L = lens(name)
    g = Ghost(*pair)
    d_in, p, d, ok = forward_ghost(L, g, field)
    assert ok.sum() > 50
    rng = np.random.default_rng(1)
    n = d_in.shape[1]
    front = L.surfaces[0].semi_diameter_mm
    r = front * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, float(L.vertex_z[0]) + 5.0)])
    wl = np.full(n, 587.5618)
    res = trace(L, Rays(o, d_in, wl), from_sensor=False, ghost=g, sensor_z=0.0,
                kernels=kernels)
    assert np.array_equal(res.valid, ok)
    np.testing.assert_allclose(res.rays.o[:, ok], p[:, ok], atol=1e-6)   # mm
    np.testing.assert_allclose(res.rays.d[:, ok], d[:, ok], atol=1e-8)
    coat = Coating("single")
    lit = trace(L, Rays(o, d_in, wl), from_sensor=False, ghost=g, sensor_z=0.0,
                coating=coat, kernels=kernels)
    back = trace(L, Rays(p[:, ok], -d[:, ok], wl[ok]), ghost=g, coating=coat, kernels=kernels)
    both = back.valid
    np.testing.assert_allclose(lit.weight[ok][both], back.weight[both], rtol=1e-9)
    assert lit.weight[ok].min() > 0 and lit.weight[ok].max() < 0.05


def test_02_weights_are_the_coatings_shares():
    """Along the singlet's axis, bare: the image keeps (1 - R)^2 and its ghost R^2 (1 - R)^2, with
    R the Fresnel share at the glass's index for that wavelength; with the MgF2 layer both
    shrink as its reflectance does."""
    L = lens("biconvex_singlet")
    wl = np.array([486.1327, 587.5618, 656.2725])
    o = np.zeros((3, 3))
    o[2] = float(L.vertex_z[-1]) - 10.0
    d = np.tile(np.array([[0.0], [0.0], [1.0]]), (1, 3))
    rays = Rays(o, d, wl)
    front, back = reflecting_surfaces(L)          # (a stop plane in air stands before them)
    glass = resolve_medium(L.media()[front + 1])
    n = np.asarray(glass.index(wl))
    r = fresnel_reflectance(1.0, n, 1.0)
    w_img = trace(L, rays, coating=Coating("bare")).weight
    np.testing.assert_allclose(w_img, (1 - r) ** 2, rtol=1e-12)
    res = trace(L, rays, ghost=Ghost(front, back), coating=Coating("bare"))
    assert res.valid.all()
    w_g = res.weight
    np.testing.assert_allclose(w_g, r * r * (1 - r) ** 2, rtol=1e-9)
    w_mgf2 = trace(L, rays, ghost=Ghost(front, back), coating=Coating("single")).weight
    rc = Coating("single").reflectance(1.0, n, 1.0, wl)
    np.testing.assert_allclose(w_mgf2, rc * rc * (1 - rc) ** 2, rtol=1e-9)
    assert np.all(w_mgf2 < w_g)


def test_03_ghosts_enumerate_reflecting_pairs_and_coatings_dim_them():
    """Every ordered pair of surfaces between different media is a ghost (the stop is not one:
    45 for the double Gauss's ten glass surfaces); a quarter-wave MgF2 coating dims each by
    roughly (1.3 % / 4-7 %)^2, ten times or more against bare glass."""
    L = lens("double_gauss_50mm_f2")
    gs = all_ghosts(L)
    stop = next(i for i, s in enumerate(L.surfaces) if s.stop)
    assert all(stop not in (g.a, g.b) for g in gs)
    k = len({g.a for g in gs} | {g.b for g in gs})
    assert len(gs) == k * (k - 1) // 2
    g = Ghost(0, 2)
    bare = ghost_energy(L, g, Coating("bare"), film_radius_mm=21.6)
    coated = ghost_energy(L, g, Coating("single"), film_radius_mm=21.6)
    assert 0.0 < coated * 8 < bare < 0.02


def _ghost_pupil_harmonic(L, ghost, aperture):
    """(dominant harmonic 3..12, its contrast) of the boundary of the directions from the film
    centre that pass along the ghost: the ghost's pupil, whose shape its image of a point
    light takes."""
    from neurolens_addon.core.pupil import disc_rays
    n = 200_000
    rng = np.random.default_rng(0)
    z = np.zeros(n)
    rays, _c = disc_rays(L, z, z, 0.0, rng.random(n), rng.random(n), np.full(n, 587.5618))
    res = trace(L, rays, ghost=ghost, stop_radius=0.5 * L.stop_radius_mm, aperture=aperture)
    v = res.valid
    px, py = (rays.d[0] / rays.d[2])[v], (rays.d[1] / rays.d[2])[v]
    ang = np.arctan2(py - py.mean(), px - px.mean())
    rad = np.hypot(px - px.mean(), py - py.mean())
    bins = ((ang + np.pi) / (2 * np.pi) * 90).astype(int) % 90
    edge = np.array([np.percentile(rad[bins == b], 99) for b in range(90)])
    spectrum = np.abs(np.fft.rfft(edge - edge.mean()))[:13]
    k = 3 + int(np.argmax(spectrum[3:]))
    return k, spectrum[k] / np.delete(spectrum[3:], k - 3).max()


@pytest.mark.parametrize("blades", [5, 6])
def test_04_the_stop_shape_shows_in_the_ghosts(blades):
    """A ghost reflected in front of the stop crosses it once: the bundle from the film
    centre that follows it is cut by the iris, so its boundary has the blade count's symmetry
    (dominant harmonic = blades, twice the next) for the double Gauss's ghosts 1-3 and 2-4;
    through a round stop no harmonic stands out."""
    from neurolens_addon.core.aperture import CircularAperture, PolygonAperture
    L = lens("double_gauss_50mm_f2")
    for g in (Ghost(0, 2), Ghost(1, 3)):
        assert g.b < L.stop_index
        k, contrast = _ghost_pupil_harmonic(L, g, PolygonAperture(blades))
        assert k == blades and contrast > 2.0, (g, k, contrast)
        _k, round_contrast = _ghost_pupil_harmonic(L, g, CircularAperture())
        assert round_contrast < contrast / 2
