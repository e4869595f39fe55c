"""What a camera ray costs per renderer (trainer.cost), recorded in model.json and read back
by the model header that model choice uses."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.neural.modelfile import read_header

ROOT = Path(__file__).resolve().parents[2]
LENS = ROOT / "presets" / "lenses" / "biconvex_singlet.toml"
MODEL = ROOT / "presets" / "models" / "biconvex_singlet.neurolens"


@pytest.fixture
def model(tmp_path):
    out = tmp_path / "m.neurolens"
    shutil.copytree(MODEL, out)
    return out


def test_01_the_engine_costs_are_measured_and_recorded_beside_the_others(model):
    """`trainer cost --record`: the engine's two costs positive and finite, written into
    model.json (the Cycles figures already there kept), read back by the header; nothing
    measured, nothing rewritten."""
    meta = json.loads((model / "model.json").read_text())
    meta["costs"] = {"cycles": {"exact_us": 0.25, "learned_us": 0.75}}
    (model / "model.json").write_text(json.dumps(meta))
    p = subprocess.run([sys.executable, "-m", "trainer", "cost", str(model), "--lens",
                        str(LENS), "--record"], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("neurolens: exact ") and "a camera ray" in p.stdout
    header = read_header(model)
    exact, learned = header.ray_cost_us("neurolens")
    assert 0.0 < exact < 100.0 and 0.0 < learned < 100.0
    assert header.ray_cost_us("cycles") == (0.25, 0.75)
    assert header.costs_measured("cycles") == ""            # recorded without its stamp
    costs = json.loads((model / "model.json").read_text())["costs"]
    assert costs["neurolens"]["provider"] and costs["neurolens"]["machine"]
    assert costs["neurolens"]["date"] == header.costs_measured("neurolens")[:10]
    from trainer.cost import record_costs
    before = (model / "model.json").read_bytes()
    record_costs(model, {})
    assert (model / "model.json").read_bytes() == before


def test_02_the_measurement_is_of_the_two_traces_on_the_same_rays(model):
    """engine_cost directly: the exact trace of a two-surface singlet costs less a ray than
    the learned model's two stages through onnxruntime (its network is the work)."""
    from trainer.cost import engine_cost
    c = engine_cost(model, load_lens(LENS), rays=4096, repeats=2)
    assert 0.0 < c["exact_us"] < c["learned_us"]


@pytest.mark.parametrize("bad, field", [
    ({"neurolens": {"exact_us": -1.0, "learned_us": 1.0}}, "costs.neurolens.exact_us"),
    ({"cycles": {"exact_us": 1.0, "learned_us": 1e9}}, "costs.cycles.learned_us"),
    ({"cycles": {"exact_us": "fast", "learned_us": 1.0}}, "costs.cycles.exact_us"),
    ({"cycles": {"exact_us": 1.0}}, "costs.cycles.learned_us"),
    ({"neurolens": [1.0, 2.0]}, "costs.neurolens"),
    ({"neurolens": {"exact_us": 0.0, "learned_us": 1.0}}, "costs.neurolens.exact_us"),
    ({"cycles": {"exact_us": 1.0, "learned_us": 2.0, "date": 20261128}}, "costs.cycles.date"),
])
def test_03_a_bad_cost_is_refused_naming_the_field(model, bad, field):
    meta = json.loads((model / "model.json").read_text())
    meta["costs"] = bad
    (model / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError) as e:
        read_header(model)
    assert field in str(e.value) and "model.json" in str(e.value)


def test_04_every_shipped_model_carries_its_costs_per_renderer():
    """Every model in presets/models records what a camera ray costs through it and through
    the exact trace in the engine, and in Cycles unless Cycles cannot render it (a learned
    anamorphic lens: its cartesian stages have no shader), each with its date and machine:
    without them AUTO would pass the model over."""
    from neurolens_addon.core.irf import RADIAL, model_frames
    from neurolens_addon.neural.modelfile import read_model_json
    models = sorted((ROOT / "presets" / "models").glob("*.neurolens"))
    assert len(models) >= 46
    for model_dir in models:
        header = read_header(model_dir)
        _d, meta, _g, _f = read_model_json(model_dir)
        radial = all(f is RADIAL for f in model_frames(meta))
        for renderer in ("neurolens", "cycles") if radial else ("neurolens",):
            cost = header.ray_cost_us(renderer)
            assert cost is not None, f"{model_dir.name}: no {renderer} cost"
            assert all(0.0 < c < 100.0 for c in cost), (model_dir.name, renderer, cost)
            assert header.costs_measured(renderer).startswith("20"), model_dir.name
