"""Faults: a trainer killed at any moment never leaves something that loads as a model, and
the add-on's code never unpickles, evaluates file contents or reaches the network."""

import ast
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.neural.model import LearnedLens

ROOT = Path(__file__).resolve().parents[2]
SINGLET = ROOT / "presets" / "lenses" / "biconvex_singlet.toml"


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


FORBIDDEN_CALLS = {"eval", "exec", "compile", "__import__"}
FORBIDDEN_MODULES = {"pickle", "cPickle", "dill", "marshal", "shelve", "socket", "urllib",
                     "http", "requests", "ftplib", "smtplib"}


def test_02_addon_code_has_no_pickle_eval_or_network():
    """No module of the shipped add-on imports pickle-like or network modules, or calls eval,
    exec, compile or __import__ (lens and model files are data, never code)."""
    offenders = []
    for path in sorted((ROOT / "neurolens_addon").rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [(node.module or "").split(".")[0]]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id in FORBIDDEN_CALLS:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {node.func.id}")
                continue
            else:
                continue
            bad = [n for n in names if n in FORBIDDEN_MODULES]
            if bad:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {bad}")
    assert not offenders, "\n".join(offenders)


def test_03_model_files_are_read_by_fixed_names_only(tmp_path):
    """A model.json whose "files" names a path outside its directory is not followed: the
    loader reads only its fixed file names and refuses the model when they are missing."""
    import json
    import shutil
    src = ROOT / "presets" / "models" / "biconvex_singlet.neurolens"
    dst = tmp_path / "evil.neurolens"
    shutil.copytree(src, dst)
    secret = tmp_path / "secret.onnx"
    secret.write_bytes((dst / "forward.onnx").read_bytes())
    meta = json.loads((dst / "model.json").read_text())
    meta["files"]["../secret.onnx"] = meta["files"]["forward.onnx"]
    (dst / "forward.onnx").unlink()
    (dst / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match="forward.onnx"):
        LearnedLens.load(dst)
