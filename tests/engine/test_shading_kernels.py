"""The compiled shading kernels (engine.shading_kernels, numba) against their numpy references
(bsdf, dielectric, camera_rays.hash_u01), stage by stage on random inputs with the edges
included (grazing and below-horizon directions, roughness 0 and 1, metal and dielectric,
F0 = 0 (a Diffuse BSDF), total internal reflection), and a whole render through each path:
same random numbers, so the same image but for the rare path whose decision (roulette, a
lobe) a last-bit difference flips."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba")

from neurolens_addon.core import jit  # noqa: E402
from neurolens_addon.engine import bsdf, camera_rays, dielectric  # noqa: E402
from neurolens_addon.engine import microfacet as mf  # noqa: E402
from neurolens_addon.engine import shading_kernels as sk  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
N = 20000


def _unit(rng, k):
    v = rng.normal(size=(k, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


@pytest.fixture(params=[1, 2, 3], ids=["seed1", "seed2", "seed3"])
def surfaces(request):
    """Random surface points: n, wo on n's side (a few exactly grazing), wi anywhere (a few
    grazing, half below), base, metallic (half exactly 0, a tenth exactly 1), roughness
    (with 0 and 1), F0 (a tenth 0), multiple scattering on or off."""
    rng = np.random.default_rng(request.param)
    n, wo, wi = _unit(rng, N), _unit(rng, N), _unit(rng, N)
    wo = np.where((np.einsum("ij,ij->i", n, wo) < 0)[:, None], -wo, wo)
    graze = rng.random(N) < 0.02                         # wo in the tangent plane
    wo[graze] -= np.einsum("ij,ij->i", n[graze], wo[graze])[:, None] * n[graze]
    wo[graze] /= np.linalg.norm(wo[graze], axis=1)[:, None]
    metallic = np.where(rng.random(N) < 0.5, 0.0, rng.random(N))
    metallic[rng.random(N) < 0.1] = 1.0
    rough = rng.random(N)
    rough[:50], rough[50:100] = 0.0, 1.0
    f0 = np.where(rng.random(N) < 0.1, 0.0, rng.random(N) * 0.2)
    return dict(base=rng.random((N, 3)), metallic=metallic, roughness=rough, n=n, wo=wo,
                wi=wi, f0=f0, multiple=(rng.random(N) < 0.7).astype(float),
                u=rng.random((3, N)), rng=rng)


def _edge(n, *ws):
    """Rows where a direction lies within rounding of the surface (|n.w| < 1e-9): its side,
    and so whether the lobe counts, may differ between two orders of summation."""
    return np.any([np.abs(np.einsum("ij,ij->i", n, w)) < 1e-9 for w in ws], axis=0)


def test_01_evaluate_parts_equals_the_numpy_lobes(surfaces):
    s = surfaces
    args = (s["base"], s["metallic"], s["roughness"], s["n"], s["wo"], s["wi"], s["f0"],
            s["multiple"])
    want = bsdf.evaluate_parts(*args)
    got = sk.run_evaluate_parts(*args, mf.tables())
    keep = ~_edge(s["n"], s["wo"], s["wi"])
    assert keep.sum() > 0.97 * N
    for w, g in zip(want, got):
        assert np.isfinite(g).all()
        np.testing.assert_allclose(g[keep], w[keep], rtol=1e-9, atol=1e-12)
    assert (want[1] > 0).sum() > N // 4            # the lobes were exercised, not all zero


def test_02_pdf_parts_equals_the_numpy_densities(surfaces):
    s = surfaces
    for f0 in (s["f0"], None):
        args = (s["metallic"], s["roughness"], s["n"], s["wo"], s["wi"], f0)
        for w, g in zip(bsdf.pdf_parts(*args), sk.run_pdf_parts(*args)):
            np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12)


def test_03_sampled_directions_equal_the_numpy_ones(surfaces):
    s = surfaces
    args = (s["metallic"], s["roughness"], s["n"], s["wo"], *s["u"], s["f0"])
    wi_w, spec_w = bsdf.sample_direction(*args)
    wi_g, spec_g = sk.run_sample_direction(*args)
    assert np.array_equal(spec_w, spec_g) and 0 < spec_g.sum() < N
    np.testing.assert_allclose(wi_g, wi_w, rtol=0, atol=1e-12)


def test_04_glass_bounces_equal_the_numpy_ones(surfaces):
    s = surfaces
    # entering (ior 1.5) and leaving (1 / 1.5: total internal reflection past ~42 degrees)
    eta = np.where(s["rng"].random(N) < 0.5, 1.5, 1.0 / 1.5)
    args = (s["n"], s["wo"], eta, s["roughness"], *s["u"])
    wi_w, wt_w, refr_w, ok_w = dielectric.sample(*args)
    wi_g, wt_g, refr_g, ok_g = sk.run_dielectric_sample(*args)
    keep = ~_edge(s["n"], s["wo"], wi_w)
    assert keep.sum() > 0.97 * N
    assert np.array_equal(refr_w, refr_g)
    assert np.array_equal(ok_w[keep], ok_g[keep])
    assert 0 < refr_g.sum() < N and (~ok_g).any()
    np.testing.assert_allclose(wi_g, wi_w, rtol=0, atol=1e-12)
    np.testing.assert_allclose(wt_g[keep], wt_w[keep], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("dim", [0, 3, 16, 16 + 4096 * 7 + 13])
def test_05_the_hash_gives_the_numpy_numbers_bit_for_bit(dim):
    rng = np.random.default_rng(dim)
    pixel = rng.integers(0, 1 << 31, 5000)
    sample = rng.integers(0, 1 << 24, 5000)
    for s in (sample, 0):
        want = camera_rays.hash_u01_numpy(12345, pixel, s, dim)
        got = sk.run_hash_u01(12345, pixel, s, dim)
        assert got.dtype == np.float64 and np.array_equal(got, want)
        assert got.min() >= 0.0 and got.max() < 1.0


def test_06_the_switch_picks_the_kernels_and_numpy_stays_the_reference(monkeypatch):
    monkeypatch.setenv("NEUROLENS_KERNELS", "numpy")
    assert not sk.active()
    monkeypatch.setenv("NEUROLENS_KERNELS", "compiled")
    assert sk.active()
    # the kernels' file is part of the cache key: an edited kernel never loads a stale one
    assert "../engine/shading_kernels.py" in jit.KERNEL_SOURCES
    assert sk._ALPHA_MIN == mf.ALPHA_MIN


@pytest.mark.slow
def test_07_a_render_through_the_kernels_is_the_numpy_render(tmp_path):
    """The still life (glass, metal, an area light; testdata/agreement_scenes.py) at 96x54,
    16 samples, one colour ray, rendered by the command line with NEUROLENS_KERNELS=numpy and
    =compiled: the same random numbers, so the mean agrees within 0.3 % and 99 % of the
    pixels within 1e-6 (a path whose roulette or lobe choice a last-bit difference flips
    moves its pixel by a sample's share)."""
    pytest.importorskip("bpy")
    from testdata import agreement_scenes as scenes
    from testdata.engine_scenes import read_exr

    def combined(path):
        ch = read_exr(path)
        return np.stack([ch[f"Combined.{c}"] for c in "RGB"], axis=-1).astype(np.float64)
    blend = scenes.write("still_life", tmp_path)
    lens, focus, fstop = scenes.CAMERAS["still_life"]
    images = {}
    for mode in ("numpy", "compiled"):
        out = tmp_path / f"{mode}.exr"
        env = dict(os.environ, PYTHONPATH=str(ROOT), NEUROLENS_KERNELS=mode)
        p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(blend),
                            "--lens", lens, "--model", "exact", "--focus", str(focus),
                            "--fstop", str(fstop), "--samples", "16", "--resolution", "96x54",
                            "--colour-rays", "1", "--no-denoise", "--quiet", "--out", str(out)],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-1500:]
        images[mode] = combined(out)
    a, b = images["numpy"], images["compiled"]
    assert a.mean() > 0.01
    assert abs(b.mean() / a.mean() - 1.0) < 3e-3
    assert np.quantile(np.abs(b - a), 0.99) < 1e-6 * max(1.0, float(a.max()))


def _lights():
    """One light of every kind and shape the engine reads, sized and not, rotated."""
    from neurolens_addon.engine.lights import Light
    rot = np.linalg.qr(np.random.default_rng(9).normal(size=(3, 3)))[0]
    ax, ay, fwd = rot[:, 0] * 0.7, rot[:, 1] * 1.3, -rot[:, 2]
    common = dict(colour=np.array([30.0, 20.0, 10.0]), position=np.array([0.3, -0.2, 2.0]),
                  axis_x=ax, axis_y=ay, forward=fwd)
    return {
        "point": Light("POINT", **common),
        "point-r": Light("POINT", radius=0.2, **common),
        "spot-r": Light("SPOT", radius=0.1, cos_half=np.cos(0.6), smooth=0.1, **common),
        "spot-hard": Light("SPOT", radius=0.1, cos_half=np.cos(0.6), **common),
        "sun": Light("SUN", **common),
        "sun-wide": Light("SUN", cos_sun=np.cos(0.2), **common),
        "square": Light("AREA", shape="SQUARE", size_x=0.5, **common),
        "rectangle": Light("AREA", shape="RECTANGLE", size_x=0.5, size_y=0.8, **common),
        "disk": Light("AREA", shape="DISK", size_x=0.6, **common),
        "ellipse": Light("AREA", shape="ELLIPSE", size_x=0.6, size_y=0.3, **common),
    }


LIGHTS = list(_lights())


@pytest.mark.parametrize("name", LIGHTS)
def test_08_light_samples_equal_the_numpy_ones(name):
    from neurolens_addon.engine import light_kernels as lk
    light = _lights()[name]
    rng = np.random.default_rng(4)
    p = rng.normal(size=(N, 3)) * 1.5
    u1, u2 = rng.random((2, N))
    want = light.sample(p, u1, u2)
    got = lk.run_sample(light.row, p, u1, u2)
    for w, g in zip(want, got):
        np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-12)
    assert (got[2] > 0).any()


@pytest.mark.parametrize("name", [n for n in LIGHTS if n not in ("point", "sun")])
def test_09_bounce_rays_meet_the_lights_as_in_numpy(name):
    """Rays from around the light aimed near it (half of them at it), a third escaped."""
    from neurolens_addon.engine import light_kernels as lk
    light = _lights()[name]
    rng = np.random.default_rng(5)
    o = rng.normal(size=(N, 3)) * 1.5
    aim = light.position + rng.normal(size=(N, 3)) * 0.3
    d = np.where((rng.random(N) < 0.5)[:, None], aim - o, _unit(rng, N))
    d /= np.linalg.norm(d, axis=1)[:, None]
    escaped = rng.random(N) < 0.66
    t_w, rad_w, pdf_w = light.hit(o, d, escaped)
    t_g, rad_g, pdf_g = lk.run_hit(light.row, o, d, escaped)
    met_w, met_g = np.isfinite(t_w), np.isfinite(t_g)
    assert (met_w != met_g).sum() <= 2                    # a ray within rounding of the edge
    assert met_g.sum() > N // 100
    both = met_w & met_g
    np.testing.assert_allclose(t_g[both], t_w[both], rtol=1e-10)
    np.testing.assert_allclose(rad_g[both], rad_w[both], rtol=1e-10)
    np.testing.assert_allclose(pdf_g[both], pdf_w[both], rtol=1e-9)
    assert not rad_g[~met_g].any() and not pdf_g[~met_g].any()


def test_10_a_fused_light_sample_equals_the_numpy_stages(surfaces):
    """shading_kernels.light_contribution against the numpy stages it fuses (the lobes, their
    densities, the power heuristic per lobe, a lobe that cannot bounce taking weight 1, a delta
    light weight 1)."""
    from neurolens_addon.engine.shading import power_heuristic
    s, rng = surfaces, surfaces["rng"]
    ng = s["n"]
    li = rng.random((N, 3)) * (rng.random(N) < 0.9)[:, None]
    pl = np.where(rng.random(N) < 0.2, np.inf, rng.random(N) * 3.0)
    thr, opaque = rng.random((N, 3)), np.where(rng.random(N) < 0.1, 0.0, rng.random(N))
    glossy_on, diffuse_on = rng.random(N) < 0.7, rng.random(N) < 0.7
    contrib, keep = sk.run_light_contribution(
        thr, s["base"], s["metallic"], s["roughness"], s["n"], ng, s["wo"], s["wi"], li, pl,
        s["f0"], s["multiple"], opaque, glossy_on, diffuse_on, mf.tables())
    fd, fg = bsdf.evaluate_parts(s["base"], s["metallic"], s["roughness"], s["n"],
                                       s["wo"], s["wi"], s["f0"], s["multiple"])
    pg, pd = bsdf.pdf_parts(s["metallic"], s["roughness"], s["n"], s["wo"], s["wi"],
                                  s["f0"])
    pg, pd = np.where(glossy_on, opaque * pg, 0.0), np.where(diffuse_on, opaque * pd, 0.0)
    finite = np.isfinite(pl)
    wd = np.where(finite, power_heuristic(pl, pd), 1.0)[:, None]
    wg = np.where(finite, power_heuristic(pl, pg), 1.0)[:, None]
    lit = ((li.max(axis=1) > 0) & (np.einsum("ij,ij->i", ng, s["wi"]) > 0) & (opaque > 0))
    want = np.where(lit[:, None], thr * (fd * wd + fg * wg) * (li * opaque[:, None]), 0.0)
    rows = ~_edge(s["n"], s["wo"], s["wi"])
    np.testing.assert_allclose(contrib[rows], want[rows], rtol=1e-9, atol=1e-12)
    assert np.array_equal(keep[rows], (np.abs(want).max(axis=1) > 0)[rows])
    assert keep.sum() > N // 10


def test_11_the_fused_bounce_off_the_opaque_lobes_equals_the_numpy_stages(surfaces):
    """shading_kernels.bounce where every point is opaque (no glass), no limit reached and no
    roulette: the direction, weight f_j (n.wi) / (P_j p_j), density and kind of the numpy
    stages (bsdf's sampling, lobes and densities)."""
    from neurolens_addon.engine.materials import SurfacePoint
    s = surfaces
    ng = s["n"]
    u1, u2, u_lobe = s["u"]
    k = ng.shape[0]
    sp = SurfacePoint(s["base"], s["metallic"], s["roughness"], np.zeros((k, 3)), ng,
                      np.zeros(k), np.full(k, 1.5), s["f0"], np.ones(k), np.zeros(k),
                      s["multiple"])
    kinds = np.zeros((k, 4), np.int64)
    eps = np.full((k, 1), 1e-4)
    _o, wi, weight, pdf, kinds_out, ok = sk.run_bounce(
        np.ones((k, 3)), np.ones(k), np.zeros(k, np.int64), kinds, sp, s["n"], ng, s["wo"],
        np.zeros((k, 3)), eps, np.ones(k, bool), np.ones(k, bool), [u1, u2, u1, u_lobe],
        u1, np.full(4, 99), 99, mf.tables())
    wi_w, spec = bsdf.sample_direction(s["metallic"], s["roughness"], s["n"], s["wo"],
                                       u1, u2, u_lobe, s["f0"])
    fd, fg = bsdf.evaluate_parts(s["base"], s["metallic"], s["roughness"], s["n"],
                                 s["wo"], wi_w, s["f0"], s["multiple"])
    pg, pd = bsdf.pdf_parts(s["metallic"], s["roughness"], s["n"], s["wo"], wi_w,
                            s["f0"])
    lobe = np.where(spec, pg, pd)
    want = np.where(spec[:, None], fg, fd) / np.where(lobe > 0, lobe, 1.0)[:, None]
    ok_w = ((np.einsum("ij,ij->i", s["n"], wi_w) > 0) & (lobe > 0)
            & (np.einsum("ij,ij->i", ng, wi_w) > 0) & (np.abs(want).max(axis=1) > 0))
    rows = ~_edge(s["n"], s["wo"], wi_w)
    assert np.array_equal(kinds_out[:, 1], spec.astype(np.int64))
    assert np.array_equal(kinds_out[:, 0], (~spec).astype(np.int64))
    np.testing.assert_allclose(wi, wi_w, rtol=0, atol=1e-12)
    # near-mirror lobes (roughness ~0: D ~ 1e5) lose digits to cancellation in D's
    # denominator, the same in both, summed in another order
    np.testing.assert_allclose(pdf[rows], lobe[rows], rtol=1e-7)
    np.testing.assert_allclose(weight[rows], want[rows], rtol=1e-7, atol=1e-12)
    assert np.array_equal(ok[rows], ok_w[rows]) and 0 < ok.sum() < k


def test_12_the_first_use_compiles_into_the_user_cache_and_later_processes_load_it(tmp_path):
    """`python -m neurolens_addon.engine.kernel_warmup` with an empty cache (NEUROLENS_CACHE_DIR)
    compiles every kernel and says so; a second process loads them from that cache; a render
    then states the warm-up in its summary line, as loaded from the cache."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NEUROLENS_CACHE_DIR=str(tmp_path / "c"),
               NEUROLENS_KERNELS="auto")
    env.pop("NUMBA_CACHE_DIR", None)
    said = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr[-1500:]
        said.append(p.stdout)
    assert "kernels compiled in" in said[0], said[0]
    assert "kernels loaded from the cache in" in said[1], said[1]
    folder = tmp_path / "c" / "numba" / jit.sources_digest()
    assert len(list(folder.rglob("*.nbi"))) >= 10           # an index per cached kernel
    out = tmp_path / "r.png"
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.render",
                        str(ROOT / "presets" / "scenes" / "demo.blend"), "--lens",
                        "double_gauss_50mm_f2", "--model", "exact", "--samples", "1",
                        "--resolution", "32x18", "--quiet", "--out", str(out)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-1500:]
    assert "| kernels loaded from the cache in" in p.stdout + p.stderr


@pytest.mark.parametrize("limits", [(0.0, 0.0), (1.5, 0.3), (0.0, 0.7)])
def test_13_the_bundle_sums_equal_the_numpy_clamped_scatter_add(limits):
    from neurolens_addon.engine.shading import clamped
    rng = np.random.default_rng(13)
    k, m = 30000, 4000
    samples = rng.integers(0, m, k)
    contrib = rng.random((k, 3)) * rng.choice([0.1, 1.0, 10.0], (k, 1))
    direct = rng.random(k) < 0.5
    want = rng.random((m, 3))
    got = want.copy()
    c = clamped(contrib, np.where(direct, limits[0], limits[1]))
    for ch in range(3):
        want[:, ch] += np.bincount(samples, c[:, ch], minlength=m)
    start = got.copy()
    sk.run_accumulate(got, samples, contrib, direct, *limits)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    if limits[1] > 0:
        assert not np.allclose(c, contrib)                 # the clamp did act
    # through rows: contribution i to idx[row[i]], direct as direct_of[row[i]], where kept
    idx, row = rng.integers(0, m, k), rng.integers(0, k, k)
    keep = rng.random(k) < 0.7
    by_rows = start.copy()
    sk.run_accumulate_rows(by_rows, idx, row, keep, contrib, direct, *limits)
    want = start.copy()
    sk.run_accumulate(want, idx[row[keep]], contrib[keep], direct[row[keep]], *limits)
    np.testing.assert_allclose(by_rows, want, rtol=1e-14)
    assert not np.allclose(by_rows, start)


def test_14_a_fused_bounce_continues_the_paths_the_numpy_bounce_continues(surfaces,
                                                                           monkeypatch):
    """Shader._bounce through shading_kernels.bounce and through numpy: glass (entering and
    leaving, tinted), the opaque lobes, bounce limits and Russian roulette, the same paths
    going on with the same rays and throughputs."""
    from neurolens_addon.engine.materials import SurfacePoint
    from neurolens_addon.engine.settings import RenderSettings
    from neurolens_addon.engine.shading import Paths, Shader
    s, rng = surfaces, surfaces["rng"]
    keep = ~_edge(s["n"], s["wo"])
    n, wo = s["n"][keep], s["wo"][keep]
    k = n.shape[0]
    sp = SurfacePoint(s["base"][keep], s["metallic"][keep], s["roughness"][keep],
                      np.zeros((k, 3)), n, np.where(rng.random(k) < 0.3, 1.0, 0.0),
                      np.full(k, 1.5), s["f0"][keep], np.ones(k), rng.random(k),
                      s["multiple"][keep])
    kinds = rng.integers(0, 3, (k, 4))
    paths = Paths(np.arange(k), np.zeros((k, 3)), -wo, rng.random((k, 3)) + 0.05,
                  np.ones(k), np.zeros(k), rng.integers(0, 6, k), kinds)
    shader = Shader(None, None, [], None, settings=RenderSettings(
        bounces=12, diffuse_bounces=4, glossy_bounces=4, transmission_bounces=4,
        min_light_bounces=2, seed=5))
    loc = rng.normal(size=(k, 3))
    eps = 1e-4 * (1.0 + np.abs(loc).max(axis=1))[:, None]
    args = (paths, sp, n, n, wo, loc, eps, rng.integers(0, 1 << 20, k), rng.integers(0, 64, k),
            16, 1.0 - sp.transmission, rng.random(k) < 0.9, rng.random(k) < 0.5)
    out = {}
    for mode in ("numpy", "compiled"):
        monkeypatch.setenv("NEUROLENS_KERNELS", mode)
        out[mode] = shader._bounce(*args)
    a, b = out["numpy"], out["compiled"]
    assert 0.2 * k < a.idx.size < k
    same = np.intersect1d(a.idx, b.idx)
    assert same.size >= a.idx.size - 3 and same.size >= b.idx.size - 3   # rounding edges
    ia, ib = np.searchsorted(a.idx, same), np.searchsorted(b.idx, same)
    for f in ("o", "d"):
        np.testing.assert_allclose(getattr(b, f)[ib], getattr(a, f)[ia], rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.thr[ib], a.thr[ia], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(b.pdf[ib], a.pdf[ia], rtol=1e-7)
    assert np.array_equal(b.kinds[ib], a.kinds[ia]) and np.array_equal(b.depth[ib], a.depth[ia])
    assert (a.kinds[:, 2] > kinds[a.idx, 2]).any()          # some paths refracted


def test_15_emissive_mesh_samples_equal_the_numpy_ones():
    from neurolens_addon.engine import light_kernels as lk
    from neurolens_addon.engine.emitters import Emitters
    rng = np.random.default_rng(15)
    corners = rng.normal(size=(40, 3, 3))
    emission = rng.random((40, 3)) * (rng.random((40, 1)) < 0.8)
    em = Emitters(corners, emission)
    p = rng.normal(size=(N, 3)) * 2.0
    u1, u2 = rng.random((2, N))
    want = em.sample(p, u1, u2)
    got = lk.run_emitters_sample(em, p, u1, u2)
    for w, g in zip(want, got):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-12)
    assert (got[3] > 0).mean() > 0.9


def test_16_hits_are_located_in_the_triangles_numpy_finds():
    """Polygons of 1 to 5 triangles (a fan), hits inside and a little outside them."""
    from neurolens_addon.engine import mesh_kernels
    from neurolens_addon.engine.mesh_tables import ObjectTable
    rng = np.random.default_rng(16)
    counts = rng.integers(1, 6, 300)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    co = rng.normal(size=(2 * counts.sum(), 3))                  # vertices, shared at random
    tv = rng.integers(0, co.shape[0], (counts.sum(), 3))
    corners = co[tv]
    poly = rng.integers(0, counts.size, N)
    t = first[poly] + rng.integers(0, 5, N) % counts[poly]
    w = rng.dirichlet([1, 1, 1], N) * 1.1 - 0.03
    p = np.einsum("ij,ijk->ik", w, corners[t])
    table = ObjectTable.__new__(ObjectTable)          # the arrays without a Blender mesh
    table._tris = (first, counts, co, tv, np.zeros((counts.sum(), 3), np.int64))
    tri_w, bary_w = table.locate_numpy(poly, p)
    tri_g, bary_g = mesh_kernels.run_locate(poly, p, first, counts, co, tv)
    assert (tri_w != tri_g).sum() <= 2
    same = tri_w == tri_g
    np.testing.assert_allclose(bary_g[same], bary_w[same], rtol=1e-9, atol=1e-12)
    # located and, on smooth polygons, the corner normals interpolated, made unit and turned
    # to the face normal's side (materials.lookup's numpy expression)
    loops = rng.permutation(3 * counts.sum()).reshape(-1, 3)
    corner_normals = _unit(rng, 3 * counts.sum())
    smooth = rng.random(counts.size) < 0.6
    face = _unit(rng, N)
    tri_s, bary_s, normal = mesh_kernels.run_locate_smooth(poly, p, first, counts, co, tv,
                                                           loops, corner_normals, smooth, face)
    assert np.array_equal(tri_s, tri_g) and np.array_equal(bary_s, bary_g)
    n = np.einsum("ij,ijk->ik", bary_s, corner_normals[loops[tri_s]])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    n = np.where((np.einsum("ij,ij->i", n, face) < 0)[:, None], -n, n)
    want = np.where(smooth[poly][:, None], n, face)
    np.testing.assert_allclose(normal, want, rtol=1e-12, atol=1e-14)
    assert smooth[poly].any() and (~smooth[poly]).any()


def test_17_many_dimensions_at_once_are_the_one_at_a_time_numbers():
    rng = np.random.default_rng(17)
    pixel, sample = rng.integers(0, 1 << 30, 3000), rng.integers(0, 1 << 20, 3000)
    dims = [16, 17, 18, 4096 * 3 + 10]
    got = sk.run_hash_u01_dims(99, pixel, sample, dims)
    for row, d in zip(got, dims):
        assert np.array_equal(row, camera_rays.hash_u01_numpy(99, pixel, sample, d))
    assert np.array_equal(sk.run_hash_u01_dims(99, pixel, 0, [3])[0],
                          camera_rays.hash_u01_numpy(99, pixel, 0, 3))


def test_18_the_albedo_tables_are_kept_for_later_processes_and_a_bad_file_is_replaced(
        tmp_path):
    """The first process computes the GGX albedo tables and leaves them in the user's cache
    folder; the next reads them (the same numbers); a truncated or wrong file is ignored,
    the tables computed again and the file replaced."""
    script = ("import numpy as np, sys\n"
              "from neurolens_addon.engine import microfacet as mf\n"
              "t = mf.tables()\n"
              "np.save(sys.argv[1], np.concatenate([a.ravel() for a in t]))\n"
              "print(mf.tables_cache_path())\n")
    env = dict(os.environ, PYTHONPATH=str(ROOT), NEUROLENS_CACHE_DIR=str(tmp_path / "c"))

    def run(i):
        p = subprocess.run([sys.executable, "-c", script, str(tmp_path / f"{i}.npy")], cwd=ROOT,
                           env=env, capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr[-1500:]
        return Path(p.stdout.strip()), np.load(tmp_path / f"{i}.npy")

    path, first = run(0)
    assert path.is_file() and str(path).startswith(str(tmp_path / "c"))
    _, second = run(1)
    assert np.array_equal(first, second)
    want = np.concatenate([a.ravel() for a in mf._compute_tables()])
    assert np.array_equal(first, want)
    for bad in (path.read_bytes()[:100], b"not a zip"):
        path.write_bytes(bad)
        _, again = run(2)
        assert np.array_equal(again, want)
        assert path.stat().st_size > 1000                      # replaced by whole tables


@pytest.mark.parametrize("streamed", [False, True], ids=["frame", "streamed"])
def test_19_the_compiled_film_sums_are_the_numpy_sums_bit_for_bit(streamed, monkeypatch):
    """Bundles with and without uncertainty and albedo, shares 1 and 1/3, into two tiles of a
    frame film and of a streamed one: every sum equal to the last bit."""
    from neurolens_addon.engine.film import Film
    from neurolens_addon.engine.plan import Tile
    rng = np.random.default_rng(19)
    tiles = [Tile(0, 0, 16, 8), Tile(16, 0, 7, 8)]
    films = {}
    for mode in ("numpy", "compiled"):
        monkeypatch.setenv("NEUROLENS_KERNELS", mode)
        rng = np.random.default_rng(19)
        film = Film(23, 8, streamed=streamed)
        for b in range(6):
            tile = tiles[b % 2]
            n = 900
            valid, hit = rng.random(n) < 0.9, rng.random(n) < 0.7
            film.add(tile, rng.integers(0, tile.pixels, n), rgb=rng.random((n, 3)) * 5,
                     valid=valid, hit=hit, depth=rng.random(n) * 10,
                     normal=rng.normal(size=(n, 3)), illumination=rng.random(n),
                     uncertainty=rng.random(n) if b % 3 == 0 else None,
                     share=1.0 if b < 3 else 1.0 / 3.0,
                     albedo=rng.random((n, 3)) if b % 2 else None)
        films[mode] = [film._sums(t)[0] for t in tiles] if streamed else [film._frame]
    for a, b in zip(films["numpy"], films["compiled"]):
        for name in vars(a):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    for name in ("count", "unc", "albedo"):                  # every kind of sum was made
        assert sum(getattr(a, name).sum() for a in films["numpy"]) > 0


def _stage_inputs(seed, k=4000):
    """A bundle's hits for the stage kernels: paths (some camera rays, some bounce rays with
    a density, some past the transparent limit), faces seen from both sides, shading normals
    facing the viewer or not, emissive, partly transparent and glass surfaces."""
    from neurolens_addon.engine.materials import SurfacePoint
    from neurolens_addon.engine.scene_cast import Hits
    from neurolens_addon.engine.shading import Paths
    rng = np.random.default_rng(seed)
    d = _unit(rng, k)
    kinds = rng.integers(0, 3, (k, 4))
    kinds[rng.random(k) < 0.2, 3] = 8                      # at the transparent limit (8)
    depth = rng.integers(0, 4, k)
    pdf = np.where(depth > 0, rng.random(k) * 2.0, 0.0)
    p = Paths(rng.integers(0, k // 2, k), rng.normal(size=(k, 3)), d, rng.random((k, 3)),
              rng.random(k) + 0.5, pdf, depth, kinds)
    hits = Hits(np.arange(k), rng.normal(size=(k, 3)) * 3.0, rng.normal(size=(k, 3)),
                np.zeros(k, np.int64), np.zeros(k, np.int32))
    normal = _unit(rng, k)
    emission = rng.random((k, 3)) * (rng.random(k) < 0.3)[:, None] * 5.0
    alpha = np.where(rng.random(k) < 0.6, 1.0, rng.random(k))
    alpha[rng.random(k) < 0.05] = 0.0
    transmission = np.where(rng.random(k) < 0.2, rng.random(k), 0.0)
    sp = SurfacePoint(rng.random((k, 3)), np.where(rng.random(k) < 0.5, 0.0, rng.random(k)),
                      rng.random(k), emission, normal, transmission, np.full(k, 1.5),
                      np.full(k, 0.04), alpha, np.zeros(k), np.ones(k))
    return rng, p, hits, sp


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("emitters_on", [False, True], ids=["no-emitters", "emitters"])
def test_20_the_fused_surface_stage_equals_the_numpy_stage(seed, emitters_on):
    """stage_kernels.surface against Shader._surface (numpy): the viewer-facing face and
    shading normals, the offsets, the emission added (MIS against the emissive meshes where
    they are sampled, clamped), the alpha choice and the throughput past the limit."""
    from neurolens_addon.engine import stage_kernels
    from neurolens_addon.engine.emitters import Emitters
    from neurolens_addon.engine.settings import RenderSettings
    from neurolens_addon.engine.shading import EPSILON, Paths, Shader, clamped
    assert stage_kernels.EPSILON == EPSILON
    rng, p, hits, sp = _stage_inputs(seed)
    k = p.idx.size
    emitters = Emitters(rng.normal(size=(6, 3, 3)), rng.random((6, 3)) + 0.1) \
        if emitters_on else None
    settings = RenderSettings(clamp_direct=3.0, clamp_indirect=1.0, transparent_bounces=8)
    shader = Shader(None, None, [], None, emitters=emitters, settings=settings)
    t_hit = rng.random(k) * 4.0 + 0.1
    px, sm, dim = rng.integers(0, 1 << 20, k), rng.integers(0, 64, k), 16 + 4096 * 2
    share = 1.0
    rgb_want, rgb_got = np.zeros((k // 2, 3)), np.zeros((k // 2, 3))
    met_direct = p.depth <= 1

    def add(samples, contribution, direct):
        c = clamped(contribution, np.where(direct, 3.0, 1.0) * share)
        for ch in range(3):
            rgb_want[:, ch] += np.bincount(samples, c[:, ch], minlength=rgb_want.shape[0])

    p_want = Paths(*(np.copy(getattr(p, f)) for f in Paths.__dataclass_fields__))
    ng, nf, wo, eps, front, through, keep = shader._surface(p_want, hits, sp, t_hit, px, sm,
                                                            dim + 4, met_direct, add)
    p_got = Paths(*(np.copy(getattr(p, f)) for f in Paths.__dataclass_fields__))
    got = stage_kernels.run_surface(p_got, hits, sp, t_hit, px, sm, shader.seed, dim + 4, 8,
                                    emitters.total if emitters else -1.0, 3.0, 1.0, rgb_got)
    np.testing.assert_allclose(got[0], ng, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(got[1], nf, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(got[2], eps[:, 0], rtol=1e-15)
    for g, w in zip(got[3:], (front, through, keep)):
        assert np.array_equal(g, w)
    np.testing.assert_allclose(p_got.thr, p_want.thr, rtol=1e-15)
    np.testing.assert_allclose(rgb_got, rgb_want, rtol=1e-12, atol=1e-14)
    assert through.any() and (~keep).any() and rgb_want.any() and (~front).any()
    assert (p_want.thr != p.thr).any()                     # the limit's opacity applied


@pytest.mark.parametrize("world_kind", ["textured", "flat"])
@pytest.mark.parametrize("seed", [3, 4])
def test_21_the_fused_light_stage_equals_the_numpy_strategies(seed, world_kind):
    """stage_kernels.light_samples against Shader._light_contribution (numpy) strategy by
    strategy (every light kind, the emissive meshes, a textured world given as its samples or
    a flat one sampled in the kernel), with the lights' and the world's numpy sampling: the
    same samples light the same points, in the numpy stage's order, with its contributions,
    directions and shadow-ray lengths."""
    from neurolens_addon.engine import stage_kernels
    from neurolens_addon.engine.emitters import Emitters
    from neurolens_addon.engine.lights import World
    from neurolens_addon.engine.settings import RenderSettings
    from neurolens_addon.engine.shading import Shader
    from neurolens_addon.engine.textures import Texture
    rng, p, hits, sp = _stage_inputs(seed)
    k = p.idx.size
    lights = list(_lights().values())
    lights[2].shadow = False                               # a light that casts no shadow
    emitters = Emitters(rng.normal(size=(6, 3, 3)), rng.random((6, 3)) + 0.1)
    world = (World(texture=Texture(rng.random((8, 16, 3)).astype(np.float32)), strength=0.5)
             if world_kind == "textured" else World(colour=(0.3, 0.2, 0.1)))
    shader = Shader(None, None, lights, world, emitters=emitters,
                    settings=RenderSettings(diffuse_bounces=2, glossy_bounces=1))
    nf = _unit(rng, k)
    ng = np.where(rng.random(k)[:, None] < 0.9, nf, _unit(rng, k))
    wo = _unit(rng, k)
    wo = np.where((np.einsum("ij,ij->i", nf, wo) < 0)[:, None], -wo, wo)
    pos, eps = hits.location, rng.random(k) * 1e-3
    px, sm = rng.integers(0, 1 << 20, k), rng.integers(0, 64, k)
    opaque = 1.0 - sp.transmission
    last = p.depth >= 3
    terms = sk.run_layer_terms(sp.roughness, nf, wo, sp.f0, sp.multiscatter, mf.tables())
    dims = [10 + 2 * i for i in range(len(lights))] + [8, 6]
    strategies = lights + [emitters, world]
    want = []
    for source, d0 in zip(strategies, dims):
        u1, u2 = (camera_rays.hash_u01_numpy(shader.seed, px, sm, d) for d in (d0, d0 + 1))
        if source is world:
            wi, li, pl = world.sample(k, u1, u2)
            dist, tested = np.full(k, np.inf), True
        else:
            wi, dist, li, pl = source.sample(pos, u1, u2)
            tested = getattr(source, "shadow", True)
        live, contrib, wi, dist = shader._light_contribution(p, sp, nf, ng, wo, wi, li, pl,
                                                             dist, opaque, last)
        if live is None:
            continue
        reach = np.where(np.isinf(dist), np.inf, dist - 2.0 * eps[live])
        want.append((live, contrib, wi, reach, np.full(live.size, tested)))
    want = [np.concatenate([w[i] for w in want]) for i in range(5)]
    u = sk.run_hash_u01_dims(shader.seed, px, sm, [6, 7])
    on = ~last
    got = stage_kernels.run_light_samples(
        shader.seed, dims, px, sm, shader._light_table, emitters,
        world.sample(k, u[0], u[1]) if world_kind == "textured" else world.colour, p.thr, sp,
        nf, ng, wo, opaque, on & (p.kinds[:, 1] < 1), on & (p.kinds[:, 0] < 2), terms, pos, eps)
    assert np.array_equal(got[0], want[0])
    np.testing.assert_allclose(got[1], want[1], rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(got[3], want[3], rtol=1e-10)
    assert np.array_equal(got[4], want[4])
    assert np.array_equal(got[5], pos[want[0]])            # each shadow ray leaves its point
    assert got[0].size > k and (~got[4]).any() and np.isinf(got[3]).any()


@pytest.mark.parametrize("transparent", [False, True], ids=["film", "transparent-film"])
def test_22_the_fused_misses_stage_equals_the_numpy_one(transparent):
    """stage_kernels.misses against Shader._light_hits and ._escapes (numpy): the distance
    to each hit, every light with size met by bounce rays before their surface (rays aimed
    at the lights, some hitting a surface first), a flat world for the rays that escape, MIS
    weights where a ray has a density, clamped sums."""
    from neurolens_addon.engine import stage_kernels
    from neurolens_addon.engine.lights import World
    from neurolens_addon.engine.scene_cast import Hits
    from neurolens_addon.engine.settings import RenderSettings
    from neurolens_addon.engine.shading import Paths, Shader, clamped
    rng = np.random.default_rng(22)
    k = 6000
    lights = list(_lights().values())
    shader = Shader(None, None, lights, World(colour=(0.2, 0.3, 0.4)),
                    settings=RenderSettings(clamp_direct=4.0, clamp_indirect=2.0),
                    transparent=transparent)
    o = rng.normal(size=(k, 3)) * 1.5
    target = lights[rng.integers(0, len(lights))].position + rng.normal(size=(k, 3)) * 0.3
    d = np.where((rng.random(k) < 0.6)[:, None], target - o, _unit(rng, k))
    d /= np.linalg.norm(d, axis=1)[:, None]
    depth = rng.integers(0, 4, k)
    paths = Paths(rng.integers(0, k // 3, k), o, d, rng.random((k, 3)), rng.random(k) + 0.5,
                  np.where((depth > 0) & (rng.random(k) < 0.7), rng.random(k) * 3.0, 0.0),
                  depth, np.zeros((k, 4), np.int64))
    ray = np.flatnonzero(rng.random(k) < 0.5)
    hits = Hits(ray, o[ray] + d[ray] * (rng.random(ray.size) * 3.0)[:, None],
                _unit(rng, ray.size), np.zeros(ray.size, np.int64), np.zeros(ray.size, np.int32))
    want, got = np.zeros((k // 3, 3)), np.zeros((k // 3, 3))

    def add(samples, contribution, direct):
        c = clamped(contribution, np.where(direct, 4.0, 2.0))
        for ch in range(3):
            want[:, ch] += np.bincount(samples, c[:, ch], minlength=want.shape[0])

    t_want = np.full(k, np.inf)
    t_want[ray] = np.linalg.norm(hits.location - o[ray], axis=1)
    met_direct = depth <= 1
    shader._light_hits(paths, t_want, met_direct, add)
    shader._escapes(paths, np.isinf(t_want), met_direct, add)
    t_got = stage_kernels.run_misses(paths, hits, shader._hit_table, shader.world.colour, True,
                                     transparent, 4.0, 2.0, got)
    np.testing.assert_allclose(t_got, t_want, rtol=1e-14)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    assert shader._hit_table.shape[0] == sum(not light.is_delta for light in lights) > 5
    lit = np.zeros((k // 3, 3))
    shader._light_hits(paths, t_want, met_direct,
                       lambda s, c, _d: np.add.at(lit, s, c))
    assert (lit > 0).any(axis=1).sum() > 100               # the lights are met, not only the sky


@pytest.mark.parametrize("selection", ["mask", "indices", "none"])
def test_23_a_compiled_compaction_takes_the_rows_numpy_takes(selection, monkeypatch):
    """Paths.take through stage_kernels.take_paths (one pass over every field) against numpy's
    fancy indexing of each field: a boolean mask, indices in any order, or no rows; and the
    bounce's compaction with its depth raised by one."""
    from neurolens_addon.engine import stage_kernels
    from neurolens_addon.engine.shading import Paths
    rng = np.random.default_rng(23)
    k = 5000
    paths = Paths(rng.integers(0, 10 ** 6, k), rng.normal(size=(k, 3)),
                  rng.normal(size=(k, 3))[:, ::-1],            # a strided view
                  rng.random((k, 3)), rng.random(k), rng.random(k), rng.integers(0, 9, k),
                  rng.integers(0, 5, (k, 4)))
    sel = {"mask": rng.random(k) < 0.4, "indices": rng.permutation(k)[:1700],
           "none": np.zeros(k, bool)}[selection]
    got = paths.take(sel)
    monkeypatch.setattr(sk, "active", lambda: False)     # the numpy reference
    want = paths.take(sel)
    for name in Paths.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert got.idx.size == (np.count_nonzero(sel) if sel.dtype == bool else sel.size)
    raised = stage_kernels.run_take_paths(sel, *paths.fields(), depth_add=1)
    np.testing.assert_array_equal(raised[6], want.depth + 1)


def test_24_embree_answers_are_gathered_into_the_hits_numpy_gathers():
    """mesh_kernels.gather_hits against the numpy gathers of EmbreeCaster.closest: the rays
    with a hit (geomID >= 0) in order, o + tfar d in float64, the triangle's normal, polygon
    and object, in their types."""
    from neurolens_addon.engine import mesh_kernels
    rng = np.random.default_rng(24)
    k, t = 8000, 300
    geom = np.where(rng.random(k) < 0.6, 0, -1).astype(np.int32)
    prim = np.where(geom >= 0, rng.integers(0, t, k), -1).astype(np.int32)
    tfar = (rng.random(k) * 50.0).astype(np.float32)
    origin, direction = rng.normal(size=(k, 3)), _unit(rng, k)
    normal, poly = _unit(rng, t), rng.integers(0, 100, t).astype(np.int32)
    obj = rng.integers(0, 5, t).astype(np.int32)
    ray, loc, nrm, hp, ho = mesh_kernels.run_gather_hits(geom, prim, tfar, origin, direction,
                                                         normal, poly, obj)
    want = np.flatnonzero(geom >= 0)
    pid = prim[want]
    np.testing.assert_array_equal(ray, want)
    np.testing.assert_array_equal(loc, origin[want] + tfar[want, None].astype(np.float64)
                                  * direction[want])
    np.testing.assert_array_equal(nrm, normal[pid])
    np.testing.assert_array_equal(hp, poly[pid])
    np.testing.assert_array_equal(ho, obj[pid])
    assert ray.dtype == hp.dtype == np.int64 and ho.dtype == np.int32 and 4000 < ray.size < 6000


def test_25_face_normals_are_the_numpy_cross_products(monkeypatch):
    """embree_cast.face_normals through the kernel against its numpy branch: unit
    (b - a) x (c - a) in Blender's winding, a degenerate triangle's normal zero, not NaN."""
    from neurolens_addon.engine import embree_cast, shading_kernels
    rng = np.random.default_rng(25)
    vertices = rng.normal(size=(500, 3)) * 10.0
    indices = rng.integers(0, 500, (2000, 3)).astype(np.int32)
    indices[7] = (3, 3, 9)                                  # two corners the same point
    monkeypatch.setenv("NEUROLENS_KERNELS", "compiled")
    got = embree_cast.face_normals(vertices, indices)
    monkeypatch.setenv("NEUROLENS_KERNELS", "numpy")
    assert not shading_kernels.active()
    want = embree_cast.face_normals(vertices, indices)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(got[7], 0.0)
    distinct = (indices[:, 0] != indices[:, 1]) & (indices[:, 1] != indices[:, 2]) \
        & (indices[:, 0] != indices[:, 2])
    np.testing.assert_array_equal(got[~distinct], 0.0)
    np.testing.assert_allclose(np.linalg.norm(got[distinct], axis=1), 1.0, rtol=0, atol=1e-12)
    a, b, c = (vertices[indices[0, i]] for i in range(3))
    assert np.dot(got[0], np.cross(b - a, c - a)) > 0      # the winding kept
