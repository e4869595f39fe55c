"""A lens known only from a ray table, rendered from the command line by both renderers: the
frame is the frame of the Tessar whose rays the table holds (testdata.table_lens), and the
set-up says the table's model renders it whatever the camera asked."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow          # renders from the command line
pytest.importorskip("onnxruntime")

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "presets" / "scenes" / "demo.blend"
SIZE, SAMPLES = "160x90", 32


def cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "neurolens_addon.render", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def _blocks(x: np.ndarray, k: int = 8) -> np.ndarray:
    h, w = x.shape[0] // k * k, x.shape[1] // k * k
    return x[:h, :w].reshape(h // k, k, w // k, k, -1).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def model():
    from testdata import table_lens
    return table_lens.MODEL


@pytest.mark.parametrize("engine", ["neurolens", "cycles"])
def test_the_table_lens_renders_the_frame_of_the_lens_it_was_taken_from(model, engine,
                                                                        tmp_path):
    """The demo scene through the table's model and through the exact Tessar at the table's
    f-number focused at infinity: the same picture (8 x 8 blocks correlate >= 0.99, mean light
    within 3 %), in the engine and in Cycles (its learned OSL camera)."""
    from testdata.engine_scenes import read_exr
    from neurolens_addon.camera.lenses import load_lens_entry
    n = load_lens_entry(model).f_number
    frames = {}
    for name, lens in (("table", model), ("exact", "tessar_f4_5")):
        out = tmp_path / f"{name}.exr"
        p = cli(DEMO, "--lens", lens, "--engine", engine, "--samples", SAMPLES, "--resolution",
                SIZE, "--focus", "1e9", "--fstop", f"{n:.4f}", "--no-denoise", "--out", out)
        assert p.returncode == 0, p.stderr[-2000:]
        if name == "table":
            assert "measured tessar (learned)" in p.stderr + p.stdout
        d = read_exr(out)
        frames[name] = np.stack([np.asarray(d[f"Combined.{c}"]) for c in "RGB"], axis=-1)
    a, b = frames["table"], frames["exact"]
    assert np.corrcoef(_blocks(a).ravel(), _blocks(b).ravel())[0, 1] >= 0.99
    assert a.mean() == pytest.approx(b.mean(), rel=0.03)


def test_show_setup_names_the_table_and_why_whatever_model_is_asked(model):
    """`--show-setup --model exact` on a table lens: the learned model, its directory, and
    why (a ray table: its model renders it whatever its cost)."""
    p = cli(DEMO, "--lens", model, "--model", "exact", "--show-setup")
    assert p.returncode == 0, p.stderr[-2000:]
    lines = p.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("{"))
    setup = json.JSONDecoder().raw_decode("\n".join(lines[start:]))[0]
    assert setup["model"] == "learned" and setup["model_dir"] == str(model)
    assert "known only from a ray table" in setup["choice_why"]
    assert setup["stop_radius_mm"] is None           # no stop: its model's domain bounds it
    assert any("ray table" in text for level, text in setup["messages"] if level == "WARNING")
