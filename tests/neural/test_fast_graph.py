"""forward_fast.onnx (onnx_export.build_fast) and the trace_from_sensor path built on it
(neural.model), on small random models (tests/neural/synthetic.py).

The fast graph must mean exactly what forward.onnx + the numpy guards + the stop test mean:
its rays agree with the float64 reference to the forward graph's tolerances, its in_domain
bits equal the numpy guards' masks, and trace_from_sensor gives the same statuses and the same
rays (to float32 rounding) as the forward.onnx path, for any input, however malformed.
"""

import base64
import json
import shutil

import numpy as np
import onnxruntime as ort
import pytest

from neurolens_addon.core.aperture import PolygonAperture
from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.neural import reference
from neurolens_addon.neural.domain import frame_inputs
from neurolens_addon.neural.model import LearnedLens
from neurolens_addon.neural.modelfile import FAST_FILE
from tests.neural.synthetic import (PLANES, make_model, near_split, random_rays,
                                    write_model, write_models)
from onnx_export import build_fast, occupancy_limits

POS_TOL, DIR_TOL = 2e-5, 2e-6            # as tests/neural/test_onnx_model.py
MODELS = {"disp_1_3": dict(dispersion=True, cells=(1, 3), seed=0),
          "nodisp_3_1": dict(dispersion=False, cells=(3, 1), seed=1),
          "sparse_disp": dict(sparse=True, skip_degree=5, cells=(1, 3), seed=7),
          "sparse_nodisp": dict(sparse=True, skip_degree=5, dispersion=False, seed=8),
          "p1": dict(skip_degree=1, seed=2), "p3_e1": dict(skip_degree=3, ensemble=1, seed=3),
          "p4_h12": dict(skip_degree=4, hidden=12, seed=4), "p5": dict(skip_degree=5, seed=5),
          # the cartesian frame of anamorphic lenses (core.irf): no rotation, 4-D occupancy
          "cart_disp_1_3": dict(frame="cartesian", cells=(1, 3), seed=9),
          "mixed_disp_1_3": dict(frame="radial,cartesian", cells=(1, 3), seed=11),
          "cart_sparse_disp": dict(frame="cartesian", sparse=True, skip_degree=5, seed=10),
          "cart_p4_nodisp_3_1": dict(frame="cartesian", skip_degree=4, dispersion=False,
                                     cells=(3, 1), seed=11)}
#: the front stage narrowed and with holes, per frame: (bounds lo, hi; occupancy lo, hi, shape)
HOLES = {"radial": ([0.0, -2.0, -2.0, -1.0, 400.0], [5.5, 2.0, 2.0, 2.0, 760.0],
                    [0.0, -1.0, -1.0], [8.0, 1.0, 1.0], [4, 5, 5]),
         "cartesian": ([-5.5, -5.5, -2.0, -2.0, -1.0, 400.0], [5.5, 5.5, 2.0, 2.0, 2.0, 760.0],
                       [1.0, -0.3, -0.05, -0.03], [6.0, 0.3, 0.1, 0.04], [4, 4, 5, 5])}
# (the cartesian grid spans where the stage-1 outputs fall: x' 2..5, |y'| < 0.2, small u', v')


def _holes(model, seed=0):
    """Punch empty occupancy cells into both stages (about a fifth of the cells)."""
    rng = np.random.default_rng(seed)
    for st in model["stages"]:
        occ = st.get("occupancy")
        if occ is None:
            continue
        grid = rng.random(occ["shape"]) > 0.2
        occ["bits"] = base64.b64encode(np.packbits(grid.ravel())).decode()
    return model


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("fast")
    out = write_models(root, MODELS)
    for name, frame in (("holes", "radial"), ("cart_holes", "cartesian")):
        m = make_model(dispersion=True, cells=(1, 3), seed=6, frame=frame)
        lo, hi, olo, ohi, shape = HOLES[frame]
        front = m["stages"][1]
        front["bounds"] = {"lo": lo, "hi": hi}
        front["occupancy"] = {"lo": olo, "hi": ohi, "shape": shape, "bits": ""}
        m = _holes(m)
        out[name] = (m, write_model(m, root / f"{name}.neurolens"))
    return out


def _session(model):
    so = ort.SessionOptions()
    so.log_severity_level = 3
    return ort.InferenceSession(build_fast(model).SerializeToString(), so,
                                providers=["CPUExecutionProvider"])


def _run(sess, rays, sensor_z=0.0, r2=np.inf):
    """rays (N, 6) (x, y, dx, dy, dz, lambda) -> dict of the graph's outputs."""
    out = sess.run(None, {"rays": np.ascontiguousarray(rays.T, dtype=np.float32),
                          "sensor_z": np.atleast_1d(np.asarray(sensor_z, np.float32)),
                          "stop_r2": np.array([r2], np.float64)})
    return dict(zip([o.name for o in sess.get_outputs()], out))


def _sensor_rays(n, seed, sensor_z=-0.5, r_max=12.0):
    """Rays on the film plane z = sensor_z (float64 Rays) reaching the synthetic Pi_1 box."""
    pi1 = random_rays(n, seed=seed, r_max=r_max, n_axis=0)
    t = sensor_z / pi1[:, 4]
    o = np.stack([pi1[:, 0] + t * pi1[:, 2], pi1[:, 1] + t * pi1[:, 3], np.zeros(n)])
    return Rays(o, pi1[:, 2:5].T.copy(), pi1[:, 5].copy())


def _same_trace(a, b, rows=None, pos=POS_TOL, dirn=DIR_TOL):
    rows = slice(None) if rows is None else rows
    np.testing.assert_array_equal(a.status[rows], b.status[rows])
    np.testing.assert_array_equal(a.valid[rows], b.valid[rows])
    np.testing.assert_array_equal(a.surface[rows], b.surface[rows])
    np.testing.assert_allclose(a.rays.o[:, rows], b.rays.o[:, rows], rtol=0, atol=pos)
    np.testing.assert_allclose(a.rays.d[:, rows], b.rays.d[:, rows], rtol=0, atol=dirn)
    np.testing.assert_array_equal(a.rays.wavelength[rows], b.rays.wavelength[rows])


@pytest.mark.parametrize("name", list(MODELS))
def test_01_fast_graph_matches_reference(built, name):
    """Rays on Pi_1 (sensor_z = input_z): stop_xy and out_rays = reference.evaluate within the
    forward graph's float32 tolerances, r = 0 rays included; every ray in the domain."""
    model, _ = built[name]
    sess = _session(model)
    rays = random_rays(20_000, seed=3).astype(np.float32).astype(np.float64)
    got = _run(sess, rays)
    assert (got["in_domain"] == 3).all() and (got["status"] == RayStatus.OK).all()
    ref = reference.evaluate(model, rays)
    keep = ~near_split(model, rays, 1e-4)
    assert keep.mean() > 0.99
    np.testing.assert_allclose(got["stop_xy"].T[keep], ref[0][keep, :2], rtol=0, atol=POS_TOL)
    np.testing.assert_allclose(got["out_rays"][:2].T[keep], ref[1][keep, :2], rtol=0,
                               atol=POS_TOL)
    np.testing.assert_allclose(got["out_rays"][2:].T[keep], ref[1][keep, 2:], rtol=0,
                               atol=DIR_TOL)


def _guard_masks(lens, rays):
    """The numpy guards on the float32 ray the graph builds (same float32 normalisation):
    (stage-1 mask incl. wavelength / w > 0 / |d|^2 / lambda finite, forward-path stage-2 mask)."""
    x, y, dx, dy, dz, lam = np.asarray(rays, np.float32).T
    with np.errstate(all="ignore"):
        n2 = (dx * dx + dy * dy) + dz * dz
        nrm = np.sqrt(n2)
        u, v, w = dx / nrm, dy / nrm, dz / nrm
        ok1 = lens._guards[0].inside(frame_inputs(lens.frames[0], x, y, u, v, w, lam,
                                                  lens.dispersion))
        ok1 &= (w > 0) & (n2 >= np.float32(1e-30)) & (n2 <= np.float32(1e30))
        ok1 &= np.isfinite(lam)
        if lens.dispersion:
            lo, hi = lens.domain["wavelength_range_nm"]
            ok1 &= (lam >= lo) & (lam <= hi)
    return ok1


@pytest.mark.parametrize("name", ["holes", "cart_holes"])
def test_02_in_domain_equals_the_numpy_guards(built, name):
    """in_domain bit 0 = the numpy stage-1 guard on the same float32 ray (inside, outside the
    box in each coordinate, empty occupancy cells, wavelength out of range, NaN and inf in every
    component); bit 1 = the stage-2 guard as the forward.onnx path applies it. Both frames:
    radial (3-D occupancy over r, u_r, u_t) and cartesian (4-D over x, y, u, v)."""
    model, d = built[name]
    lens = LearnedLens.load(d, threads=1)
    sess = _session(model)
    rng = np.random.default_rng(11)
    rays = random_rays(6000, seed=12, r_max=19.0, dir_max=0.75)
    rays[:300, :2] *= 1.3                                          # r beyond the box
    rays[300:600, 2:4] *= 1.6                                      # |u_r|, |u_t| beyond 0.6
    rays[300:600, 4] = np.sqrt(np.maximum(1 - (rays[300:600, 2:4] ** 2).sum(1), 0))
    rays[600:700, 5] = rng.uniform(200, 399.9, 100)                # wavelength too short
    rays[700:800, 5] = rng.uniform(760.1, 900, 100)                # too long
    for k in range(6):                                             # NaN and inf everywhere
        rays[800 + 20 * k:810 + 20 * k, k] = np.nan
        rays[810 + 20 * k:820 + 20 * k, k] = np.inf * (-1) ** k
    rays[920:940, 2:5] = 0.0                                       # no direction
    rays[940:960, 4] *= -1                                         # backwards
    got = _run(sess, rays)
    ok1 = _guard_masks(lens, rays)
    assert 0.3 < ok1.mean() < 0.9 and not ok1[600:960].any()
    np.testing.assert_array_equal((got["in_domain"] & 1).astype(bool), ok1)
    # stage 2: the guard on the forward graph's stop-plane rays, away from its limits (the two
    # graphs' stop-plane rays differ by float32 rounding)
    stop_fwd, _, _, dom, _ = lens._run(rays, False, 4096)     # stop rays not zeroed
    in_dom = dom[:, 1]
    both = got["in_domain"] == 3
    X2 = frame_inputs(lens.frames[1], *stop_fwd.T, rays[:, 5].astype(np.float32), True)
    g2 = lens._guards[1]
    near = np.zeros(len(rays), bool)
    for i in range(len(X2)):          # the box's faces (r's upper one, radial)
        near |= (np.abs(X2[i] - g2.hi[i]) < 1e-4) | (np.abs(X2[i] - g2.lo[i]) < 1e-4)
    for i in range(g2.grid.ndim):
        f = (X2[i] - g2.occ_lo[i]) * (g2.grid.shape[i] / (g2.occ_hi[i] - g2.occ_lo[i]))
        near |= np.abs(f - np.round(f)) < 1e-3
    assert near[ok1].mean() < 0.02
    np.testing.assert_array_equal(both[ok1 & ~near], in_dom[ok1 & ~near])
    np.testing.assert_array_equal(both[~ok1], False)
    assert ((both != ok1) & ok1).sum() > 100 and both.sum() > 1000   # stage 2 refuses some
    # rows out of the domain carry zeros
    assert (got["out_rays"][:, ~both] == 0).all() and (got["stop_xy"][:, ~ok1] == 0).all()
    assert np.isfinite(got["out_rays"]).all() and np.isfinite(got["stop_xy"]).all()


def test_03_occupancy_limits_are_exact():
    """LO/HI from occupancy_limits reproduce the guard's float32 range test bit for bit at
    the limits (the float32 neighbours on both sides) and at random points."""
    rng = np.random.default_rng(5)
    for _ in range(30):
        lo = rng.uniform(-2, 1, 3) * 10.0 ** rng.integers(-3, 3)
        hi = lo + rng.uniform(0.01, 5, 3) * 10.0 ** rng.integers(-2, 2)
        shape = rng.integers(1, 80, 3)
        for i, (TL, TU) in enumerate(occupancy_limits(lo, hi, shape)):
            o = np.float32(lo[i])
            sc = np.float32(shape[i] / (hi[i] - lo[i]))
            xs = np.concatenate([
                [np.nextafter(TL, np.float32(-np.inf)), TL, np.nextafter(TL, np.float32(np.inf)),
                 np.nextafter(TU, np.float32(-np.inf)), TU, np.nextafter(TU, np.float32(np.inf))],
                rng.uniform(lo[i] - 1, hi[i] + 1, 200)]).astype(np.float32)
            with np.errstate(all="ignore"):
                f = (xs - o) * sc
                want = (f >= 0) & (f <= shape[i])
            np.testing.assert_array_equal((xs >= TL) & (xs <= TU), want)


@pytest.mark.parametrize("name", ["disp_1_3", "nodisp_3_1", "p5", "holes", "cart_disp_1_3",
                                  "cart_p4_nodisp_3_1", "cart_holes"])
def test_04_trace_from_sensor_fast_equals_forward_path(built, name):
    """Film rays (unit and non-unit directions, one plane or one per ray, the design stop, a
    smaller stop, a hexagonal iris): the forward_fast path and the forward.onnx path give the
    same statuses, surfaces and wavelengths, and the same rays to float32 rounding."""
    model, d = built[name]
    lens = LearnedLens.load(d, threads=2)
    assert lens.has_fast_graph
    rays = _sensor_rays(12_000, seed=21)
    rays.d[:, ::3] *= 1.7                                  # not unit: both paths normalise
    rays.wavelength[::50] = 900.0 if lens.dispersion else rays.wavelength[::50]
    zs = np.where(np.arange(rays.n) % 2 == 0, -0.5, -1.25)
    o2 = rays.o.copy()
    o2[:2, 1::2] -= 0.75 * rays.d[:2, 1::2] / rays.d[2, 1::2]      # the same rays, lower film
    per_ray = Rays(o2, rays.d, rays.wavelength)
    stop, _, _, ok = lens.evaluate(np.stack([*_pi1(rays, -0.5), rays.wavelength], 1))
    R = float(np.median(np.hypot(stop[ok, 0], stop[ok, 1])))
    for rr, z, kw in ((rays, -0.5, {}), (per_ray, zs, {}), (rays, -0.5, {"stop_radius": R}),
                      (rays, -0.5, {"stop_radius": R, "aperture": PolygonAperture(6)})):
        fast = lens.trace_from_sensor(rr, z, **kw)
        slow = lens.trace_from_sensor(rr, z, uncertainty=True, **kw)
        assert fast.uncertainty is None and slow.uncertainty is not None
        stop = lens.evaluate(np.stack([*_pi1(rr, z), rr.wavelength], 1))[0]
        R = kw.get("stop_radius", PLANES["stop_radius_mm"])
        rim = np.abs(np.hypot(stop[:, 0], stop[:, 1]) - R) < 1e-3 * R
        if "aperture" in kw:
            hx, hy = stop[:, 0] / R, stop[:, 1] / R
            ap = kw["aperture"]
            rim = ap.inside(hx * 1.001, hy * 1.001) ^ ap.inside(hx * 0.999, hy * 0.999)
        _same_trace(fast, slow, ~rim)
        st = np.bincount(fast.status, minlength=9)
        assert st[RayStatus.OK] > 0.05 * rays.n
        assert "stop_radius" not in kw or st[RayStatus.CLIPPED_STOP] > 0.1 * rays.n


def _pi1(rays, sensor_z):
    """Pi_1 rays (x, y, u, v, w) the float64 way (for reference stop radii)."""
    d = rays.d / np.linalg.norm(rays.d, axis=0)
    t = (0.0 - np.broadcast_to(sensor_z, (rays.n,))) / d[2]
    return rays.o[0] + t * d[0], rays.o[1] + t * d[1], d[0], d[1], d[2]


def test_05_malformed_rays_get_the_forward_paths_status(built):
    """NaN / inf anywhere, zero, backwards and enormous or tiny direction vectors, a NaN
    sensor plane: BAD_INPUT exactly where the forward.onnx path says so; directions scaled by
    1e20 or 1e-20 (float32 cannot square them) are re-run from float64 and trace normally."""
    model, d = built["disp_1_3"]
    lens = LearnedLens.load(d, threads=2)
    rays = _sensor_rays(3000, seed=31)
    o, dd, wl = rays.o, rays.d, rays.wavelength
    o[0, 0], o[1, 1], dd[0, 2], dd[2, 3], wl[4] = np.nan, np.inf, np.nan, -np.inf, np.nan
    dd[:, 5] = 0.0
    dd[2, 6] *= -1
    dd[:, 7] = [0.0, 0.0, 1e300]                          # |d|^2 overflows float64 too
    dd[:, 100:200] *= 1e20
    dd[:, 200:300] *= 1e-20
    dd[:, 300:310] *= 1e-40                               # subnormal float32 components
    o[:2, 310:320] = 1e35                                 # beyond any domain
    zs = np.full(rays.n, -0.5)
    zs[8] = np.nan
    fast = lens.trace_from_sensor(Rays(o, dd, wl), zs)
    slow = lens.trace_from_sensor(Rays(o, dd, wl), zs, uncertainty=True)
    _same_trace(fast, slow)
    assert (fast.status[:9] == RayStatus.BAD_INPUT).all()
    assert fast.valid[100:310].mean() > 0.5
    assert (fast.status[310:320] == RayStatus.OUT_OF_DOMAIN).all()
    for a in (fast.rays.o, fast.rays.d, fast.rays.wavelength):
        assert np.isfinite(a).all() and (a[..., ~fast.valid] == 0).all()


def test_06_threads_and_batches_do_not_change_results(built):
    """1 or 2 worker threads, batches of 1000, 1 or the default: the same statuses, and rays
    equal to rounding (a GEMM may sum in another order for another batch width)."""
    _, d = built["disp_1_3"]
    rays = _sensor_rays(9000, seed=41)
    base = LearnedLens.load(d, threads=1).trace_from_sensor(rays, -0.5)
    two = LearnedLens.load(d, threads=2)
    for kw in ({}, {"batch": 1000}, {"batch": 1}):
        r = two.trace_from_sensor(rays if "batch" not in kw or kw["batch"] > 1 else
                                  Rays(rays.o[:, :50], rays.d[:, :50], rays.wavelength[:50]),
                                  -0.5, **kw)
        k = r.status.shape[0]
        np.testing.assert_array_equal(r.status, base.status[:k])
        np.testing.assert_allclose(r.rays.o, base.rays.o[:, :k], rtol=0, atol=1e-6)
        np.testing.assert_allclose(r.rays.d, base.rays.d[:, :k], rtol=0, atol=1e-7)
    empty = two.trace_from_sensor(Rays(np.zeros((3, 0)), np.zeros((3, 0)), np.zeros(0)), 0.0)
    assert empty.status.shape == (0,) and empty.rays.o.shape == (3, 0)


def test_07_models_without_the_fast_graph_still_load(built, tmp_path):
    """A model written before forward_fast.onnx existed loads and traces via forward.onnx."""
    _, d = built["disp_1_3"]
    dst = tmp_path / d.name
    shutil.copytree(d, dst)
    (dst / FAST_FILE).unlink()
    meta = json.loads((dst / "model.json").read_text())
    del meta["files"][FAST_FILE]
    (dst / "model.json").write_text(json.dumps(meta))
    lens = LearnedLens.load(dst, threads=1)
    assert not lens.has_fast_graph
    res = lens.trace_from_sensor(_sensor_rays(500, seed=51), -0.5)
    assert res.uncertainty is not None and res.valid.mean() > 0.5


def test_08_a_broken_fast_graph_is_refused(built, tmp_path):
    """Truncated forward_fast.onnx: ModelError on the hash; forward.onnx in its place with the
    hash updated: ModelError on its inputs / outputs."""
    import hashlib
    _, d = built["disp_1_3"]
    dst = tmp_path / "a" / d.name
    shutil.copytree(d, dst)
    data = (dst / FAST_FILE).read_bytes()
    (dst / FAST_FILE).write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match=r"forward_fast\.onnx.*sha256"):
        LearnedLens.load(dst)
    data = (d / "forward.onnx").read_bytes()
    (dst / FAST_FILE).write_bytes(data)
    meta = json.loads((dst / "model.json").read_text())
    meta["files"][FAST_FILE] = hashlib.sha256(data).hexdigest()
    (dst / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match=r"forward_fast\.onnx.*inputs.*expected"):
        LearnedLens.load(dst)


@pytest.mark.parametrize("which", [0, 1])
def test_09_free_space_stages(tmp_path, which):
    """A model with a free-space stage (a ray-table model: stage 2 of length 0 and no stop; or
    a stage-1 flight): the fast path equals the forward.onnx path."""
    m = make_model(dispersion=True, cells=(1, 1), seed=61)
    if which == 1:
        m["stages"][1] = {"name": "front", "propagate": True}
        m["planes"]["output_z"] = m["planes"]["stop_z"]
        m["planes"]["stop_radius_mm"] = None
    else:
        m["stages"][0] = {"name": "rear", "propagate": True}
    d = write_model(m, tmp_path / "free.neurolens")
    lens = LearnedLens.load(d, threads=2)
    rays = _sensor_rays(4000, seed=62, r_max=8.0)
    rays.d[:, 0] = np.nan
    kw = {} if which == 1 else {"stop_radius": 6.0}
    fast = lens.trace_from_sensor(rays, -0.5, **kw)
    slow = lens.trace_from_sensor(rays, -0.5, uncertainty=True, **kw)
    _same_trace(fast, slow)
    assert fast.valid.mean() > 0.1 and fast.status[0] == RayStatus.BAD_INPUT


def test_10_wavelength_of_a_model_without_dispersion(built):
    """Without dispersion lambda is not an input, yet a NaN / inf one is BAD_INPUT and one
    beyond float32 (1e39) still traces, as on the forward.onnx path."""
    _, d = built["nodisp_3_1"]
    lens = LearnedLens.load(d, threads=2)
    rays = _sensor_rays(2000, seed=71)
    rays.wavelength[:4] = [np.nan, np.inf, 1e39, 450.0]
    fast = lens.trace_from_sensor(rays, -0.5)
    slow = lens.trace_from_sensor(rays, -0.5, uncertainty=True)
    _same_trace(fast, slow)
    assert fast.status[:2].tolist() == [RayStatus.BAD_INPUT] * 2 and fast.valid[2:4].all()
