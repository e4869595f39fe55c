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
            "--rays", "6000", "--max-depth", "0", "--theta", "4", "--ensemble", "2"]


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
    import onnx_export as ex
    from trainer.pipeline import write_model
    meta = json.loads((SINGLET_MODEL / "model.json").read_text())

    def boom(*a, **k):
        raise RuntimeError("killed")
    monkeypatch.setattr(ex, "write_onnx_files", boom)
    with pytest.raises(RuntimeError):
        write_model(meta, tmp_path / "x.neurolens")
    assert list(tmp_path.iterdir()) == []


def test_03_a_model_directory_is_shared_as_the_umask_says(tmp_path):
    """A new model directory gets 0777 & ~umask and its files 0666 & ~umask (mkdtemp's 0700
    used to hide a model on a shared models folder from the other users); a model written
    over an old one keeps the old directory's mode."""
    import os

    from trainer.pipeline import write_model
    meta = json.loads((SINGLET_MODEL / "model.json").read_text())
    out = tmp_path / "x.neurolens"
    old_mask = os.umask(0o022)
    try:
        write_model(dict(meta), out)
        assert oct(out.stat().st_mode & 0o777) == "0o755"
        assert {oct(f.stat().st_mode & 0o777) for f in out.iterdir()} == {"0o644"}
        os.chmod(out, 0o750)
        write_model(dict(meta), out)
        assert oct(out.stat().st_mode & 0o777) == "0o750"
    finally:
        os.umask(old_mask)
    LearnedLens.load(out, lens=load_lens(SINGLET))


def test_04_a_full_disk_leaves_the_old_model(tmp_path):
    """write_model with every file capped at 4 KB (a nearly full disk: testdata.full_disk):
    the old model directory stays and loads, one line names the model's file (not the
    temporary directory's), and no temporary directory is left."""
    import shutil

    from testdata.full_disk import run_with_file_limit, write_model_script
    out = tmp_path / "x.neurolens"
    shutil.copytree(SINGLET_MODEL, out)
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    script = write_model_script(SINGLET_MODEL / "model.json", out)
    p = run_with_file_limit(4096, "-c", script)
    assert p.returncode == 1, p.stderr
    line = p.stderr.strip()
    assert "\n" not in line and str(out) in line and ".tmp" not in line, line
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before
    assert sorted(f.name for f in tmp_path.iterdir()) == ["x.neurolens"]
    LearnedLens.load(out, lens=load_lens(SINGLET))
