"""Faults while a model is written: a trainer killed at any moment, or an export that fails
half-way, never leaves something that loads as a model."""

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.neural.model import LearnedLens

pytestmark = pytest.mark.slow          # trains models

ROOT = Path(__file__).resolve().parents[2]
SINGLET = ROOT / "presets" / "lenses" / "biconvex_singlet.toml"
SINGLET_MODEL = ROOT / "presets" / "models" / "biconvex_singlet.neurolens"


def _fit_cmd(out: Path):
    return [sys.executable, "-m", "trainer", "fit", str(SINGLET), "--out", str(out),
            "--rays", "15000", "--max-depth", "0", "--theta", "4", "--ensemble", "3"]


def test_01_killed_trainer_leaves_no_loadable_partial_model(tmp_path):
    """SIGKILL at several moments of a fit (start-up, data, training, export): afterwards the
    output either does not exist or is a complete model that loads with its hashes checked;
    a run left alone completes and loads."""
    lens = load_lens(SINGLET)
    out = tmp_path / "m.neurolens"
    t0 = time.perf_counter()
    done = subprocess.run(_fit_cmd(out), cwd=ROOT, capture_output=True, timeout=300)
    full = time.perf_counter() - t0
    assert done.returncode == 0, done.stderr.decode()[-500:]
    LearnedLens.load(out, lens=lens)
    for frac in (0.5, 0.9):
        target = tmp_path / f"k{int(frac * 100)}.neurolens"
        p = subprocess.Popen(_fit_cmd(target), cwd=ROOT, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        time.sleep(frac * full)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)
        if target.exists():
            LearnedLens.load(target, lens=lens)        # complete, or the load raises
        for stray in tmp_path.glob(f"{target.name}.*.tmp"):
            with pytest.raises((ModelError, FileNotFoundError, OSError)):
                if not (stray / "model.json").exists():
                    raise FileNotFoundError(stray)
                LearnedLens.load(stray, lens=lens)


def test_02_an_interrupted_write_leaves_no_model(tmp_path, monkeypatch):
    """If export fails half-way, no NAME.neurolens appears and the temporary files are gone."""
    import trainer.export_onnx as ex
    from trainer.pipeline import write_model
    meta = json.loads((SINGLET_MODEL / "model.json").read_text())

    def boom(*a, **k):
        raise RuntimeError("killed")
    monkeypatch.setattr(ex, "write_onnx_files", boom)
    with pytest.raises(RuntimeError):
        write_model(meta, tmp_path / "x.neurolens")
    assert list(tmp_path.iterdir()) == []
