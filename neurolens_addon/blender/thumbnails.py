"""Cross-section thumbnails for the lens picker, through bpy.utils.previews.

Each lens is drawn once (crosssection.py) into a PNG cached in the extension's user directory
("thumbnails", never the add-on folder), named by the lens's content hash, and loaded into one
preview collection that lives from register() to unregister().
"""

from __future__ import annotations

from pathlib import Path

import bpy
import bpy.utils.previews

from ..core import crosssection
from .preferences import user_directory

THUMB_SIZE = (256, 128)
_PREVIEWS: dict = {}          # "collection" -> ImagePreviewCollection while registered


def thumbnail_path(content_hash: str) -> Path:
    return user_directory("thumbnails") / f"{content_hash}-v{crosssection.RENDER_VERSION}.png"


def ensure_thumbnail(entry) -> Path:
    """The cached PNG of `entry`'s cross-section, drawn now if missing."""
    path = thumbnail_path(entry.content_hash)
    if not path.is_file():
        rgba = crosssection.cross_section_rgba(entry.lens, *THUMB_SIZE)
        crosssection.write_png(path, rgba)
    return path


def icon_id(entry) -> int:
    """The preview icon of a lens (0 when previews are unavailable or drawing failed)."""
    pcoll = _PREVIEWS.get("collection")
    if pcoll is None or entry is None or entry.table:     # a ray table has no surfaces to draw
        return 0
    key = entry.content_hash
    preview = pcoll.get(key)
    if preview is None:
        try:
            path = ensure_thumbnail(entry)
        except Exception as exc:  # noqa: BLE001 - an undrawable lens must not break the picker
            print(f"NeuroLens: no thumbnail for '{entry.name}': {exc}")
            return 0
        preview = pcoll.load(key, str(path), "IMAGE")
    return preview.icon_id


def collection():
    return _PREVIEWS.get("collection")


def register():
    if "collection" not in _PREVIEWS:
        _PREVIEWS["collection"] = bpy.utils.previews.new()


def unregister():
    pcoll = _PREVIEWS.pop("collection", None)
    if pcoll is not None:
        bpy.utils.previews.remove(pcoll)
