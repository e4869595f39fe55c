"""A learned lens (model.json dict) written as its ONNX graphs: forward.onnx and
forward_jacobian.onnx (onnx_export.forward) and forward_fast.onnx (onnx_export.fast),
each serialised once and recorded by sha256, the digest model.json's "files" holds.

The same model dict always gives the same bytes (nodes and constants are named in creation
order), so `scripts/generated_digests.py` can show that a change leaves the graphs alone.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from neurolens_addon.neural.modelfile import FAST_FILE, FORWARD_FILE, JACOBIAN_FILE

from .fast import build_fast
from .fast_domain import occupancy_limits
from .forward import build_forward

__all__ = ["build_fast", "build_forward", "occupancy_limits", "write_onnx_files"]


def write_onnx_files(model: dict, directory, shown=None) -> dict[str, str]:
    """Write forward.onnx, forward_jacobian.onnx and forward_fast.onnx into `directory`, each
    flushed and read back (core.atomic.write_checked; errors name the file in `shown`, the
    model directory the user knows, when `directory` is a temporary one); {filename: sha256
    hex}."""
    from neurolens_addon.core.atomic import write_checked
    directory = Path(directory)
    named = Path(shown) if shown is not None else directory
    directory.mkdir(parents=True, exist_ok=True)
    hashes = {}
    for fname, build in ((FORWARD_FILE, lambda: build_forward(model)),
                         (JACOBIAN_FILE, lambda: build_forward(model, jacobian=True)),
                         (FAST_FILE, lambda: build_fast(model))):
        data = build().SerializeToString()
        write_checked(directory / fname, data, shown=named / fname)
        hashes[fname] = hashlib.sha256(data).hexdigest()
    return hashes
