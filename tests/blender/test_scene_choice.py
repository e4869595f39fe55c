"""Automatic model choice from the render settings (issue 6, the Blender part): the error budget
and region a scene needs, AUTO picking the cheapest model within the budget (fake but valid
model directories: copies of the shipped bi-convex singlet model with edited "evaluation"
figures), the override buttons, the panel's choice line, and training a scene model with the
operator (a real, tiny training run of the bi-convex singlet) and cancelling one.

The trainer runs in its own process with the Python the preference "Trainer Python" names:
these tests pick one that has torch (this one, NEUROLENS_TRAINER_PYTHON, or the checkout's
.venv: under Blender 5.2's Python 3.13, which has no torch, the project's 3.11 environment
trains), and one without torch to see the operator refuse in one line."""

import json
import os
import subprocess
import sys
from dataclasses import replace
import shutil
import time
from pathlib import Path

import bpy
import pytest

from .conftest import ROOT
from .test_ui import _Recorder

LENS = "biconvex_singlet"
PRESET_MODEL = ROOT / "presets" / "models" / f"{LENS}.neurolens"
TINY = {"rays": 20_000, "max_depth": 0}        # a one-cell model: a few seconds of training


@pytest.fixture(autouse=True)
def no_shipped_models(addon, tmp_path, monkeypatch):
    """The shipped models carry recorded evaluations, so AUTO could choose them: these tests
    see only the models they make (the presets' model folder is an empty one)."""
    empty = tmp_path / "no-shipped-models"
    empty.mkdir()
    monkeypatch.setattr(addon.lenses, "PRESET_MODELS_DIR", empty)


@pytest.fixture
def models_dir(addon, tmp_path):
    """A throw-away user models folder (the preference), emptied of choices afterwards."""
    ap = addon.preferences.addon_preferences()
    folder = tmp_path / "models"
    ap.models_directory = str(folder)
    yield addon.preferences.user_directory("models")
    ap.models_directory = ""


def _has_torch(python) -> bool | None:
    """True / False: `python` runs and has / lacks torch; None: it does not run."""
    try:
        proc = subprocess.run([str(python), "-c", "import importlib.util, sys; "
                               "sys.exit(0 if importlib.util.find_spec('torch') else 3)"],
                              capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return {0: True, 3: False}.get(proc.returncode)


def _pythons():
    """Interpreters on this machine: this one, the one NEUROLENS_TRAINER_PYTHON names, the
    checkout's .venv (the project's 3.11 environment) and the interpreter a venv was made from
    (no packages of its own)."""
    found = [sys.executable, os.environ.get("NEUROLENS_TRAINER_PYTHON"),
             ROOT / ".venv" / "bin" / "python", getattr(sys, "_base_executable", None)]
    return [str(p) for p in found if p and Path(p).is_file()]


@pytest.fixture
def trainer_python(addon):
    """The preference "Trainer Python" set to an interpreter with torch (skip: none here)."""
    python = next((p for p in _pythons() if _has_torch(p)), None)
    if python is None:
        pytest.skip("no Python with torch on this machine to train with (the project's 3.11 "
                    "environment, .venv, or NEUROLENS_TRAINER_PYTHON)")
    ap = addon.preferences.addon_preferences()
    ap.trainer_python = python
    yield python
    ap.trainer_python = ""


@pytest.fixture
def torchless_python(addon):
    """The preference "Trainer Python" set to an interpreter without torch (skip: none)."""
    python = next((p for p in _pythons() if _has_torch(p) is False), None)
    if python is None:
        pytest.skip("every Python on this machine has torch")
    ap = addon.preferences.addon_preferences()
    ap.trainer_python = python
    yield python
    ap.trainer_python = ""


#: the exact trace's recorded cost a camera ray (us) in the fake models, both renderers
EXACT_US = 2.0


def fake_model(folder: Path, name: str, p99_um: float, rays_per_s: float,
               costs: dict | None = None) -> Path:
    """A valid model of the bi-convex singlet whose recorded evaluation says `p99_um`, and
    whose recorded costs say a camera ray costs 1 / rays_per_s through it and EXACT_US
    through the exact trace in either renderer (`costs`: {renderer: (exact, learned) us}
    instead; a renderer given None has no figure)."""
    out = folder / f"{name}.neurolens"
    shutil.copytree(PRESET_MODEL, out)
    meta = json.loads((out / "model.json").read_text())
    meta["evaluation"] = {"image_error_um_p50": p99_um / 3.0, "image_error_um_p99": p99_um,
                          "onnx_rays_per_s": rays_per_s, "exact_rays_per_s": 5e5}
    if costs is None:
        costs = {r: (EXACT_US, 1e6 / rays_per_s) for r in ("neurolens", "cycles")}
    meta["costs"] = {r: {"exact_us": c[0], "learned_us": c[1], "date": "2026-11-28",
                         "machine": "the test's"} for r, c in costs.items() if c is not None}
    (out / "model.json").write_text(json.dumps(meta))
    return out


def singlet_camera(camera, name="Auto"):
    """A bi-convex singlet camera on AUTO whose frame lies inside the shipped model's film
    radius (24 mm sensor): at 1920 x 1080 its budget is 0.5 x 24 / 1920 mm = 6.25 um."""
    obj = camera(name, lens_id=LENS)
    obj.data.sensor_width = 24.0
    obj.data.dof.focus_distance = 5.0
    obj.data.dof.aperture_fstop = 8.0
    assert obj.data.neurolens.model == "AUTO"
    return obj


def _cached_models(addon):
    import importlib
    return importlib.import_module(addon.root + ".neural.cache").cached_models


def _draw(addon, obj, scene):
    log = []
    addon.panel.draw_panel(_Recorder(log), scene, obj, obj.data)
    texts = [kw.get("text", "") for name, _a, kw in log if name == "label"]
    ops = [a[0] for name, a, _kw in log if name == "operator"]
    return texts, ops


def test_01_render_needs_follow_the_render_settings(addon, scene):
    """The budget is pixel_fraction x pixel pitch: doubling the resolution halves it, 50 %
    resolution doubles it, the scene's Error Budget (px) scales it, VERTICAL fit measures the
    sensor height; a render region becomes the border (off-centre: a ring that misses the
    axis); dispersion and the sensor come from the camera."""
    snb = addon.scene_needs_bpy
    sc, camera = scene
    obj = camera("Needs")
    needs = snb.render_needs(sc, obj)
    assert (needs.resolution_x, needs.resolution_y) == (1920, 1080)
    assert needs.pixel_fraction == 0.5 and needs.sensor_fit == "AUTO"
    assert needs.error_budget_um() == pytest.approx(0.5 * 36.0 / 1920 * 1000.0)
    assert needs.border == (0.0, 0.0, 1.0, 1.0) and needs.dispersion is True
    sc.render.resolution_x, sc.render.resolution_y = 3840, 2160
    assert snb.render_needs(sc, obj).error_budget_um() == pytest.approx(
        needs.error_budget_um() / 2.0)
    sc.render.resolution_percentage = 50
    assert snb.render_needs(sc, obj).error_budget_um() == pytest.approx(needs.error_budget_um())
    sc.neurolens.pixel_fraction = 0.25
    assert snb.render_needs(sc, obj).error_budget_um() == pytest.approx(
        needs.error_budget_um() / 2.0)
    obj.data.sensor_fit, obj.data.sensor_height = "VERTICAL", 20.0
    assert snb.render_needs(sc, obj).pixel_pitch_mm() == pytest.approx(20.0 / 1080)
    sc.render.use_border = True
    sc.render.border_min_x, sc.render.border_max_x = 0.75, 1.0
    sc.render.border_min_y, sc.render.border_max_y = 0.5, 1.0
    ring = snb.render_needs(sc, obj)
    assert ring.border == pytest.approx((0.75, 0.5, 1.0, 1.0))
    r_min, r_max = ring.film_radii_mm()
    assert r_min > 0.0 and r_max == pytest.approx(needs.film_radii_mm()[1] * 20.0 / 20.25,
                                                  rel=1e-6)
    obj.data.neurolens.dispersion = False
    assert snb.render_needs(sc, obj).wavelength_range_nm()[0] == \
        snb.render_needs(sc, obj).wavelength_range_nm()[1]


def test_02_animated_f_number_and_focus_give_every_value_over_the_frame_range(addon, scene):
    """Keyframed F-Stop / focus distance: the needs hold the value at every frame of
    [frame_start, frame_end] (keys outside the range ignored), read from the F-curves without
    changing the current frame; a focus object gives its distance at the current frame and a
    note saying so; the region keeps only the extremes (clamped to the closest focus)."""
    snb = addon.scene_needs_bpy
    sc, camera = scene
    obj = singlet_camera(camera, "Anim")
    dof = obj.data.dof
    sc.frame_start, sc.frame_end, sc.frame_current = 1, 10, 4
    for frame, f, d in ((1, 4.0, 2.0), (10, 11.0, 20.0), (30, 22.0, 0.01)):
        dof.aperture_fstop, dof.focus_distance = f, d
        dof.keyframe_insert("aperture_fstop", frame=frame)
        dof.keyframe_insert("focus_distance", frame=frame)
    needs = snb.render_needs(sc, obj)
    assert sc.frame_current == 4
    assert len(needs.f_numbers) == 10
    assert min(needs.f_numbers) == pytest.approx(4.0) and max(needs.f_numbers) < 11.5
    assert min(needs.focus_distances_m) == pytest.approx(2.0)
    assert any("F-number animated" in n for n in needs.extras["notes"])
    entry = addon.lenses.load_lens_entry(addon.library.path_for(LENS))
    reduced = addon.model_choice.region_needs(needs, entry)
    assert reduced.f_numbers == (min(needs.f_numbers), max(needs.f_numbers))
    assert reduced.focus_distances_m == (min(needs.focus_distances_m),
                                         max(needs.focus_distances_m))
    target = bpy.data.objects.new("Target", None)
    sc.collection.objects.link(target)
    try:
        target.location = (0.0, 0.0, -3.0)
        dof.focus_object = target
        bpy.context.view_layer.update()
        needs = snb.render_needs(sc, obj)
        assert needs.focus_distances_m == pytest.approx((3.0,))
        assert any("Target" in n and "current frame" in n for n in needs.extras["notes"])
    finally:
        bpy.data.objects.remove(target)


def test_03_auto_uses_the_cheapest_model_within_the_budget(addon, scene, models_dir):
    """AUTO: of the lens's models whose recorded p99 image error meets the budget (6.25 um
    here) and whose domain covers the scene, the one whose recorded cost a camera ray is the
    lowest against the exact trace's is used; the state records its kind, path, expected
    error, budget and reason, and the spec renders it."""
    pytest.importorskip("onnxruntime")
    sc, camera = scene
    fast = fake_model(models_dir, "fast", 3.0, 4e6)
    fake_model(models_dir, "slow", 2.0, 1e6)
    fake_model(models_dir, "coarse", 40.0, 9e6)          # fastest, but over the budget
    obj = singlet_camera(camera)
    state = addon.camera_state.evaluate_camera(obj, sc)
    choice = state.choice
    assert state.model == "learned" and state.setup.model_dir == str(fast)
    assert choice.kind == "learned" and choice.path == str(fast)
    assert choice.error_um_p99 == 3.0 and choice.budget_um == pytest.approx(6.25)
    assert "fast" in choice.name and "within the budget" in choice.reason
    assert not choice.trainable
    spec = addon.sync.camera_spec(obj, sc)
    assert spec.model == "learned" and spec.model_dir == str(fast)


@pytest.mark.parametrize("engine", ["NEUROLENS", "CYCLES"])
def test_03b_auto_picks_the_model_the_cost_table_says_on_the_renderer(addon, scene,
                                                                      models_dir, engine):
    """The same models, their recorded costs cheaper than the exact trace in the engine and
    dearer in Cycles: AUTO takes the cheapest against the exact trace in the engine and the
    exact trace in Cycles, each saying why with the figures; a model with no figure for the
    renderer is passed over and the reason says it was never measured."""
    pytest.importorskip("onnxruntime")
    sc, camera = scene
    sc.render.engine = engine
    cheap = fake_model(models_dir, "cheap", 3.0, 1e6,
                       {"neurolens": (2.0, 0.5), "cycles": (0.2, 0.9)})
    fake_model(models_dir, "dear", 2.0, 1e6, {"neurolens": (2.0, 1.5), "cycles": (0.2, 0.3)})
    obj = singlet_camera(camera)
    choice = addon.camera_state.evaluate_camera(obj, sc).choice
    if engine == "NEUROLENS":
        assert choice.renderer == "neurolens" and choice.kind == "learned"
        assert choice.path == str(cheap) and choice.cost_us == 0.5
        assert choice.exact_cost_us == 2.0
        assert "0.5 us a camera ray in the NEUROLENS engine against the exact trace's 2 us" \
            in choice.reason
    else:
        assert choice.renderer == "cycles" and choice.kind == "exact"
        assert choice.cost_us == choice.exact_cost_us == 0.2
        assert choice.reason.startswith("Exact trace: cheaper in Cycles than dear.neurolens")
        assert "0.3 us a camera ray in Cycles against the exact trace's 0.2 us" in choice.reason
    assert "\u00b5s a camera ray" in choice.summary
    # the figures gone for this renderer: never chosen, and the reason says why
    for name in ("cheap", "dear"):
        path = models_dir / f"{name}.neurolens" / "model.json"
        meta = json.loads(path.read_text())
        meta["costs"].pop("neurolens" if engine == "NEUROLENS" else "cycles")
        path.write_text(json.dumps(meta))
    choice = addon.camera_state.evaluate_camera(obj, sc).choice
    assert choice.kind == "exact" and "was never measured" in choice.reason
    assert ("python -m trainer cost" if engine == "NEUROLENS" else "benchmarks/model_costs.py") \
        in choice.reason


def test_04_auto_uses_the_exact_trace_when_no_model_meets_the_budget(addon, scene,
                                                                     models_dir):
    """A budget tighter than every model (0.1 px = 1.25 um): the exact trace, with a reason
    naming each model and why, and an offer to train; the cached choice follows an edit of
    a model's recorded evaluation (model.json's stat is part of the key)."""
    sc, camera = scene
    fast = fake_model(models_dir, "fast", 3.0, 4e6)
    obj = singlet_camera(camera)
    sc.neurolens.pixel_fraction = 0.1
    state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.model == "exact" and state.choice.kind == "exact"
    assert state.choice.budget_um == pytest.approx(1.25) and state.choice.trainable
    assert "No learned model meets the budget" in state.choice.reason
    assert "learned model fast: image error p99 3 um > budget 1.25 um" in state.choice.reason
    meta = json.loads((fast / "model.json").read_text())
    meta["evaluation"]["image_error_um_p99"] = 1.0
    (fast / "model.json").write_text(json.dumps(meta) + " ")
    pytest.importorskip("onnxruntime")
    assert addon.camera_state.evaluate_camera(obj, sc).choice.path == str(fast)


def test_05_override_buttons_switch_the_model(addon, scene, models_dir, cycles_stub):
    """EXACT, LEARNED and THIN override AUTO in one click (each applied to the camera at
    once, no choice recorded); back on AUTO the choice is used again."""
    pytest.importorskip("onnxruntime")
    _sc, camera = scene
    fast = fake_model(models_dir, "fast", 3.0, 4e6)
    obj = singlet_camera(camera)
    expected = {"EXACT": ("exact", None), "LEARNED": ("learned", "*"), "THIN": ("thin", None),
                "AUTO": ("learned", str(fast))}
    for model, (kind, model_dir) in expected.items():
        obj.data.neurolens.model = model                     # the update callback syncs
        spec = cycles_stub.applied[-1][1]
        assert spec.model == kind, model
        if model_dir == "*":
            assert spec.model_dir is not None
        else:
            assert spec.model_dir == model_dir
        state = addon.sync.last_state(obj)
        assert (state.choice is not None) == (model == "AUTO")


def test_06_panel_shows_the_choice_and_offers_training(addon, scene, models_dir):
    """The Lens section draws 'Using: <model> - expected error p99 X um (budget Y um = F px)',
    the reason and the Error Budget (px); with the exact trace chosen because no model meets
    the budget it draws 'Train a model for this scene', otherwise not; an override hides it."""
    pytest.importorskip("onnxruntime")
    sc, camera = scene
    fake_model(models_dir, "fast", 3.0, 4e6)
    obj = singlet_camera(camera)
    texts, ops = _draw(addon, obj, sc)
    joined = " ".join(texts)
    assert any(t.startswith("Using: learned model fast") for t in texts)
    assert "expected error p99 3 \u00b5m" in joined and "6.25 \u00b5m = 0.5 px" in joined
    assert "neurolens.train_scene_model" not in ops
    sc.neurolens.pixel_fraction = 0.1
    texts, ops = _draw(addon, obj, sc)
    assert any(t.startswith("Using: exact trace") for t in texts)
    assert "neurolens.train_scene_model" in ops
    obj.data.neurolens.model = "EXACT"
    texts, ops = _draw(addon, obj, sc)
    assert not any(t.startswith("Using:") for t in texts)
    assert "neurolens.train_scene_model" not in ops


@pytest.mark.slow
def test_07_train_operator_trains_once_and_auto_picks_the_model(addon, scene, models_dir,
                                                                 trainer_python):
    """neurolens.train_scene_model (EXEC, synchronous): a tiny bi-convex singlet job at a small
    resolution trains a model into <models>/scene-cache (never the add-on folder); AUTO then
    uses it (it covers the region at the f-number's own best focus and meets the budget); a
    second run finds it in the cache instead of training again."""
    pytest.importorskip("onnxruntime")
    cached_models = _cached_models(addon)
    sc, camera = scene
    sc.render.resolution_x, sc.render.resolution_y = 64, 48
    obj = singlet_camera(camera, "Train")
    before = addon.camera_state.evaluate_camera(obj, sc).choice
    assert before.kind == "exact" and before.trainable
    t0 = time.perf_counter()
    assert bpy.ops.neurolens.train_scene_model("EXEC_DEFAULT", camera=obj.name,
                                               **TINY) == {"FINISHED"}
    first = time.perf_counter() - t0
    models = cached_models(models_dir)
    assert len(models) == 1 and models_dir in models[0].parents
    assert addon.training.active_job() is None
    # the trainer measured what a camera ray costs in the engine, through the model and the
    # exact trace; AUTO takes the model only where it is the cheaper (a two-surface singlet's
    # exact trace is hard to beat)
    meta = json.loads((models[0] / "model.json").read_text())
    exact_us, learned_us = (meta["costs"]["neurolens"][k] for k in ("exact_us", "learned_us"))
    assert exact_us > 0 and learned_us > 0 and "cycles" not in meta["costs"]
    state = addon.sync.last_state(obj)                  # the operator re-synced the camera
    assert state.choice.renderer == "neurolens"
    assert (state.model == "learned") == (learned_us < exact_us)
    if state.model == "exact":
        assert state.choice.reason.startswith("Exact trace: cheaper in the NEUROLENS engine")
        # the same model recorded as the cheaper: AUTO uses it
        meta["costs"]["neurolens"]["learned_us"] = exact_us / 2.0
        (models[0] / "model.json").write_text(json.dumps(meta))
        state = addon.camera_state.evaluate_camera(obj, sc)
    assert state.model == "learned" and state.setup.model_dir == str(models[0])
    assert state.choice.path == str(models[0]) and state.choice.name.startswith("scene model")
    assert state.choice.error_um_p99 <= state.choice.budget_um
    # at f/8 the singlet's best focus lies ~1 mm from its full-aperture one: the model covers
    # the sensor position rendered, and so does core.scene_needs.training_region called
    # directly (no focus cache), while its full-aperture focus range alone would not
    import importlib
    core = importlib.import_module(addon.root + ".core.scene_needs")
    entry = state.entry
    needs = addon.model_choice.region_needs(addon.scene_needs_bpy.render_needs(sc, obj), entry)
    direct = core.training_region(entry.lens, needs)
    lo, hi = json.loads((models[0] / "model.json").read_text())["domain"]["sensor_z_range"]
    assert lo <= state.sensor_z_mm <= hi
    assert direct.sensor_z_range[0] <= state.sensor_z_mm <= direct.sensor_z_range[1]
    full_aperture = core.training_region(entry.lens, replace(needs, f_numbers=()))
    assert not (full_aperture.sensor_z_range[0] <= state.sensor_z_mm
                <= full_aperture.sensor_z_range[1])
    assert bpy.ops.neurolens.train_scene_model("EXEC_DEFAULT", camera=obj.name,
                                               **TINY) == {"FINISHED"}
    assert cached_models(models_dir) == models
    print(f"trained in {first:.1f} s")


@pytest.mark.slow
def test_08_cancel_stops_the_trainer_and_leaves_no_model(addon, scene, models_dir,
                                                         trainer_python):
    """A training job (the process the modal operator runs and polls) cancelled with the
    panel's Cancel button while it fits: the trainer exits, the job says 'cancelled', no
    model appears in the cache, and the train button is offered again."""
    cached_models = _cached_models(addon)
    training = addon.training
    sc, camera = scene
    sc.render.resolution_x, sc.render.resolution_y = 80, 60
    obj = singlet_camera(camera, "Cancel")
    # a job long enough (1.5 million exact rays before any fitting: seconds on any machine,
    # longer than drawing the panel) that the cancel always lands while it trains (400 000
    # once let a clean clone's run reach the evaluation first)
    command = training.trainer_command(obj, sc, rays=1_500_000, max_depth=0)
    assert command.models_dir == models_dir and command.argv[1:4] == ["-u", "-m", "trainer"]
    assert command.argv[0] == trainer_python
    job = training.TrainingJob(command.argv, command.cwd, label=command.lens_name).start()
    training.set_active(job)
    try:
        deadline = time.monotonic() + 60.0
        while job.running and not any(ln.startswith("[1/4]") for ln in job.lines):
            assert time.monotonic() < deadline, job.lines
            job.poll()
            time.sleep(0.05)
        assert 0.0 < job.progress < 0.5 and job.running
        _texts, ops = _draw(addon, obj, sc)
        assert "neurolens.cancel_scene_training" in ops
        assert "neurolens.train_scene_model" not in ops
        assert bpy.ops.neurolens.cancel_scene_training() == {"FINISHED"}
        assert job.wait(timeout=20.0) == training.CANCELLED
    finally:
        if job.running:
            job._proc.kill()
        training.set_active(None)
    assert job._proc.poll() is not None
    level, text = addon.operators.training_outcome(job, obj, sc)
    assert level == "INFO" and "cancelled: nothing was added" in text
    assert cached_models(models_dir) == []
    assert not list((models_dir / "scene-cache").glob("*.tmp"))
    _texts, ops = _draw(addon, obj, sc)
    assert "neurolens.train_scene_model" in ops


def test_09_a_trainer_python_without_torch_is_refused_in_one_line(addon, scene, models_dir,
                                                                  torchless_python):
    """With "Trainer Python" naming an interpreter that has no torch (under Blender 5.2 this
    Python itself, with no preference set; under 5.0 the interpreter the venv was made from),
    the operator starts no process and says in one line that training needs torch and where
    to point the preference; nothing is added to the models folder and the button stays."""
    cached_models = _cached_models(addon)
    sc, camera = scene
    sc.render.resolution_x, sc.render.resolution_y = 64, 48
    obj = singlet_camera(camera, "NoTorch")
    t0 = time.perf_counter()
    with pytest.raises(RuntimeError) as err:
        bpy.ops.neurolens.train_scene_model("EXEC_DEFAULT", camera=obj.name, **TINY)
    message = str(err.value).strip()
    assert time.perf_counter() - t0 < 20.0
    assert "\n" not in message
    assert "training needs torch" in message and torchless_python in message
    assert "Trainer Python" in message and "Python 3.11" in message
    assert addon.training.active_job() is None
    assert cached_models(models_dir) == []
    _texts, ops = _draw(addon, obj, sc)
    assert "neurolens.train_scene_model" in ops
