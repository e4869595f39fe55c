"""Scene models cached by content hash, so a region of a lens is never trained twice.

A scene model for lens L, region R (core.scene_needs.TrainingRegion) and trainer settings C
lives at  <models dir>/scene-cache/<lens slug>-<key>.neurolens  with
    key = sha256(L's content hash, R rounded to 1e-6, C)[:24]   (TrainingRegion.key).
Changing the prescription changes its content hash and so the key: an edited lens is never
served a stale model. The cache is plain files in the user's models directory (never the
add-on folder), so it survives Blender restarts; a directory only counts once it holds a
model.json (the trainer writes the whole directory under a temporary name and renames it, so
an interrupted training leaves nothing that looks like a model).
"""

from __future__ import annotations

import re
from pathlib import Path

from ..core.prescription import Lens
from ..core.scene_needs import TrainingRegion
from .modelfile import MODEL_FILE, MODEL_SUFFIX, model_dirs

CACHE_DIR = "scene-cache"


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")[:40] or "lens"


def scene_model_path(models_dir, lens: Lens, region: TrainingRegion, config: dict) -> Path:
    """Where the scene model for (lens, region, config) lives, whether or not it exists."""
    root = Path(models_dir).resolve() / CACHE_DIR
    path = (root / f"{_slug(lens.name)}-{region.key(lens, config)}{MODEL_SUFFIX}").resolve()
    if root not in path.parents:                       # a lens name never escapes the cache
        raise ValueError(f"scene model path {path} is outside {root}")
    return path


def cached_scene_model(models_dir, lens: Lens, region: TrainingRegion,
                       config: dict) -> Path | None:
    """The cached model directory, or None when it has not been trained yet."""
    path = scene_model_path(models_dir, lens, region, config)
    return path if (path / MODEL_FILE).is_file() else None


def cache_dir(models_dir) -> Path:
    """The scene-model cache folder of a models directory (a modelfile.model_dirs candidate)."""
    return Path(models_dir) / CACHE_DIR


def cached_models(models_dir) -> list[Path]:
    """Every complete model in the cache (for neural.choice), in path order."""
    return [d for d, _key in model_dirs([cache_dir(models_dir)])]
