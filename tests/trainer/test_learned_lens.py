"""A real learned lens end to end: trained from exact traces (small, fast), exported, loaded
with onnxruntime, and compared with the exact trace it learned. Two lenses: the Cooke triplet
(radial frame) and the anamorphic test lens (testdata.anamorphic_lenses, squeeze 1.30: the
cartesian frame of core.irf)."""

import dataclasses
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.field import design_film_radius_mm
from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.irf import propagate_to_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays, RayStatus
from neurolens_addon.core.trace import trace
from neurolens_addon.neural.model import LearnedLens
from trainer.data import default_domain
from trainer.evaluate import camera_rays_at_focus
from trainer.fit import FitConfig
from trainer.pipeline import fit_lens

from testdata.anamorphic_lenses import cylinder_attachment_lens
from tests.neural.synthetic import reference_jacobian_fd

ROOT = Path(__file__).resolve().parents[2]
COOKE = ROOT / "presets" / "lenses" / "cooke_triplet_f4.toml"
LENSES = {"cooke": lambda: load_lens(COOKE), "anamorphic": cylinder_attachment_lens}
#: each stage's frame (rear group, front group): the test lens's cylinders stand before its
#: stop, its singlet behind it
FRAMES = {"cooke": ["radial", "radial"], "anamorphic": ["radial", "cartesian"]}


def field_domain(lens):
    """The default domain held to the lens's stated field: a one-cell model this small fits it
    to the tolerances below (the shipped models, deeper, also cover full-frame corners)."""
    return dataclasses.replace(default_domain(lens), film_radius_mm=design_film_radius_mm(lens))


_TRAINED = {}


def _trained(name, tmp_path_factory):
    """(lens, LearnedLens) of LENSES[name], trained once per test session."""
    if name not in _TRAINED:
        lens = LENSES[name]()
        out = tmp_path_factory.mktemp("models") / name
        cfg = FitConfig(theta=4, ensemble=2, skip_degree=4, max_depth=0, member_samples=6000,
                        lm_iterations=10, cell_time_budget_s=30)
        fit_lens(lens, out, cfg, n_rays=80000, domain=field_domain(lens), log=lambda *a: None)
        model = LearnedLens.load(out.with_name(f"{name}.neurolens"), lens=lens)
        assert [f.name for f in model.frames] == FRAMES[name]
        assert model.meta["frame"] == ("cartesian" if "cartesian" in FRAMES[name] else "radial")
        _TRAINED[name] = lens, model
    return _TRAINED[name]


@pytest.fixture(scope="module", params=list(LENSES))
def learned(request, tmp_path_factory):
    return _trained(request.param, tmp_path_factory)


@pytest.fixture(scope="module")
def anamorphic(tmp_path_factory):
    return _trained("anamorphic", tmp_path_factory)


@pytest.mark.slow
def test_01_learned_rays_match_the_exact_trace(learned):
    """Camera rays focused at 2 m: the learned lens agrees with the exact trace on which rays
    pass (>= 97 %) and, where both pass, to 0.05 mm on Pi_2 and 1e-3 in direction (the
    anamorphic lens, one small cell for five inputs: 1e-3 for 99 % of the rays, 2.5e-3 for
    all)."""
    lens, model = learned
    dom = field_domain(lens)
    rays, z_s = camera_rays_at_focus(lens, dom, 20000, 2000.0, seed=1)
    ex = trace(lens, rays)
    le = model.trace_from_sensor(rays, sensor_z=z_s)
    assert (ex.valid == le.valid).mean() >= 0.97
    v = ex.valid & le.valid
    # rays aimed over the rear element's disc (an anamorphic lens) pass less often than
    # rays through the rear pupil
    assert v.mean() > (0.25 if lens.anamorphic else 0.8)
    eo = propagate_to_z(ex.rays.o[:, v], ex.rays.d[:, v], model.planes["output_z"])
    assert np.abs(eo[:2] - le.rays.o[:2, v]).max() < 0.05
    dd = np.abs(ex.rays.d[:, v] - le.rays.d[:, v]).max(axis=0)
    assert np.percentile(dd, 99) < 1e-3
    assert dd.max() < (2.5e-3 if lens.anamorphic else 1e-3)


def test_02_a_model_for_another_lens_is_refused(learned):
    """Loading the model for the Tessar prescription raises ModelError naming both."""
    lens, model = learned
    other = load_lens(ROOT / "presets" / "lenses" / "tessar_f4_5.toml")
    with pytest.raises(ModelError, match=f"{re.escape(lens.name)}.*Tessar"):
        LearnedLens.load(model.directory, lens=other)


def test_03_rays_outside_the_learned_domain_are_flagged(learned):
    """Film points far beyond the image circle and wavelengths beyond 780 nm come back flagged
    OUT_OF_DOMAIN with zero rays, never extrapolated."""
    lens, model = learned
    o = np.array([[0.0, 80.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    tgt = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [lens.rear_vertex_z] * 3])
    d = tgt - o
    d /= np.linalg.norm(d, axis=0)
    res = model.trace_from_sensor(Rays(o, d, np.array([550.0, 550.0, 900.0])), sensor_z=0.0)
    assert res.valid.tolist() == [True, False, False]
    assert (res.status[1:] == RayStatus.OUT_OF_DOMAIN).all()
    assert not res.rays.o[:, 1:].any()


def test_04_jacobian_of_the_real_model_matches_finite_differences(learned):
    """The in-graph Jacobian of the trained model agrees with central differences of its own
    float64 reference within 2 % of the Jacobian's scale."""
    lens, model = learned
    meta = json.loads((model.directory / "model.json").read_text())
    dom = field_domain(lens)
    rays, z_s = camera_rays_at_focus(lens, dom, 200, 2000.0, seed=2)
    p1 = propagate_to_z(np.array(rays.o), rays.d, model.planes["input_z"])
    x = np.stack([p1[0], p1[1], rays.d[0], rays.d[1], rays.d[2], rays.wavelength], 1)
    stop, out, spread, ok, J = model.evaluate(x, jacobian=True)
    x = x[ok]
    J = J[ok]
    fd = reference_jacobian_fd(meta, x, h=1e-5)
    scale = np.abs(fd).max(axis=(1, 2), keepdims=True)
    assert np.abs(J - fd).max() / scale.max() < 0.02
    assert np.median(np.abs(J - fd) / scale) < 1e-3


@pytest.mark.slow
def test_06_a_model_without_dispersion_learns_the_d_line(tmp_path):
    """--no-dispersion: networks take 4 inputs (no wavelength), the model follows the exact
    d-line trace, and it is achromatic: any wavelength gets the d-line rays."""
    lens = load_lens(ROOT / "presets" / "lenses" / "tessar_f4_5.toml")
    cfg = FitConfig(theta=4, ensemble=2, skip_degree=4, max_depth=0, member_samples=5000,
                    lm_iterations=8, cell_time_budget_s=20)
    meta = fit_lens(lens, tmp_path / "t", cfg, n_rays=60000, dispersion=False,
                    log=lambda *a: None)
    assert np.asarray(meta["stages"][0]["cells"][0]["members"][0]["W1"]).shape[1] == 4
    model = LearnedLens.load(tmp_path / "t.neurolens", lens=lens)
    dom = default_domain(lens, dispersion=False)
    rays, z_s = camera_rays_at_focus(lens, dom, 5000, 2000.0, seed=3)
    assert np.all(rays.wavelength == 587.5618)
    ex, le = trace(lens, rays), model.trace_from_sensor(rays, sensor_z=z_s)
    v = ex.valid & le.valid
    assert v.mean() > 0.8
    assert np.abs(ex.rays.d[:, v] - le.rays.d[:, v]).max() < 1e-3
    blue = model.trace_from_sensor(Rays(rays.o, rays.d, np.full(rays.n, 450.0)), sensor_z=z_s)
    np.testing.assert_array_equal(blue.valid, le.valid)
    np.testing.assert_array_equal(blue.rays.d, le.rays.d)


# ---------------------------------------------------------------- the anamorphic lens

#: film points (mm) on x, on y and on both diagonals, both signs: a radial-frame model (one map
#: for every azimuth) cannot fit both meridians of a lens squeezed 1.30
FILM_POINTS = [(0.0, 0.0), (11.0, 0.0), (-11.0, 0.0), (0.0, 11.0), (0.0, -11.0),
               (7.8, 7.8), (-7.8, 7.8), (7.8, -7.8), (-7.8, -7.8), (4.0, -9.0)]


def _disc_rays(lens, fx, fy, n, z_s, seed):
    """n rays from the film point (fx, fy) over the rear element's disc (core.pupil)."""
    from neurolens_addon.core.pupil import RearDiscSampler
    rng = np.random.default_rng(seed)
    return RearDiscSampler(lens, z_s).sample(np.full(n, fx), np.full(n, fy), rng.random(n),
                                             rng.random(n), rng.random(n),
                                             rng.uniform(420.0, 700.0, n)).rays


def test_07_anamorphic_rays_match_the_exact_trace_all_around_the_film(anamorphic):
    """Focused at 2 m, at every film point of FILM_POINTS: the learned lens passes the same
    rays as the exact trace (>= 97 %) and, where both pass, lands within 0.03 mm on Pi_2 and
    1e-3 in direction; the two meridians image differently (the lens is anamorphic), so the
    model learned both, not one map turned around the axis."""
    lens, model = anamorphic
    z_s = focus_sensor_z(lens, 2000.0)
    slopes = {}
    for k, (fx, fy) in enumerate(FILM_POINTS):
        rays = _disc_rays(lens, fx, fy, 3000, z_s, seed=10 + k)
        ex = trace(lens, rays)
        le = model.trace_from_sensor(rays, sensor_z=z_s)
        assert (ex.valid == le.valid).mean() >= 0.97, (fx, fy)
        v = ex.valid & le.valid
        assert v.sum() > 500, (fx, fy)
        eo = propagate_to_z(ex.rays.o[:, v], ex.rays.d[:, v], model.planes["output_z"])
        assert np.abs(eo[:2] - le.rays.o[:2, v]).max() < 0.03, (fx, fy)
        assert np.abs(ex.rays.d[:, v] - le.rays.d[:, v]).max() < 1e-3, (fx, fy)
        slopes[(fx, fy)] = np.median(np.hypot(le.rays.d[0, v], le.rays.d[1, v]))
    # the chief-ray angles on x and on y differ by the squeeze (a radial map would equal them)
    assert slopes[(11.0, 0.0)] / slopes[(0.0, 11.0)] > 1.1 or \
        slopes[(0.0, 11.0)] / slopes[(11.0, 0.0)] > 1.1


def test_08_anamorphic_fast_and_forward_graphs_agree(anamorphic):
    """forward_fast.onnx (the default path) and forward.onnx give the same statuses and rays to
    float32 rounding, and the fast graph's in_domain bits equal the numpy guards bit for bit."""
    import onnxruntime as ort

    from neurolens_addon.neural.domain import frame_inputs
    lens, model = anamorphic
    z_s = focus_sensor_z(lens, 2000.0)
    rays = _disc_rays(lens, 0.0, 0.0, 1, z_s, 0)
    rng = np.random.default_rng(5)
    n = 20000
    r, phi = 26.0 * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)   # past the film too
    rays = _disc_rays(lens, 0.0, 0.0, n, z_s, 6)
    o = rays.o.copy()
    o[0], o[1] = r * np.cos(phi), r * np.sin(phi)
    tgt = rays.o + rays.d * ((lens.rear_vertex_z - z_s) / rays.d[2])    # the same disc points
    d = tgt - o
    d /= np.linalg.norm(d, axis=0)
    wl = rays.wavelength.copy()
    wl[::97] = 900.0
    rays = Rays(o, d, wl)
    fast = model.trace_from_sensor(rays, sensor_z=z_s)
    slow = model.trace_from_sensor(rays, sensor_z=z_s, uncertainty=True)
    st = np.bincount(fast.status, minlength=9)
    assert st[RayStatus.OK] > 0.2 * n and st[RayStatus.OUT_OF_DOMAIN] > 0.05 * n
    agree = fast.status == slow.status
    assert agree.mean() > 0.999                  # the stop's rim: float32 vs float64 flights
    np.testing.assert_allclose(fast.rays.o[:, agree], slow.rays.o[:, agree], rtol=0, atol=2e-4)
    np.testing.assert_allclose(fast.rays.d[:, agree], slow.rays.d[:, agree], rtol=0, atol=2e-6)
    # domain bits: the graph against the numpy guard on the float32 ray it builds
    so = ort.SessionOptions()
    so.log_severity_level = 3
    sess = ort.InferenceSession(str(model.directory / "forward_fast.onnx"), so,
                                providers=["CPUExecutionProvider"])
    cols = np.concatenate([o[:2], d, wl[None]]).astype(np.float32)
    out = dict(zip([x.name for x in sess.get_outputs()], sess.run(None, {
        "rays": cols, "sensor_z": np.array([z_s], np.float32),
        "stop_r2": np.array([np.inf])})))
    x, y, dx, dy, dz, lam = cols
    with np.errstate(all="ignore"):
        nrm = np.sqrt((dx * dx + dy * dy) + dz * dz)
        u, v, w = dx / nrm, dy / nrm, dz / nrm
        t = (np.float32(model.planes["input_z"]) - np.float32(z_s)) / w
        x1, y1 = x + t * u, y + t * v
        ok1 = model._guards[0].inside(frame_inputs(model.frames[0], x1, y1, u, v, w, lam, True))
        ok1 &= (lam >= 380.0) & (lam <= 780.0)
    assert 0.3 < ok1.mean() < 0.99
    np.testing.assert_array_equal((out["in_domain"] & 1).astype(bool), ok1)


def test_09_anamorphic_frame_checked_on_load(anamorphic, tmp_path):
    """model.json's frames are checked: without them (a radial model) the anamorphic lens
    refuses the model, naming the file, 'frame' and the group its cylinders are in; without the
    lens the front stage's 6-column bounds contradict the radial frame's 5; an unknown frame is
    named, the model's or a stage's; a radial model with the lens's hash is refused for that
    lens."""
    lens, model = anamorphic
    dst = tmp_path / model.directory.name
    shutil.copytree(model.directory, dst)
    meta = json.loads((dst / "model.json").read_text())

    def write(m):
        (dst / "model.json").write_text(json.dumps(m))

    assert [st["frame"] for st in meta["stages"]] == ["radial", "cartesian"]
    bare = [{k: v for k, v in st.items() if k != "frame"} for st in meta["stages"]]
    write({**{k: v for k, v in meta.items() if k != "frame"}, "stages": bare})
    with pytest.raises(ModelError, match=r"model\.json.*field 'frame'.*radial stage.*front "
                                         r"group of the anamorphic lens") as e:
        LearnedLens.load(dst, lens=lens)
    assert "\n" not in str(e.value)
    with pytest.raises(ModelError, match=r"model\.json.*stages\[1\]\.bounds\.lo.*6 values.*"
                                         r"radial frame has 5"):
        LearnedLens.load(dst)
    write({**meta, "frame": "polar"})
    with pytest.raises(ModelError, match=r"field 'frame'.*expected one of 'radial', "
                                         r"'cartesian', got 'polar'"):
        LearnedLens.load(dst)
    stages = [dict(st) for st in meta["stages"]]
    stages[1]["frame"] = "polar"
    write({**meta, "stages": stages})
    with pytest.raises(ModelError, match=r"field 'stages\[1\]\.frame'.*got 'polar'"):
        LearnedLens.load(dst)
    stages[1]["frame"] = "radial"
    write({**meta, "stages": stages})
    with pytest.raises(ModelError, match=r"field 'stages\[1\]\.frame'.*radial stage"):
        LearnedLens.load(dst, lens=lens)
    from tests.neural.synthetic import make_model, write_model
    radial = write_model(make_model(hidden=4, lens_name=lens.name,
                                    lens_hash=lens.content_hash()), tmp_path / "r.neurolens")
    with pytest.raises(ModelError, match=r"field 'frame'"):
        LearnedLens.load(radial, lens=lens)
    write(meta)
    assert [f.name for f in LearnedLens.load(dst, lens=lens).frames] == ["radial", "cartesian"]
    # the Cycles learned camera has no shader for this frame: it says so, naming the field
    from types import SimpleNamespace

    from neurolens_addon.cycles.learned import load_model
    with pytest.raises(ModelError, match=r"field 'frame'.*radial-frame models only"):
        load_model(SimpleNamespace(model_dir=str(dst), lens=lens))


def test_10_the_models_frame_says_whether_a_stage_is_cartesian(anamorphic, tmp_path):
    """model.json's own "frame" (what the header reports without reading the stages) must be
    cartesian exactly when a stage is: a radial one over a cartesian stage is refused,
    naming the file and the field."""
    lens, model = anamorphic
    dst = tmp_path / model.directory.name
    shutil.copytree(model.directory, dst)
    meta = json.loads((dst / "model.json").read_text())
    (dst / "model.json").write_text(json.dumps({**meta, "frame": "radial"}))
    with pytest.raises(ModelError, match=r"model\.json.*field 'frame'.*'radial', but its stages "
                                         r"are \['radial', 'cartesian'\]"):
        LearnedLens.load(dst)
