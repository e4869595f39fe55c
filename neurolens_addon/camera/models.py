"""Learned models of a lens: their headers, where they are found, and whether they can run.

A model is a `NAME.neurolens` directory whose model.json names the lens it was trained for by
the lens's content hash; a model for another lens (or another version of the file) never
applies. Candidates are model directories or folders holding them; the first match wins.
The learned lens runs through onnxruntime: without it the exact trace is used, saying why.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import ModelError
from .lru import cache, stats

#: The message shown when onnxruntime cannot be imported (the learned lens needs it).
ONNXRUNTIME_MISSING = "onnxruntime not available: learned lens disabled; exact and thin work"

_MODELS = cache(256)       # (model.json path, mtime_ns, size) -> ModelInfo
_ORT: list = []            # [(available, message)] once probed



@dataclass(frozen=True)
class ModelInfo:
    """What a lens set-up needs from a model.json without loading its graphs."""

    directory: str
    lens_content_hash: str
    dispersion: bool
    sensor_z_range: tuple[float, float]
    film_radius_mm: float


def model_info(directory) -> ModelInfo:
    """Read `directory/model.json` (cached by its mtime and size). Raises ModelError."""
    path = Path(directory) / "model.json"
    try:
        st = path.stat()
    except OSError:
        raise ModelError("no model.json in the model directory", path=str(directory)) from None
    key = (str(path), st.st_mtime_ns, st.st_size)
    hit = _MODELS.get_lru(key)
    if hit is not None:
        return hit
    stats["model_reads"] += 1
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
        domain = meta["domain"]
        zr = domain["sensor_z_range"]
        info = ModelInfo(directory=str(Path(directory)),
                         lens_content_hash=str(meta["lens"]["content_hash"]),
                         dispersion=bool(domain.get("dispersion", False)),
                         sensor_z_range=(float(zr[0]), float(zr[1])),
                         film_radius_mm=float(domain["film_radius_mm"]))
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise ModelError(f"not a readable NeuroLens model.json ({exc.__class__.__name__}: "
                         f"{exc})", path=str(path)) from None
    return _MODELS.put(key, info)


def model_dirs(candidates) -> list[tuple[Path, tuple]]:
    """(model directory, stat key of its model.json) for every model among `candidates`
    (model directories, or folders of *.neurolens directories), each once. Cheap: one
    scandir per folder and one stat per model, on every redraw."""
    out, seen = [], set()

    def add(path: str) -> bool:
        try:
            st = os.stat(os.path.join(path, "model.json"))
        except OSError:
            return False
        if path not in seen:
            seen.add(path)
            out.append((Path(path), (path, st.st_mtime_ns, st.st_size)))
        return True

    for cand in candidates:
        if cand is None:
            continue
        folder = os.path.normpath(os.fspath(cand))
        if add(folder):
            continue
        try:
            with os.scandir(folder) as it:
                names = sorted(e.path for e in it if e.name.endswith(".neurolens"))
        except OSError:
            continue
        for path in names:
            add(path)
    return out


def models_of_lens(content_hash: str, candidates) -> list[Path]:
    """The model directories among `candidates` trained for the lens of this content hash."""
    mine = []
    for d, _key in model_dirs(candidates):
        try:
            if model_info(d).lens_content_hash == content_hash:
                mine.append(d)
        except ModelError:
            continue
    return mine


def find_model(content_hash: str, candidates) -> ModelInfo | None:
    """The first model among `candidates` trained for this very lens, or None."""
    mine = models_of_lens(content_hash, candidates)
    return model_info(mine[0]) if mine else None


def onnxruntime_status() -> tuple[bool, str]:
    """(available, message): whether `import onnxruntime` works here (probed once)."""
    if not _ORT:
        try:
            import onnxruntime
            _ORT.append((True, f"onnxruntime {getattr(onnxruntime, '__version__', '?')}"))
        except Exception as exc:  # noqa: BLE001 - ImportError, or a broken native library
            _ORT.append((False, f"{ONNXRUNTIME_MISSING} ({exc.__class__.__name__}: {exc})"))
    return _ORT[0]


def forget_onnxruntime_probe() -> None:
    _ORT.clear()
