"""What the model loader reads: only a model directory's fixed file names, whatever its
model.json lists."""

from pathlib import Path

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.neural.model import LearnedLens

ROOT = Path(__file__).resolve().parents[2]


def test_01_model_files_are_read_by_fixed_names_only(tmp_path):
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
