"""The lens library the picker shows: the shipped presets plus the user's lens folder.

A file that cannot be read costs its own entry only: it is listed (last) with a one-line note
saying why, and every other lens is listed as before.

Identifiers are stable strings stored on each camera: a preset's file stem
("double_gauss_50mm_f2") or "user:" + a file name in the user's lens folder
("user:my_lens.toml"; "user:NAME.neurolens" for the model of a lens known only from a ray
table, camera.table_lens). Listing is cached by the folders' contents (names, sizes, times);
the lenses themselves are cached by neurolens_addon.camera.lenses, which also resolves an
identifier to its file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..camera.lens_kinds import lens_kind, picker_order
from ..camera.lenses import (DEFAULT_LENS_ID, LENS_SUFFIXES, MODEL_SUFFIX, PRESETS_DIR,
                             USER_PREFIX, LensEntry, library_path, load_lens_entry)
from ..camera.table_lens import is_table_model
from ..core.errors import NeuroLensError, debug_traceback
from .preferences import user_directory

__all__ = ["DEFAULT_LENS_ID", "LibraryItem", "PRESETS_DIR", "USER_PREFIX", "items", "path_for",
           "user_lenses_dir"]


@dataclass(frozen=True)
class LibraryItem:
    """One lens of the picker: `entry` is None (and `error` says why) for a broken file."""

    id: str
    path: str
    entry: LensEntry | None
    error: str | None = None

    @property
    def is_user(self) -> bool:
        return self.id.startswith(USER_PREFIX)

    @property
    def label(self) -> str:
        if self.entry is None:
            return f"{Path(self.path).name} (unreadable)"
        return self.entry.name

    @property
    def kind(self) -> str:
        """The picker's group (camera.lens_kinds); "" for a broken file."""
        return lens_kind(self.entry.lens) if self.entry is not None else ""

    @property
    def summary(self) -> str:
        """Designed focal length and f-number, and the kind, as the picker shows them."""
        if self.entry is None:
            return self.error or "unreadable lens file"
        zoom = self.entry.lens.zoom_gaps
        focal = (f"{zoom.positions[0]:.4g}-{zoom.positions[-1]:.4g} mm" if zoom is not None
                 else f"{self.entry.focal_length_mm:.4g} mm")
        known = ", known only from a ray table" if self.entry.table else ""
        return f"{focal} f/{self.entry.f_number:.3g}, {self.kind}{known}"

    @property
    def search_text(self) -> str:
        """What the picker's search lists and matches: the name and the summary."""
        return f"{self.label}  ({self.summary})" if self.entry is not None else self.label


_CACHE: dict = {}


def _listing(folder: Path):
    """(name, size, mtime) of the lens files in `folder`, and of the model directories of
    lenses known only from a ray table (their model.json's size and time)."""
    files = []
    try:
        with os.scandir(folder) as it:
            for e in it:
                if e.is_file() and e.name.lower().endswith(LENS_SUFFIXES):
                    files.append((e.name, e.stat().st_size, e.stat().st_mtime_ns))
                elif e.is_dir() and e.name.endswith(MODEL_SUFFIX) and is_table_model(e.path):
                    st = os.stat(os.path.join(e.path, "model.json"))
                    files.append((e.name, st.st_size, st.st_mtime_ns))
    except OSError:
        files = []
    return tuple(sorted(files))


def _one_line(text: str) -> str:
    """A note for the picker: one line, at most 300 characters."""
    text = " ".join(text.split())
    return text if len(text) <= 300 else text[:297] + "..."


def user_lenses_dir() -> Path:
    return user_directory("lenses")


def _order(item: LibraryItem):
    """Grouped by kind, then by focal length (camera.lens_kinds); broken files last."""
    if item.entry is None:
        return (1, (), item.label.lower())
    return (0, picker_order(item.entry.lens), item.label.lower())


def items() -> list[LibraryItem]:
    """Presets then the user's lenses, each grouped by kind and sorted by focal length;
    broken files are listed with why."""
    user_dir = user_lenses_dir()
    key = (str(user_dir), _listing(PRESETS_DIR), _listing(user_dir))
    if _CACHE.get("key") == key:
        return _CACHE["items"]
    found = []
    for folder, prefix, only_toml in ((PRESETS_DIR, "", True), (user_dir, USER_PREFIX, False)):
        for name, _size, _mtime in key[1 if prefix == "" else 2]:
            if only_toml and not name.endswith(".toml"):
                continue
            path = folder / name
            ident = prefix + (Path(name).stem if prefix == "" else name)
            try:
                found.append(LibraryItem(ident, str(path), load_lens_entry(path)))
            except NeuroLensError as exc:
                found.append(LibraryItem(ident, str(path), None, _one_line(str(exc))))
            except Exception as exc:  # noqa: BLE001 - the last line of defence: one file, one entry
                # (the readers raise only LensError: anything else is a bug, said in its entry)
                debug_traceback()
                found.append(LibraryItem(ident, str(path), None, _one_line(
                    f"{path.name}: unexpected {type(exc).__name__}: {exc} (please report it)")))
    presets = sorted((i for i in found if not i.is_user), key=_order)
    users = sorted((i for i in found if i.is_user), key=_order)
    result = presets + users
    _CACHE.update(key=key, items=result)
    return result


def path_for(lens_id: str) -> str:
    """The file of a library identifier. Raises LensError for an unknown identifier."""
    return library_path(lens_id, user_lenses_dir())


def clear_cache() -> None:
    _CACHE.clear()
