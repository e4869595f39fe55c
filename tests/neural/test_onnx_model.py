"""The ONNX export (onnx_export) and the learned-lens runtime (neural.model) on small
random models (tests/neural/synthetic.py), against the float64 reference (neural.reference).

float32 tolerances (the graph computes in float32 on inputs rounded to float32; the reference
in float64 on the same rounded inputs): positions 2e-5 mm (about 1e-6 of the 20-40 mm field),
directions 2e-6, spreads 2e-5; Jacobian |dJ| <= 5e-5 + 2e-5 |J| against central differences
(h = 1e-6) of the reference. Observed errors are 10-20x smaller.
"""

import base64
import copy
import hashlib
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from neurolens_addon.core.aperture import PolygonAperture
from neurolens_addon.core.errors import ModelError, NeuroLensError
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.neural import reference
from neurolens_addon.neural.model import LearnedLens
from tests.core.lenses import singlet
from tests.neural.synthetic import (PLANES, make_model, near_split, random_rays,
                                    reference_jacobian_fd,
                                    write_model, write_models)

POS_TOL, DIR_TOL, SPREAD_TOL = 2e-5, 2e-6, 2e-5
MODELS = {"disp_1_3": dict(dispersion=True, cells=(1, 3), seed=0),
          "nodisp_3_1": dict(dispersion=False, cells=(3, 1), seed=1),
          "sparse_disp": dict(sparse=True, skip_degree=5, cells=(1, 3), seed=7),
          "sparse_nodisp": dict(sparse=True, skip_degree=5, dispersion=False, seed=8),
          # the cartesian frame of anamorphic lenses (core.irf)
          "cart_disp_1_3": dict(frame="cartesian", cells=(1, 3), seed=9),
          # a frame per stage: a front anamorphic attachment before a rear group of revolution
          "mixed_disp_1_3": dict(frame="radial,cartesian", cells=(1, 3), seed=11),
          "mixed_rev_nodisp": dict(frame="cartesian,radial", dispersion=False, seed=12),
          "cart_sparse_nodisp_3_1": dict(frame="cartesian", sparse=True, skip_degree=5,
                                         dispersion=False, cells=(3, 1), seed=10)}


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """{name: (model dict, directory)} for the synthetic models, written once."""
    root = tmp_path_factory.mktemp("models")
    out = write_models(root, MODELS)
    return out


def _copy(built, name, tmp_path):
    m, d = built[name]
    dst = tmp_path / d.name
    shutil.copytree(d, dst)
    return copy.deepcopy(m), dst


def _rewrite_json(directory, edit):
    meta = json.loads((directory / "model.json").read_text())
    edit(meta)
    (directory / "model.json").write_text(json.dumps(meta))


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.mark.parametrize("name", list(MODELS))
def test_01_forward_matches_reference(built, name):
    """ONNX forward (LearnedLens.evaluate) = reference.evaluate to float32 tolerance, r = 0 too."""
    model, d = built[name]
    lens = LearnedLens.load(d, threads=2)
    rays = random_rays(20_000, seed=3).astype(np.float32).astype(np.float64)
    assert (np.hypot(rays[:, 0], rays[:, 1]) == 0).sum() == 200
    stop, out, spread, ok = lens.evaluate(rays)
    assert ok.all()
    ref = reference.evaluate(model, rays)
    keep = ~near_split(model, rays, 1e-4)
    assert keep.mean() > 0.99
    for got, want in zip((stop, out), ref[:2]):
        assert np.isfinite(got).all()
        np.testing.assert_allclose(got[keep, :2], want[keep, :2], rtol=0, atol=POS_TOL)
        np.testing.assert_allclose(got[keep, 2:], want[keep, 2:], rtol=0, atol=DIR_TOL)
    np.testing.assert_allclose(spread[keep], ref[2][keep], rtol=0, atol=SPREAD_TOL)
    assert (spread > 0).all()


@pytest.mark.parametrize("name", list(MODELS))
def test_02_jacobian_matches_finite_differences(built, name):
    """The in-graph forward-mode Jacobian equals central differences of the float64 reference."""
    model, d = built[name]
    lens = LearnedLens.load(d, threads=2)
    rays = random_rays(3000, seed=4, n_axis=0).astype(np.float32).astype(np.float64)
    rays = rays[~near_split(model, rays, 1e-3)]
    stop, out, spread, ok, J = lens.evaluate(rays, jacobian=True)
    assert ok.all() and J.shape == (len(rays), 4, 4)
    fwd = lens.evaluate(rays)
    np.testing.assert_allclose(out, fwd[1], rtol=0, atol=1e-6)
    Jfd = reference_jacobian_fd(model, rays, h=1e-6)
    assert np.all(np.abs(J - Jfd) <= 5e-5 + 2e-5 * np.abs(Jfd))


def test_03_on_axis_rays_finite_in_both_graphs(built):
    """Rays with r = 0 (and exactly axial ones) give finite rays, spreads and Jacobians."""
    model, d = built["disp_1_3"]
    lens = LearnedLens.load(d, threads=1)
    rays = random_rays(500, seed=5, n_axis=500)
    rays[:10, 2:5] = [0.0, 0.0, 1.0]
    res = lens.evaluate(rays, jacobian=True)
    assert res[3].all()
    for a in res[:3] + res[4:]:
        assert np.isfinite(a).all()
    ref = reference.evaluate(model, rays.astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(res[1][:, :2], ref[1][:, :2], rtol=0, atol=POS_TOL)


def test_04_streaming_equals_one_batch(built):
    """Batches of 1000 rays give the same result as one batch (memory bounded for any N)."""
    _, d = built["disp_1_3"]
    lens = LearnedLens.load(d, threads=1)
    rays = random_rays(10_500, seed=6)
    rays[::97, 0] = np.nan                       # out-of-domain rows mixed in
    one = lens.evaluate(rays, jacobian=True, batch=len(rays))
    many = lens.evaluate(rays, jacobian=True, batch=1000)
    for a, b in zip(one, many):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(one[3], many[3])


def test_05_out_of_domain_rays_flagged_and_zero(built, tmp_path):
    """Rays off the box, in a False cell, at a foreign wavelength or NaN/inf are flagged and 0."""
    model, d = _copy(built, "disp_1_3", tmp_path)
    occ = model["stages"][0]["occupancy"]
    grid = np.ones(occ["shape"], bool)
    grid[-1] = False                            # r in the last quarter of [0, 20] mm
    _rewrite_json(d, lambda m: m["stages"][0]["occupancy"].update(
        bits=base64.b64encode(np.packbits(grid.ravel())).decode()))
    lens = LearnedLens.load(d, threads=1)
    rays = random_rays(400, seed=7, r_max=14.0)
    bad = {"bounds": 0, "occupancy": 1, "wavelength": 2, "nan": 3, "inf": 4, "w": 5}
    rays[0, :2] = [25.0, 0.0]                   # r beyond the stage-1 box
    rays[1, :2] = [0.0, 16.0]                   # occupancy cell False
    rays[2, 5] = 300.0                          # below the wavelength range
    rays[3, 2] = np.nan
    rays[4, 1] = np.inf
    rays[5, 4] = 0.3                            # w below the box (0.6)
    stop, out, spread, ok = lens.evaluate(rays)
    assert not ok[list(bad.values())].any()
    assert ok[len(bad):].all()
    for a in (stop, out, spread):
        assert np.isfinite(a).all()
        assert (a[~ok] == 0).all()
    # stage 2 is checked on stage 1's output: shrink the front box below some stop-plane rays
    ref_stop = reference.evaluate(model, rays[len(bad):])[0]
    r_stop = np.hypot(ref_stop[:, 0], ref_stop[:, 1])
    cut = float(np.median(r_stop))
    _rewrite_json(d, lambda m: m["stages"][1]["bounds"]["hi"].__setitem__(0, cut))
    _, out2, _, ok2 = LearnedLens.load(d, threads=1).evaluate(rays)
    margin = np.abs(r_stop - cut) > 1e-3
    np.testing.assert_array_equal(ok2[len(bad):][margin], (r_stop <= cut)[margin])
    assert (out2[~ok2] == 0).all()


def test_06_truncated_onnx_refused(built, tmp_path):
    """A truncated forward.onnx raises ModelError naming the file and the hash mismatch."""
    _, d = _copy(built, "disp_1_3", tmp_path)
    data = (d / "forward.onnx").read_bytes()
    (d / "forward.onnx").write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match=r"forward\.onnx.*sha256.*truncated"):
        LearnedLens.load(d)


def test_07_foreign_onnx_refused(built, tmp_path):
    """Another model's ONNX file, or a swapped graph / garbage with a matching hash, is refused."""
    _, d = _copy(built, "disp_1_3", tmp_path)
    shutil.copy(built["nodisp_3_1"][1] / "forward_jacobian.onnx", d / "forward_jacobian.onnx")
    with pytest.raises(ModelError, match=r"forward_jacobian\.onnx.*another model"):
        LearnedLens.load(d)
    # the jacobian graph under the forward name, hash updated: the outputs give it away
    _, d2 = _copy(built, "disp_1_3", tmp_path / "b")
    data = (d2 / "forward_jacobian.onnx").read_bytes()
    (d2 / "forward.onnx").write_bytes(data)
    _rewrite_json(d2, lambda m: m["files"].update({"forward.onnx": _sha(data)}))
    with pytest.raises(ModelError, match=r"forward\.onnx.*outputs.*jacobian"):
        LearnedLens.load(d2)
    junk = b"not an onnx graph at all"
    (d2 / "forward.onnx").write_bytes(junk)
    _rewrite_json(d2, lambda m: m["files"].update({"forward.onnx": _sha(junk)}))
    with pytest.raises(ModelError, match=r"forward\.onnx.*onnxruntime cannot load"):
        LearnedLens.load(d2)


@pytest.mark.parametrize("edit, pattern", [
    (lambda m: m.pop("planes"), r"field 'planes': missing"),
    (lambda m: m["stages"][0].pop("bounds"), r"field 'stages\[0\]\.bounds': missing"),
    (lambda m: m["stages"][1]["cells"][0]["members"][1].update(W2=[[0.0]]),
     r"stages\[1\]\.cells\[0\]\.members\[1\]\.W2': expected shape \(8, 8\)"),
    (lambda m: m["stages"][0]["occupancy"].update(bits="AAAA"), r"occupancy\.bits.*bytes"),
    (lambda m: m["stages"][0]["tree"].__setitem__(0, {"cell": 5}), r"tree\[0\]\.cell.*not a cell"),
    (lambda m: m.update(format="something-else"), r"field 'format'.*not a NeuroLens model"),
    (lambda m: m.update(version=2), r"version 2 is not supported"),
    (lambda m: m["files"].pop("forward.onnx"), r"files\.forward\.onnx': missing"),
    (lambda m: m["stages"][0]["cells"][0]["members"][0].update(skip_degree=99),
     r"skip_degree': must be 1\.\.8"),
    (lambda m: m["stages"][0]["cells"][0]["members"][0].update(skip_terms=[[1, 0]]),
     r"skip_terms\[0\]': expected 1\.\.8 non-decreasing input indices"),
    (lambda m: m["stages"][0]["cells"][0]["members"][0].update(skip_terms=[[7]]),
     r"skip_terms\[0\]': expected .* indices in 0\.\.4"),
    (lambda m: m["stages"][0]["cells"][0]["members"][0].update(skip_terms=[[1], [1]]),
     r"skip_terms\[1\]': monomial \[1\] listed twice"),
    (lambda m: m["stages"][0]["cells"][0]["members"][0].update(skip_terms=[[1], [2]]),
     r"members\[0\]\.L': expected shape \(4, 2\)"),
    (lambda m: m["stages"][0]["cells"][0]["x_norm"].update(wavelength_ref_nm=float("nan")),
     r"'NaN' is not a number JSON allows"),
    (lambda m: m["stages"][0]["cells"][0]["x_norm"].update(w_residual_column=2),
     r"x_norm\.w_residual_column': expected the stage's w column 3, got 2"),
])
def test_08_bad_model_json_refused(built, tmp_path, edit, pattern):
    """Missing key, wrong shape, foreign format/version, malformed skip monomials or feature:
    ModelError naming the file and field."""
    _, d = _copy(built, "disp_1_3", tmp_path)
    _rewrite_json(d, edit)
    with pytest.raises(ModelError, match=pattern) as e:
        LearnedLens.load(d)
    assert str(d / "model.json") in str(e.value)
    assert isinstance(e.value, NeuroLensError)


def test_09_lens_hash_checked(tmp_path):
    """Another prescription is refused, naming both lenses and hashes; the right lens loads."""
    lens = singlet()
    good = write_model(make_model(hidden=4, lens_name=lens.name, lens_hash=lens.content_hash()),
                       tmp_path / "good.neurolens")
    assert LearnedLens.load(good, lens=lens).lens_name == lens.name
    other = write_model(make_model(hidden=4, lens_name="double Gauss", lens_hash="abc123"),
                        tmp_path / "dg.neurolens")
    with pytest.raises(ModelError, match=r"model 'dg\.neurolens' was trained for lens "
                                         r"'double Gauss' \(hash abc123\), not 'test singlet' "
                                         rf"\(hash {lens.content_hash()}\)"):
        LearnedLens.load(other, lens=lens)


def test_10_cpu_provider_without_cuda(built, monkeypatch):
    """With no CUDA provider available the session runs on, and reports, CPUExecutionProvider."""
    import onnxruntime as ort
    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CPUExecutionProvider"])
    lens = LearnedLens.load(built["disp_1_3"][1])
    assert lens.provider == "CPUExecutionProvider"
    if "CUDAExecutionProvider" not in ort.get_available_providers():
        assert LearnedLens.load(built["disp_1_3"][1], threads=1).provider == "CPUExecutionProvider"


@pytest.mark.parametrize("uncertainty", [False, True], ids=["forward_fast", "forward"])
def test_11_trace_from_sensor_statuses_and_rays(built, uncertainty):
    """trace_from_sensor = flight to Pi_1 + evaluate + exact stop test; statuses; invalid = 0.
    Both paths: forward_fast.onnx (default) and forward.onnx (uncertainty=True)."""
    model, d = built["disp_1_3"]
    lens = LearnedLens.load(d, threads=1)
    sensor_z = -0.5
    pi1 = random_rays(3000, seed=8, r_max=12.0, n_axis=0)   # r = 0 would not survive the
    # film -> Pi_1 round trip exactly, and a random model is not continuous across the axis
    # film points that reach these Pi_1 rays: step back from z = 0 to the sensor plane
    t = sensor_z / pi1[:, 4]
    o = np.stack([pi1[:, 0] + t * pi1[:, 2], pi1[:, 1] + t * pi1[:, 3], np.zeros(len(pi1))])
    dirs = pi1[:, 2:5].T.copy() * 2.0          # not unit: trace_from_sensor normalises
    wl = pi1[:, 5].copy()
    dirs[:, 0] = [0.0, 0.0, -1.0]              # backwards
    o[0, 1] = np.nan                           # bad origin
    wl[2] = 200.0                              # outside the wavelength range
    stop, out, spread, ok = lens.evaluate(pi1)
    r_stop = np.hypot(stop[:, 0], stop[:, 1]).astype(np.float64)
    rest = slice(3, None)
    kw = {"uncertainty": uncertainty}
    full = lens.trace_from_sensor(Rays(o, dirs, wl), sensor_z, **kw)    # design's stop radius
    assert lens.stop_radius_mm == PLANES["stop_radius_mm"]
    far = np.abs(r_stop[rest] - PLANES["stop_radius_mm"]) > 1e-4      # clear of the rim
    np.testing.assert_array_equal((full.status[rest] == RayStatus.CLIPPED_STOP)[far],
                                  (r_stop[rest] > PLANES["stop_radius_mm"])[far])
    R = float(np.median(r_stop[rest]))
    res = lens.trace_from_sensor(Rays(o, dirs, wl), sensor_z, stop_radius=R, **kw)
    assert res.status[0] == RayStatus.BAD_INPUT and res.status[1] == RayStatus.BAD_INPUT
    assert res.status[2] == RayStatus.OUT_OF_DOMAIN
    clipped = r_stop[rest] > R
    far = np.abs(r_stop[rest] - R) > 1e-4
    assert 0.4 < clipped.mean() < 0.6
    assert (res.status[rest][clipped & far] == RayStatus.CLIPPED_STOP).all()
    assert (res.status[rest][~clipped & far] == RayStatus.OK).all()
    v = res.valid
    np.testing.assert_allclose(res.rays.o[:2, v].T, out[v, :2], atol=1e-4)
    np.testing.assert_allclose(res.rays.d[:, v].T, out[v, 2:5], atol=1e-5)
    assert (res.rays.o[2, v] == PLANES["output_z"]).all()
    if uncertainty:
        np.testing.assert_allclose(res.uncertainty[v], spread[v], atol=1e-6)
        assert np.isfinite(res.uncertainty).all() and (res.uncertainty[~v] == 0).all()
    else:
        assert res.uncertainty is None
    for a in (res.rays.o, res.rays.d, res.rays.wavelength):
        assert np.isfinite(a).all()
    assert (res.rays.o[:, ~v] == 0).all() and (res.rays.d[:, ~v] == 0).all()
    assert (res.rays.wavelength[~v] == 0).all()
    # a hexagonal iris at a smaller radius clips more, at the stop plane only
    hexa = lens.trace_from_sensor(Rays(o, dirs, wl), sensor_z, stop_radius=4.0,
                                  aperture=PolygonAperture(6), **kw)
    # one sensor plane per ray: each ray as if traced alone from its own plane
    zs = np.where(np.arange(len(pi1)) % 2 == 0, sensor_z, -1.5)
    t2 = zs / pi1[:, 4]
    o2 = np.stack([pi1[:, 0] + t2 * pi1[:, 2], pi1[:, 1] + t2 * pi1[:, 3], zs])
    per_ray = lens.trace_from_sensor(Rays(o2, dirs, wl), zs, stop_radius=R, **kw)
    same = np.abs(r_stop[rest] - R) > 1e-4
    np.testing.assert_array_equal(per_ray.status[rest][same], res.status[rest][same])
    both = per_ray.valid & res.valid
    np.testing.assert_allclose(per_ray.rays.o[:, both], res.rays.o[:, both], atol=1e-4)
    hx, hy = stop[rest, 0] / 4.0, stop[rest, 1] / 4.0
    inside = PolygonAperture(6).inside(hx, hy)
    far = ~(PolygonAperture(6).inside(hx * 1.0001, hy * 1.0001) ^ PolygonAperture(6).inside(
        hx * 0.9999, hy * 0.9999))
    assert 0.05 < inside.mean() < 0.95
    np.testing.assert_array_equal(hexa.valid[rest][far], inside[far])


def test_12_runtime_imports_without_onnxruntime_torch_onnx():
    """neural.model imports with onnxruntime, onnx and torch all unavailable (lazy onnxruntime),
    and so do the model file (neural.modelfile) and the model choice, without bpy too."""
    code = ("import sys\n"
            "for m in ('onnxruntime', 'onnx', 'torch', 'bpy'): sys.modules[m] = None\n"
            "import neurolens_addon.neural.modelfile, neurolens_addon.neural.choice\n"
            "import neurolens_addon.neural.model as mm\n"
            "print(mm.LearnedLens.__name__)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=".")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "LearnedLens"


def test_13_w_residual_is_w_beyond_its_expansion_without_cancellation():
    """The sparse basis sees w as w - (1 - q/2 - q^2/8), w = sqrt(1 - q) (neural.reference):
    the cancellation-free form equals that difference in float64, and in float32 it keeps
    1e-5 of its value where the difference taken directly keeps nothing for small q."""
    q = np.geomspace(1e-3, 0.9, 200)
    w = np.sqrt(1.0 - q)
    direct = w - (1.0 - q / 2 - q * q / 8)
    keep = q > 0.05                        # float64's own cancellation stays below 1e-9 here
    np.testing.assert_allclose(reference.w_residual(q, w)[keep], direct[keep], rtol=1e-9)
    q32, w32 = q.astype(np.float32), w.astype(np.float32)
    exact = reference.w_residual(q32.astype(float), w32.astype(float))
    one, two, eight = np.float32(1), np.float32(2), np.float32(8)
    assert np.all(np.abs(reference.w_residual(q32, w32) / exact - 1) < 1e-5)
    naive = w32 - (one - q32 / two - q32 * q32 / eight)
    assert np.abs(naive / exact - 1)[q < 0.01].min() > 1e-2
