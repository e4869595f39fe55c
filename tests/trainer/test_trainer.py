"""The trainer: Latin hypercube data, the network's closed-form Jacobian, LM and Adam, the
kd-tree of cells, exact occupancy, and a whole small fit (real torch, small data)."""

from pathlib import Path

import numpy as np
import pytest
import torch

from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.neural import reference
from neurolens_addon.neural.modelfile import decode_occupancy, encode_occupancy, monomial_terms
from trainer import occupancy
from trainer.data import default_domain, latin_hypercube, stage_samples
from trainer.fit import FitConfig, fit_stage, relative_error
from trainer.mlp import MLP, _jacobian_chunk, fit_member, init_mlp, monomials, train_adam, train_lm

pytestmark = pytest.mark.slow          # trains models

ROOT = Path(__file__).resolve().parents[2]
SINGLET = ROOT / "presets" / "lenses" / "biconvex_singlet.toml"


def smooth_problem(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, 3))
    y = np.stack([np.sin(2 * x[:, 0]) * x[:, 1], np.tanh(x[:, 2] - x[:, 0] ** 2)], axis=1)
    return x, y, rng


def test_01_latin_hypercube_has_one_point_per_stratum():
    """Every dimension of a Latin hypercube of n points has exactly one point in each 1/n."""
    u = latin_hypercube(500, 4, np.random.default_rng(1))
    for row in u:
        assert sorted(np.floor(row * 500).astype(int)) == list(range(500))


def test_02_closed_form_parameter_jacobian_matches_autograd():
    """The LM Jacobian dy/dtheta (closed form) equals torch autograd's, polynomial skip included."""
    x, y, rng = smooth_problem(50)
    net = init_mlp(x, y, 5, rng, skip_degree=2)
    theta = torch.from_numpy(net.flat())
    xt = torch.from_numpy(x)
    phi = torch.from_numpy(monomials(x, net.terms))
    _, J = _jacobian_chunk(theta, xt, phi, 3, 5, 2, 2)

    def f(th):
        return _jacobian_chunk(th, xt, phi, 3, 5, 2, 2)[0]
    J_auto = torch.autograd.functional.jacobian(f, theta)
    torch.testing.assert_close(J, J_auto, rtol=1e-10, atol=1e-12)


def test_03_levenberg_marquardt_fits_a_smooth_map():
    """LM lowers the loss monotonically and fits a smooth 3 -> 2 map to under 2 % error."""
    x, y, rng = smooth_problem()
    net = init_mlp(x, y, 8, rng)
    net, hist = train_lm(net, x, y, max_iter=60, time_budget_s=60)
    assert all(b <= a for a, b in zip(hist, hist[1:]))
    assert relative_error(net.forward(x), y) < 0.02
    assert hist[-1] < 0.05 * hist[0]


def test_04_adam_also_trains_the_same_network():
    """Adam lowers the loss of the same network by at least half in a few epochs."""
    x, y, rng = smooth_problem()
    net = init_mlp(x, y, 8, rng)
    before = ((net.forward(x) - y) ** 2).sum()
    net, hist = train_adam(net, x, y, epochs=30, batch=256, time_budget_s=60)
    assert hist[-1] < 0.5 * before


def test_05_polynomial_skip_member_beats_its_polynomial():
    """A member = least-squares polynomial + network on the residual, at least as good as the
    polynomial alone, and stored as one network that reproduces both."""
    x, y, rng = smooth_problem()
    terms = monomial_terms(3, 2)
    A = np.concatenate([monomials(x, terms), np.ones((len(x), 1))], axis=1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    poly_err = relative_error(A @ coef, y)
    m = fit_member(x, y, 6, 2, rng, lm_iterations=30)
    assert relative_error(m.forward(x), y) < 0.5 * poly_err
    again = MLP.from_dict(m.as_dict())
    np.testing.assert_array_equal(again.forward(x), m.forward(x))


@pytest.fixture(scope="module")
def singlet_data():
    lens = load_lens(SINGLET)
    dom = default_domain(lens)
    return lens, dom, stage_samples(lens, dom, 60000, seed=3)


def test_06_stage_samples_are_exact_traces(singlet_data):
    """Both stages' samples have finite values, unit directions implied (w in (0, 1]), and
    stage 2 consumes only rays that passed stage 1."""
    lens, dom, (planes, s1, s2) = singlet_data
    assert s1.x.shape[1] == 5 and s1.y.shape[1] == 4
    assert np.isfinite(s1.x).all() and np.isfinite(s2.y).all()
    assert ((s1.x[:, 3] > 0) & (s1.x[:, 3] <= 1)).all()
    assert s2.passed.size == s1.passed.sum()
    assert s2.passed.all()                    # the singlet's stop is its front surface: free space
    assert planes.input_z == lens.rear_vertex_z and planes.stop_z > planes.input_z


def test_07_error_driven_split_routes_every_sample_to_its_cell(singlet_data):
    """A strict threshold makes the kd-tree split; reference routing sends each sample to a
    cell whose prediction matches the cell's own ensemble."""
    lens, dom, (planes, s1, s2) = singlet_data
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=2, error_threshold=1e-9, max_depth=1,
                    min_cell_samples=2000, member_samples=3000, lm_iterations=5,
                    cell_time_budget_s=10)
    sf = fit_stage(s1.x, s1.y, cfg, log=lambda *a: None)
    assert len(sf.cells) == 2 and "axis" in sf.tree[0]
    leaf = reference.route(sf.tree, s1.x)
    axis, split = sf.tree[0]["axis"], sf.tree[0]["split"]
    assert ((leaf == sf.tree[sf.tree[0]["left"]]["cell"]) == (s1.x[:, axis] < split)).all()


def test_08_occupancy_is_exact_and_conservative(singlet_data):
    """Every sample that passed stage 1 falls in an occupied cell; the grid round-trips through
    its base64 encoding; points outside the box are out of the domain."""
    lens, dom, (planes, s1, s2) = singlet_data
    lo, hi = s1.x[:, :3].min(0) - 1e-3, s1.x[:, :3].max(0) + 1e-3
    grid = occupancy.occupancy_grid(lens, (lens.stop_index, len(lens.surfaces)), planes.input_z, lo, hi,
                                    shape=(24, 24, 24), stop_radius=lens.stop_radius_mm)
    enc = encode_occupancy(grid, lo, hi)
    back = decode_occupancy(enc)
    np.testing.assert_array_equal(back, grid)
    assert occupancy.lookup(enc, back, s1.x[:, :3]).mean() > 0.999
    assert not occupancy.lookup(enc, back, (hi + 1.0)[None, :]).any()
    assert 0.05 < grid.mean() < 1.0          # the box has corners no ray passes


def test_09_same_seed_same_model_and_resume_from_checkpoints(singlet_data, tmp_path):
    """Two fits with one seed give identical weights; a fit resumed from its cell checkpoints
    gives the same cells without retraining them."""
    from trainer.pipeline import CellCheckpoints
    lens, dom, (planes, s1, s2) = singlet_data
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=2, max_depth=0, member_samples=2000,
                    lm_iterations=4, cell_time_budget_s=30, seed=11)
    a = fit_stage(s2.x, s2.y, cfg, stage=1, log=lambda *a: None)
    b = fit_stage(s2.x, s2.y, cfg, stage=1, log=lambda *a: None)
    assert a.cells[0]["members"] == b.cells[0]["members"]
    ck = CellCheckpoints(tmp_path / "ck", "fp")
    fit_stage(s2.x, s2.y, cfg, stage=1, log=lambda *a: None, cache=ck)
    lines = []
    c = fit_stage(s2.x, s2.y, cfg, stage=1, log=lines.append, cache=ck)
    assert any("resumed" in l for l in lines)
    assert c.cells[0]["members"] == a.cells[0]["members"]


def test_10_fit_from_an_external_ray_table(tmp_path):
    """A lens known only by a ray table (here: exact traces of the Tessar written to .npz)
    is learned as one stage; the reference model reproduces held-out table rays to < 0.5 %."""
    from neurolens_addon.core.irf import propagate_to_z
    from neurolens_addon.core.rays import Rays
    from neurolens_addon.core.trace import trace
    from trainer.data import sensor_rays
    from trainer.pipeline import fit_table
    lens = load_lens(ROOT / "presets" / "lenses" / "tessar_f4_5.toml")
    dom = default_domain(lens, dispersion=False)
    o, d, wl = sensor_rays(lens, dom, 60000, np.random.default_rng(5))
    o0 = propagate_to_z(o, d, 0.0)
    res = trace(lens, Rays(o0, d, wl))
    z_out = lens.front_vertex_z + 1.0
    oo = propagate_to_z(res.rays.o, res.rays.d, z_out)
    inputs = np.concatenate([o0[:2], d, wl[None]]).T
    outputs = np.concatenate([oo[:2], res.rays.d]).T
    table = tmp_path / "tessar_rays.npz"
    np.savez(table, inputs=inputs, outputs=outputs, valid=res.valid, input_z=0.0, output_z=z_out,
             name="mystery lens")
    cfg = FitConfig(theta=6, ensemble=2, skip_degree=3, max_depth=0, member_samples=6000,
                    lm_iterations=15, cell_time_budget_s=60)
    model = fit_table(table, tmp_path / "mystery", cfg, log=lambda *a: None)
    assert (tmp_path / "mystery.neurolens" / "model.json").exists()
    v = res.valid
    _, out, _ = reference.evaluate(model, inputs[v][-5000:])
    assert relative_error(out, outputs[v][-5000:]) < 0.005


def test_11_progress_bar_reports_each_decile_in_logs():
    """Written to a log (not a terminal), the bar prints one line per 10 % and ends at 100 %."""
    import io
    from trainer.progress import ProgressBar
    buf = io.StringIO()
    bar = ProgressBar(20, "work", stream=buf)
    for _ in range(20):
        bar.update()
    lines = buf.getvalue().splitlines()
    assert len(lines) == 11
    assert "100.0%" in lines[-1] and "[" + "#" * 30 + "]" in lines[-1]


def test_12_least_squares_falls_back_when_svd_fails(monkeypatch):
    """If LAPACK's SVD solver fails, lstsq still returns the least-squares solution (via the
    regularised normal equations)."""
    from trainer import mlp
    rng = np.random.default_rng(12)
    A = rng.normal(size=(500, 7))
    y = A @ np.arange(1.0, 8.0) + 3.0
    A1 = np.concatenate([A, np.ones((500, 1))], axis=1)

    def broken(*a, **k):
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
    monkeypatch.setattr(np.linalg, "lstsq", broken)
    np.testing.assert_allclose(mlp.lstsq(A1, y), list(range(1, 8)) + [3.0], atol=1e-8)


def test_13_monomials_of_a_sparse_set_need_no_listed_prefixes():
    """phi(x) for monomials whose prefixes are not listed equals the direct products, in
    numpy and torch, and in neural.reference."""
    rng = np.random.default_rng(13)
    x = rng.uniform(-1, 1, (50, 5))
    terms = [(0, 3, 4), (2, 2, 2, 2), (1,), (0, 4, 4)]
    direct = np.stack([np.prod(x[:, list(t)], axis=1) for t in terms], axis=1)
    np.testing.assert_allclose(monomials(x, terms), direct, rtol=1e-14)
    np.testing.assert_allclose(monomials(torch.from_numpy(x), terms).numpy(), direct, rtol=1e-14)
    np.testing.assert_allclose(reference.monomials(x, terms), direct, rtol=1e-14)


def test_14_mirror_skip_is_exactly_symmetric(singlet_data):
    """The sparse skip fitted with the mirror option: even outputs carry no odd monomial and
    odd outputs no even one (nor a constant), so flipping u_t flips x'_t and u'_t and keeps
    x'_r and u'_r exactly; its error stays within 10 % of the unconstrained fit's."""
    from trainer.fit import CellInputs
    from trainer.mlp import is_odd_term, skip_lstsq, sparse_skip_terms
    lens, dom, (planes, s1, s2) = singlet_data
    cfg = FitConfig(skip_basis="sparse", skip_degree=4)
    ci = CellInputs.fit(s1.x, s1.y, cfg)
    assert ci.nx.mean[2] == 0.0 and ci.ny.mean[1] == 0.0 and ci.ny.mean[3] == 0.0
    xn, yn = ci.xn(s1.x), ci.ny.apply(s1.y)
    terms = sparse_skip_terms(5, 4)
    L, c = skip_lstsq(xn, yn, terms, mirror=True)
    odd = np.array([is_odd_term(t) for t in terms])
    assert not L[np.ix_([0, 2], np.flatnonzero(odd))].any()
    assert not L[np.ix_([1, 3], np.flatnonzero(~odd))].any() and c[1] == c[3] == 0.0
    flipped = xn * np.array([1, 1, -1, 1, 1])
    a, b = monomials(xn, terms) @ L.T + c, monomials(flipped, terms) @ L.T + c
    np.testing.assert_allclose(b, a * np.array([1, -1, 1, -1]), rtol=0, atol=1e-12)
    L0, c0 = skip_lstsq(xn, yn, terms, mirror=False)
    err = lambda L, c: relative_error(monomials(xn, terms) @ L.T + c, yn)
    assert err(L, c) <= 1.1 * err(L0, c0)


def test_15_sparse_basis_sees_the_wavelength_as_inverse_square(singlet_data):
    """A cell fitted with the sparse basis records its reference wavelength, normalises its
    training rays' mu = (l0 / lambda)^2 into [-1, 1], lists its skip monomials explicitly and
    fits the simple lens well."""
    from trainer.fit import fit_cell
    lens, dom, (planes, s1, s2) = singlet_data
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=3, skip_basis="sparse", member_samples=3000,
                    lm_iterations=5, cell_time_budget_s=10)
    n = len(s1.x)
    fit = fit_cell(s1.x[: n // 2], s1.y[: n // 2], s1.x[n // 2:], s1.y[n // 2:], cfg,
                   np.random.default_rng(0), log=lambda *a: None)
    xn_rule = fit.cell["x_norm"]
    assert xn_rule["wavelength_ref_nm"] == 550.0
    mu = reference.cell_features(s1.x[: n // 2], xn_rule)[:, 4]
    np.testing.assert_allclose(mu, (550.0 / s1.x[: n // 2, 4]) ** 2)
    z = (mu - xn_rule["mean"][4]) / xn_rule["scale"][4]
    assert np.abs(z).max() <= 1.0 + 1e-9
    assert all("skip_terms" in m for m in fit.cell["members"])
    assert fit.test_error < 0.05                       # mm at 1 m on this simple lens
    assert xn_rule["w_residual_column"] == 3           # w seen beyond the directions' expansion
    q = s1.x[: n // 2, 1] ** 2 + s1.x[: n // 2, 2] ** 2
    np.testing.assert_allclose(reference.cell_features(s1.x[: n // 2], xn_rule)[:, 3],
                               reference.w_residual(q, s1.x[: n // 2, 3]))


def test_15b_a_sparse_model_is_as_accurate_in_float32_as_in_float64(tmp_path):
    """The sparse skip's w beside the directions: raw, its least-squares and LM coefficients
    grew to 1e2-1e5 and cancelled, so the float32 graphs (onnxruntime, OSL) missed the float64
    reference by up to 7 mm on Pi_2 (the 180 mm macro); seen as its residual, the double
    Gauss's sparse model agrees with the reference to float32 rounding."""
    pytest.importorskip("onnxruntime")
    import json

    from neurolens_addon.neural.model import LearnedLens
    from trainer.fit import FitConfig
    from trainer.pipeline import fit_lens
    lens = load_lens(ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml")
    out = tmp_path / "sparse.neurolens"
    fit_lens(lens, out, FitConfig(skip_basis="sparse", ensemble=1, max_depth=0, lm_iterations=10),
             n_rays=60_000, log=lambda *a: None)
    meta = json.loads((out / "model.json").read_text())
    biggest = max(np.abs(np.asarray(m["L"])).max() for st in meta["stages"]
                  for c in st["cells"] for m in c["members"])
    assert biggest < 20.0
    _, s1, _ = stage_samples(lens, default_domain(lens), 4000, seed=9)[:3]
    rays = np.column_stack([s1.x[:, 0], np.zeros(len(s1.x)), s1.x[:, 1], s1.x[:, 2],
                            s1.x[:, 3], s1.x[:, 4]])        # on Pi_1, in the meridian y = 0
    stop, out_rays, _, ok = LearnedLens.load(out, lens=lens).evaluate(rays)
    ref = reference.evaluate(meta, rays)
    assert ok.mean() > 0.5                 # some leave the model's domain in stage 2
    np.testing.assert_allclose(out_rays[ok, :2], ref[1][ok, :2], atol=2e-4)


@pytest.fixture(scope="module")
def anamorphic_data():
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    lens = cylinder_attachment_lens()
    dom = default_domain(lens)
    return lens, dom, stage_samples(lens, dom, 40000, seed=5)


def test_16_anamorphic_samples_are_in_their_groups_frames(anamorphic_data):
    """The test lens's cylinders stand before its stop: its rear group (a spherical singlet)
    is learned in the radial frame, X = (r, u_r, u_t, w, lambda), and its front group in the
    cartesian frame, X = (x, y, u, v, w, lambda) on the stop plane from points all around the
    axis, with Y = (x', y', u', v') unrotated; the stop-plane points lie inside the stop, and
    the front group's map is not rotationally symmetric (the two meridians differ)."""
    from neurolens_addon.core.irf import CARTESIAN, RADIAL, stage_frames
    lens, dom, (planes, s1, s2) = anamorphic_data
    assert stage_frames(lens) == (RADIAL, CARTESIAN)
    assert s1.x.shape[1] == 5 and s2.x.shape[1] == 6 and s2.valid_in.shape[1] == 5
    np.testing.assert_allclose(s2.x[:, 4], np.sqrt(1 - s2.x[:, 2] ** 2 - s2.x[:, 3] ** 2))
    quadrants = np.unique((s2.x[:, 0] > 0).astype(int) * 2 + (s2.x[:, 1] > 0))
    assert quadrants.tolist() == [0, 1, 2, 3]
    assert (np.hypot(s1.y[:, 0], s1.y[:, 1]) <= lens.stop_radius_mm * (1 + 1e-9)).all()
    assert s2.passed.size == len(s1.x) and 0.5 < s2.passed.mean()
    # the output direction's slope per unit input height, on x and on y: the cylinders make
    # the two meridians differ
    on_x = (np.abs(s2.x[:, 1]) < 0.3) & (np.abs(s2.x[:, 0]) > 2) & (np.abs(s2.x[:, 3]) < 0.01)
    on_y = (np.abs(s2.x[:, 0]) < 0.3) & (np.abs(s2.x[:, 1]) > 2) & (np.abs(s2.x[:, 2]) < 0.01)
    kx = np.polyfit(s2.x[on_x, 2], s2.y[on_x, 2], 1)[0]
    ky = np.polyfit(s2.x[on_y, 3], s2.y[on_y, 3], 1)[0]
    assert abs(kx / ky - 1) > 0.1


def test_17_cartesian_occupancy_is_exact_and_conservative(anamorphic_data):
    """The 4-D occupancy grid over (x, y, u, v) of the front group (its cylinders): every
    stage-2 sample that passed falls in an occupied cell, the grid round-trips through its
    encoding, and it has empty cells."""
    from neurolens_addon.core.irf import CARTESIAN
    lens, dom, (planes, s1, s2) = anamorphic_data
    lo, hi = s2.x[:, :4].min(0) - 1e-3, s2.x[:, :4].max(0) + 1e-3
    grid = occupancy.occupancy_grid(lens, (0, lens.stop_index), planes.stop_z,
                                    lo, hi, stop_radius=lens.stop_radius_mm, frame=CARTESIAN)
    assert grid.shape == (16, 16, 16, 16)
    enc = encode_occupancy(grid, lo, hi)
    back = decode_occupancy(enc)
    np.testing.assert_array_equal(back, grid)
    assert occupancy.lookup(enc, back, s2.x[:, :4]).mean() > 0.999
    assert not occupancy.lookup(enc, back, (hi + 1.0)[None, :]).any()
    assert 0.02 < grid.mean() < 0.9


def test_18_cartesian_frame_has_no_mirror_symmetry(anamorphic_data):
    """In the cartesian frame the sparse skip keeps monomials odd in every input (no mirror
    split), its w (column 4) at most linear and mu (column 5) at most squared, and inputs keep
    their own means; a split may choose any axis, u and v included."""
    from neurolens_addon.core.irf import CARTESIAN
    from trainer.fit import CellInputs, best_split_axis
    lens, dom, (planes, s1, s2) = anamorphic_data
    cfg = FitConfig(skip_basis="sparse", skip_degree=3, min_cell_samples=2000)
    ci = CellInputs.fit(s2.x, s2.y, cfg, CARTESIAN)
    assert not ci.mirror and ci.nx.mean[2] != 0.0 and ci.ny.mean[1] != 0.0
    assert (3,) in ci.terms and (0, 3) in ci.terms and (2, 2, 3) in ci.terms
    assert all(t.count(4) <= 1 and t.count(5) <= 2 for t in ci.terms)
    assert ci.x_norm["wavelength_ref_nm"] == 550.0
    # a map with a kink at u = 0 (column 2, u_t's place in the radial frame): the cartesian
    # frame splits there; the radial frame's sparse basis never splits column 2
    rng = np.random.default_rng(2)
    X = np.concatenate([rng.uniform(-1, 1, (20000, 4)), rng.uniform(0.8, 1, (20000, 1)),
                        rng.uniform(400, 700, (20000, 1))], axis=1)
    Y = np.stack([np.abs(X[:, 2]), X[:, 0], X[:, 1] * np.abs(X[:, 2]), X[:, 3]], axis=1)
    test_mask = rng.random(len(X)) < 0.2
    split = best_split_axis(X, Y, X.min(0), X.max(0), test_mask, cfg, CARTESIAN)
    assert split[0] == 2 and abs(split[2]) < 1e-3
    radial = best_split_axis(X[:, 1:], Y, X[:, 1:].min(0), X[:, 1:].max(0), test_mask, cfg)
    assert radial is None or radial[0] != 2
