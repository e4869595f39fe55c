"""Learned models of a lens: which of the candidates belong to it, and whether they can run.

A model is a `NAME.neurolens` directory whose model.json names the lens it was trained for by
the lens's content hash; a model for another lens (or another version of the file) never
applies. Candidates are model directories or folders holding them; the first match wins.
Headers, discovery and the file format are neural.modelfile's. The learned lens runs through
onnxruntime: without it the exact trace is used, saying why.
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import ModelError
from ..neural.modelfile import ModelHeader, find_model, model_dirs, read_header

#: The message shown when onnxruntime cannot be imported (the learned lens needs it).
ONNXRUNTIME_MISSING = "onnxruntime not available: learned lens disabled; exact and thin work"

_ORT: list = []            # [(available, message)] once probed

__all__ = ["ONNXRUNTIME_MISSING", "ModelHeader", "find_model", "model_dirs", "models_of_lens",
           "onnxruntime_status", "read_header"]


def models_of_lens(content_hash: str, candidates) -> list[Path]:
    """The model directories among `candidates` trained for the lens of this content hash."""
    mine = []
    for d, _key in model_dirs(candidates):
        try:
            if read_header(d).lens_content_hash == content_hash:
                mine.append(d)
        except ModelError:
            continue
    return mine


def onnxruntime_status() -> tuple[bool, str]:
    """(available, message): whether `import onnxruntime` works here (probed once)."""
    if not _ORT:
        try:
            import onnxruntime
            _ORT.append((True, f"onnxruntime {getattr(onnxruntime, '__version__', '?')}"))
        except Exception as exc:  # noqa: BLE001 - ImportError, or a broken native library
            _ORT.append((False, f"{ONNXRUNTIME_MISSING} ({exc.__class__.__name__}: {exc})"))
    return _ORT[0]


def forget() -> None:
    """Probe onnxruntime again and re-read every header (e.g. when the add-on unregisters)."""
    from ..neural.modelfile import clear_header_cache
    _ORT.clear()
    clear_header_cache()
