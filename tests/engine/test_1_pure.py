"""The engine's pure-numpy parts (no bpy): bundles and the memory bound, the image inversion,
lens space -> camera space, sample streams, the BSDF and the film."""

from __future__ import annotations

import numpy as np
import pytest

from neurolens_addon.engine import bsdf, plan
from neurolens_addon.core.film import FilmSettings, film_from_settings
from neurolens_addon.engine.camera_rays import (camera_to_world, camera_uniforms, hash_u01,
                                                lens_to_camera, rigid)
from neurolens_addon.engine.film import DEPTH_FAR, Film


def test_01_bundles_of_a_4k_frame_at_256_samples_never_exceed_the_bound():
    """Memory bound: a 3840 x 2160 frame at 256 spp is cut into bundles of at most max_rays
    camera samples, which together cover every (pixel, sample) exactly once."""
    for w, h, s, bound in ((3840, 2160, 256, plan.DEFAULT_MAX_RAYS),
                           (3840, 2160, 256, plan.HARD_MAX_RAYS), (300, 200, 8, 1000)):
        biggest, total = 0, 0
        per_tile_pass = {}
        for b in plan.bundles(w, h, s, 64, bound):
            biggest = max(biggest, b.rays)
            total += b.rays
            key = (b.tile_index, b.s0)
            per_tile_pass[key] = per_tile_pass.get(key, 0) + (b.p1 - b.p0)
        assert biggest <= bound
        assert total == w * h * s                       # nothing missing, nothing twice
        assert all(v == 64 * 64 or v < 64 * 64 for v in per_tile_pass.values())


def test_02_progressive_passes_double_and_cover_all_samples():
    """Progressive passes: 1, 1, 2, 4, ... samples per pixel (capped), covering 0..S."""
    assert plan.sample_passes(16, 64) == [(0, 1), (1, 2), (2, 4), (4, 8), (8, 16)]
    p = plan.sample_passes(100, 8)
    assert p[0] == (0, 1) and p[-1][1] == 100
    assert all(b - a <= 8 for a, b in p)
    assert all(p[i][1] == p[i + 1][0] for i in range(len(p) - 1))


def test_03_film_readout_inverts_the_lens_image():
    """The image point right/up of the centre is read from the lens-space film point left/down
    (x, y) = (-p, -q): with the lens space -> camera space map (x, y, z) -> (x, y, -z), a ray
    through the lens centre from that film point leaves towards camera +X/+Y (image right/up)."""
    f = film_from_settings(FilmSettings(36.0, 24.0, "AUTO", 100, 50))
    assert f.width_mm == 36.0 and f.height_mm == pytest.approx(18.0)
    p, q = f.image_points(np.array([99]), np.array([49]), 0.5, 0.5)   # top-right pixel
    assert p[0] > 0 and q[0] > 0
    # a chief ray from film point (-p, -q, 0) through the lens centre (0, 0, 50) (lens space)
    o = np.array([[-p[0]], [-q[0]], [0.0]])
    d = np.array([[p[0]], [q[0]], [50.0]])
    d /= np.linalg.norm(d)
    pc, dc = lens_to_camera(o, d, sensor_z=0.0, mm_per_unit=1000.0)
    assert dc[0, 2] < 0                          # towards the scene: camera -Z
    assert dc[0, 0] > 0 and dc[0, 1] > 0         # image right / up
    assert pc[0, 0] == pytest.approx(-p[0] / 1000.0)


def test_05_camera_to_world_removes_scale_and_normalises():
    """World rays: the camera's rotation without its scale; unit directions."""
    m = np.diag([2.0, 2.0, 2.0, 1.0])
    m[:3, 3] = (1.0, 2.0, 3.0)
    r = rigid(m)
    p, d = camera_to_world(np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, -3.0]]), r)
    np.testing.assert_allclose(p[0], (1.0, 2.0, 2.0))
    np.testing.assert_allclose(d[0], (0.0, 0.0, -1.0))


def test_06_sample_streams_are_uniform_reproducible_and_decorrelated():
    """Samples are a pure function of (seed, pixel, sample, dimension), uniform on [0, 1), and
    the wavelength stream is uncorrelated with the aperture stream."""
    pix = np.repeat(np.arange(2000), 16)
    smp = np.tile(np.arange(16), 2000)
    a = camera_uniforms(3, pix, smp)
    b = camera_uniforms(3, pix[::-1], smp[::-1])
    np.testing.assert_array_equal(a["aperture"], b["aperture"][:, ::-1])
    for u in (a["wavelength"], a["aperture"][0], a["jitter"][0]):
        assert 0.0 <= u.min() and u.max() < 1.0
        assert abs(u.mean() - 0.5) < 0.01 and abs(u.var() - 1 / 12) < 0.005
    for k in range(3):
        assert abs(np.corrcoef(a["wavelength"], a["aperture"][k])[0, 1]) < 0.02
    # within a pixel the wavelengths are low-discrepancy (golden-ratio sequence): the largest
    # circular gap between 16 samples stays below 2/16 (random points: ~(ln 16)/16 typically)
    for px in range(0, 2000, 97):
        w = np.sort(a["wavelength"][16 * px:16 * px + 16])
        gaps = np.diff(np.concatenate([w, [w[0] + 1.0]]))
        assert gaps.max() < 2.0 / 16
    assert not np.array_equal(hash_u01(0, pix[:50], smp[:50], 3), hash_u01(1, pix[:50],
                                                                            smp[:50], 3))


def test_07_bsdf_sampling_is_unbiased_and_energy_bounded():
    """The BSDF's one-sample mixture estimate of the reflected fraction equals quadrature of
    f cos, and a white diffuse or metal surface reflects at most all the light."""
    rng = np.random.default_rng(0)
    n_dirs = 200000
    for metal, rough in ((0.0, 1.0), (1.0, 0.3), (0.5, 0.6)):
        n = np.tile([0.0, 0.0, 1.0], (n_dirs, 1))
        wo = np.tile([np.sin(0.5), 0.0, np.cos(0.5)], (n_dirs, 1))
        base = np.ones((n_dirs, 3))
        m = np.full(n_dirs, metal)
        r = np.full(n_dirs, rough)
        _, thr, _ = bsdf.sample(base, m, r, n, wo, *rng.random((3, n_dirs)))
        est = thr[:, 0].mean()
        # reference: uniform hemisphere quadrature of f cos / p, p = 1 / 2pi
        u1, u2 = rng.random((2, n_dirs))
        z = u1
        s = np.sqrt(1 - z * z)
        wi = np.stack([s * np.cos(2 * np.pi * u2), s * np.sin(2 * np.pi * u2), z], axis=1)
        ref = (bsdf.evaluate(base, m, r, n, wo, wi)[:, 0] * 2 * np.pi).mean()
        assert est == pytest.approx(ref, rel=0.03)
        assert est <= 1.02


def test_08_film_means_counts_and_background_depth():
    """The film's passes are per-pixel means: Combined and Vignetting (the relative
    illumination) over all samples, Depth / Normal over first hits (1e10 where none),
    uncertainty over valid ones."""
    f = Film(2, 1)
    tile = plan.Tile(0, 0, 2, 1)
    f.add(tile, np.array([0, 0, 0, 1]), rgb=np.array([[1, 1, 1], [3, 3, 3], [0, 0, 0],
                                                      [0, 0, 0]], float),
          valid=np.array([True, True, False, False]), hit=np.array([True, False, False, False]),
          depth=np.array([2.0, 0, 0, 0]), normal=np.tile([0.0, 0.0, 1.0], (4, 1)),
          illumination=np.array([0.9, 0.6, 0.0, 0.0]),
          uncertainty=np.array([0.1, 0.3, 0.0, 0.0]))
    out = f.readout(tile)
    np.testing.assert_allclose(out["Combined"][0], [4 / 3, 4 / 3, 4 / 3, 1.0], rtol=1e-6)
    np.testing.assert_allclose(out["Vignetting"][:, 0], [1.5 / 3, 0.0], rtol=1e-6)
    np.testing.assert_allclose(out["Depth"][:, 0], [2.0, DEPTH_FAR], rtol=1e-6)
    np.testing.assert_allclose(out["Normal"][0], [0, 0, 1])
    np.testing.assert_allclose(out["Lens Uncertainty"][:, 0], [0.2, 0.0], rtol=1e-6)


@pytest.mark.parametrize("limit", [0.0, 0.5, 2.0, 10.0])
def test_09_clamping_scales_a_contribution_to_the_limit_as_cycles_does(limit):
    from neurolens_addon.engine.shading import clamped
    c = np.array([[0.1, 0.2, 0.3], [3.0, -1.0, 2.0], [50.0, 40.0, 10.0], [0.0, 0.0, 0.0]])
    out = clamped(c, limit)
    if limit == 0.0:
        np.testing.assert_array_equal(out, c)
        return
    total = np.abs(c).sum(axis=1)
    np.testing.assert_allclose(np.abs(out).sum(axis=1), np.minimum(total, limit))
    # the colour (the ratios of the channels) is kept
    np.testing.assert_allclose(out * total[:, None],
                               c * np.minimum(total, limit)[:, None], rtol=1e-12)


def test_principled_layers_keep_energy():
    """A white dielectric under a uniform sky reflects no more than it receives: the
    hemispherical integral of f (n.wi) over wi stays within 3 % of 1 at every view angle and
    roughness (Monte Carlo, 200 000 directions), where the diffuse lobe added on top of the
    specular one gave up to 1.29; and the specular layer reflects more at grazing angles
    (test_12 checks the whole to 1 %)."""
    import numpy as np
    from neurolens_addon.engine import bsdf
    rng = np.random.default_rng(5)
    n_dirs = 200_000
    u1, u2 = rng.random(n_dirs), rng.random(n_dirs)
    z = u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    wi = np.stack([r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2), z], axis=1)
    n = np.tile([0.0, 0.0, 1.0], (n_dirs, 1))
    for mu in (1.0, 0.5, 0.15):
        wo = np.tile([np.sqrt(1 - mu * mu), 0.0, mu], (n_dirs, 1))
        for rough in (0.3, 0.8):
            f = bsdf.evaluate(np.ones((n_dirs, 3)), np.zeros(n_dirs), np.full(n_dirs, rough),
                              n, wo, wi)
            albedo = f[:, 0].mean() * 2 * np.pi            # uniform hemisphere pdf 1 / 2pi
            assert albedo <= 1.03, (mu, rough, albedo)
    e = bsdf.specular_albedo(np.array([0.5, 0.5]), np.array([1.0, 0.1]))
    assert 0.02 < e[0] < e[1] < 0.5                          # more at grazing angles


# -- the GGX lobe against Cycles' Principled BSDF at grazing light (issue 29)

def _directions(elev_o, elev_i, azimuth_i):
    """Unit wo and wi (1, 3) at the given elevations (degrees), wi turned by azimuth_i from
    the plane of wo (180: the light in front of the viewer, backlit)."""
    eo, ei, az = np.radians([elev_o, elev_i, azimuth_i])
    wo = np.array([[np.cos(eo), 0.0, np.sin(eo)]])
    wi = np.array([[np.cos(ei) * np.cos(az), np.cos(ei) * np.sin(az), np.sin(ei)]])
    return wo, wi


def _glossy(wo, wi, metallic, base, roughness=1.0, f0=0.04):
    """The glossy part of f (n.wi) for one pair of directions (a surface facing +z)."""
    one = lambda v: np.array([v], dtype=np.float64)  # noqa: E731
    _, g = bsdf.evaluate_parts(np.array([[base] * 3]), one(metallic), one(roughness),
                               np.array([[0.0, 0.0, 1.0]]), wo, wi, one(f0))
    return float(g[0, 0])


def test_10_the_ggx_lobe_masks_and_shadows_as_smiths_height_correlated_g2():
    """Backlit ground (roughness 1, the viewer 14 degrees and the sun 6 degrees above the
    surface, the sun in front): the lobe's masking-shadowing is Cycles' height-correlated
    G2 = 1 / (1 + Lambda(wo) + Lambda(wi)), not the product G1(wo) G1(wi). At alpha = 1,
    D = 1 / pi and Lambda(w) = (1 / mu - 1) / 2, so G2 = 2 mu_o mu_i / (mu_o + mu_i); a white
    metal (F = 1) isolates it, and the ratio of two lights for one viewer cancels every term
    that depends on wo alone (1 / (4 mu_o), the multiple-scattering scale):
        f(wi_1) (n.wi_1) / f(wi_2) (n.wi_2) = G2(wo, wi_1) / G2(wo, wi_2).
    The product gives half of it here (0.19 against 0.37): the engine's ground under a sun
    6 degrees high was 0.40x Cycles'."""
    wo, grazing = _directions(14.0, 6.0, 180.0)
    _, overhead = _directions(14.0, 90.0, 0.0)
    mu_o, mu_1, mu_2 = np.sin(np.radians([14.0, 6.0, 90.0]))

    def g2(mu_i):
        return 2.0 * mu_o * mu_i / (mu_o + mu_i)
    want = g2(mu_1) / g2(mu_2)
    got = _glossy(wo, grazing, 1.0, 1.0) / _glossy(wo, overhead, 1.0, 1.0)
    assert got == pytest.approx(want, rel=1e-6), (got, want)
    assert want == pytest.approx(0.3747, abs=1e-4)


def test_11_the_dielectric_specular_follows_the_exact_fresnel_curve():
    """Principled's dielectric specular (IOR 1.5, F0 = 0.04) reflects by the exact Fresnel
    curve of its IOR, as Cycles' (a generalized Schlick whose curve is the real one), not
    Schlick's approximation (1.29x lower where wo.h = 0.60). Two lights at one elevation for
    one viewer share D (alpha = 1), G2 and every wo-only term, so the ratio of their glossy
    parts is the ratio of the reflectances at their wo.h, each computed here from the s and p
    amplitudes of Snell's law."""
    wo, behind = _directions(14.0, 60.0, 180.0)      # the light in front of the viewer
    _, beside = _directions(14.0, 60.0, 0.0)         # the light behind the viewer

    def exact(c, n=1.5):
        t = np.sqrt(1.0 - (1.0 - c * c) / (n * n))
        rs = (c - n * t) / (c + n * t)
        rp = (n * c - t) / (n * c + t)
        return 0.5 * (rs * rs + rp * rp)

    def wo_h(wi):
        h = (wo + wi)[0]
        return float(wo[0] @ h / np.linalg.norm(h))
    want = exact(wo_h(behind)) / exact(wo_h(beside))
    got = _glossy(wo, behind, 0.0, 0.0) / _glossy(wo, beside, 0.0, 0.0)
    assert wo_h(behind) == pytest.approx(0.60, abs=0.01)
    assert got == pytest.approx(want, rel=1e-6), (got, want)


def test_12_white_lobes_reflect_all_the_light_at_every_angle():
    """White furnace, as Cycles' Principled BSDF (Multiscatter GGX, its default) passes it: a
    white metal (F = 1) and a white dielectric (its diffuse layer under the specular one)
    reflect all the light from every view direction, roughness 1 and 0.6 (the hemispherical
    integral of f (n.wi) by quadrature, 400 x 400 directions, within 1 %). Single scattering
    alone loses what the microfacets shadow: the white metal at roughness 1 reflected 0.31 at
    normal incidence (1 - ln 2 exactly: G2 = 2 mu_i / (1 + mu_i) there), and the dielectric's
    diffuse layer, weighed by a fitted specular albedo, gave 0.96 to 1.02. Plain GGX (a
    Principled BSDF set to GGX: `multiple` 0) keeps single scattering: 1 - ln 2."""
    k = 400
    mu = (np.arange(k) + 0.5) / k
    phi = (np.arange(k) + 0.5) / k * 2.0 * np.pi
    mm, pp = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - mm * mm)
    wi = np.stack([s * np.cos(pp), s * np.sin(pp), mm], -1).reshape(-1, 3)
    dw = 2.0 * np.pi / (k * k)
    count = wi.shape[0]
    n = np.tile([0.0, 0.0, 1.0], (count, 1))
    white = np.ones((count, 3))

    def albedo(metallic, rough, mu_o, multiple=None):
        wo = np.tile([np.sqrt(1.0 - mu_o * mu_o), 0.0, mu_o], (count, 1))
        extra = {} if multiple is None else {"multiple": np.full(count, multiple)}
        f = bsdf.evaluate(white, np.full(count, metallic), np.full(count, rough), n, wo, wi,
                          **extra)
        return f[:, 0].sum() * dw
    for metallic in (1.0, 0.0):
        for rough in (1.0, 0.6):
            for mu_o in (1.0, 0.5, 0.25, 0.1):
                assert albedo(metallic, rough, mu_o) == pytest.approx(1.0, abs=0.01), (
                    metallic, rough, mu_o)
    assert albedo(1.0, 1.0, 1.0, multiple=0.0) == pytest.approx(1.0 - np.log(2.0), abs=2e-3)


def test_13_a_diffuse_bsdf_is_lambert_alone():
    """A Diffuse BSDF (F0 0, metallic 0: shader_nodes.py) is Cycles' Lambert: f = b / pi at
    every pair of directions, grazing ones included, and the bounce never picks a glossy lobe
    it does not have (its paths keep b a bounce, as Cycles'). The Schlick term gave it a
    glossy (1 - wo.h)^5 and took a fitted specular albedo off its diffuse, and a fifth of its
    bounces went to that lobe."""
    rng = np.random.default_rng(3)
    k = 20000
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    wo = np.tile([np.cos(0.1), 0.0, np.sin(0.1)], (k, 1))       # 6 degrees above the surface
    base = np.full((k, 3), 0.8)
    zero, rough = np.zeros(k), np.full(k, 0.5)
    u = rng.random((3, k))
    cos_i = u[0]
    wi = np.stack([np.sqrt(1.0 - cos_i ** 2) * np.cos(6.0 * u[1]),
                   np.sqrt(1.0 - cos_i ** 2) * np.sin(6.0 * u[1]), cos_i], axis=1)
    f = bsdf.evaluate(base, zero, rough, n, wo, wi, f0=zero)
    np.testing.assert_allclose(f, np.broadcast_to(0.8 / np.pi * cos_i[:, None], f.shape),
                               rtol=1e-12)
    _, thr, ok = bsdf.sample(base, zero, rough, n, wo, *u, f0=zero)
    assert ok.all()
    np.testing.assert_allclose(thr, 0.8, rtol=1e-12)            # b / pi x cos / (cos / pi)
