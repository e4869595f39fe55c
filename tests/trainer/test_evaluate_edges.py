"""trainer evaluate when nothing can be measured: one ModelError, not a division by zero."""

import dataclasses
from pathlib import Path

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.core.lensfile import load_lens
from trainer.evaluate import domain_of, relative_error

ROOT = Path(__file__).resolve().parents[2]


def test_01_no_valid_ray_is_one_model_error():
    """A stop closed to a nanometre passes none of the evaluation's sensor rays: the error
    measure says so in one line (it divided zero by zero)."""
    pytest.importorskip("onnxruntime")
    from neurolens_addon.neural.model import LearnedLens
    lens = load_lens(ROOT / "presets" / "lenses" / "biconvex_singlet.toml")
    model = LearnedLens.load(ROOT / "presets" / "models" / "biconvex_singlet.neurolens",
                             lens=lens)
    shut = dataclasses.replace(domain_of(model.meta), stop_radius_mm=1e-6)
    with pytest.raises(ModelError, match="no ray passes both"):
        relative_error(model, lens, shut, 2000, 0)
