"""Finding and loading lenses: preset names, library identifiers and files, cached by content.

A lens is named by a preset's file stem ("double_gauss_50mm_f2"), a library identifier
("user:" + a file name in the user's lens folder) or a file path (.toml, pbrt .dat or Zemax .zmx).
`load_lens_entry(path)` reads a file with core.lensfile once per content (sha256 of its bytes;
one stat() per call decides whether to re-read) and keeps the figures the panel and the
resolver ask for: paraxial focal length, design f-number, closest focus.
"""

from __future__ import annotations

import functools
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import LensError
from ..core.prescription import Lens
from .lru import cache, stats

ADDON_ROOT = Path(__file__).resolve().parents[2]
PRESETS_DIR = ADDON_ROOT / "presets" / "lenses"
PRESET_MODELS_DIR = ADDON_ROOT / "presets" / "models"
DEFAULT_LENS_ID = "double_gauss_50mm_f2"
USER_PREFIX = "user:"
LENS_SUFFIXES = (".toml", ".dat", ".zmx")
#: a model directory's suffix: one learned from a ray table is a lens (camera.table_lens)
MODEL_SUFFIX = ".neurolens"

_BY_STAT = cache(256)      # (realpath, mtime_ns, size) -> file hash
_BY_HASH = cache(128)      # (file hash, path) -> LensEntry
_TABLES = cache(16)        # (model.json, mtime, size) -> LensEntry of a ray table's lens



@dataclass(frozen=True)
class LensEntry:
    """A loaded lens with the figures the panel shows. Immutable and shared by content."""

    lens: Lens
    path: str
    file_hash: str          # sha256 of the file's bytes (first 16 hex digits)
    content_hash: str       # Lens.content_hash(): what changes the rays
    efl_mm: float           # paraxial effective focal length at the d line
    closest_focus_mm: float  # from the sensor

    @property
    def name(self) -> str:
        return self.lens.name

    @property
    def table(self) -> bool:
        """Whether the lens is known only from a ray table (camera.table_lens): its learned
        model is the lens."""
        return bool(getattr(self.lens, "table", False))

    @property
    def f_number(self) -> float:
        """The widest f-number of the lens as it stands (its design f-number at this zoom:
        core.variable_gaps.lens_at), the lens's own: one source for every caller."""
        return float(self.lens.f_number)

    @property
    def focal_length_mm(self) -> float:
        """The designer's stated focal length."""
        return float(self.lens.focal_length_mm)

    @functools.cached_property
    def squeeze(self) -> float:
        """f_y / f_x of an anamorphic lens (core.paraxial.squeeze); 1 for a lens of
        revolution."""
        if not self.lens.anamorphic:
            return 1.0
        from ..core.paraxial import squeeze
        return squeeze(self.lens)


def zoomed_entry(entry: LensEntry, focal_length_mm: float) -> LensEntry:
    """The entry of a zoom lens (a [zoom] table) set to a focal length within its range: the
    lens with its zoom gaps (and its iris, where the table has a stop column) moved
    (core.variable_gaps.lens_at), its paraxial focal length, and its widest f-number there:
    the moved lens's own design f-number, which lens_at sets (one source for everyone)."""
    from ..core.focus import closest_focus_mm
    from ..core.paraxial import paraxial_data
    from ..core.variable_gaps import lens_at, zoom_position
    lens = entry.lens
    s = zoom_position(lens, focal_length_mm)
    if s == 0.0:
        return entry
    moved = lens_at(lens, zoom=s)
    return LensEntry(lens=moved, path=entry.path, file_hash=entry.file_hash,
                     content_hash=moved.content_hash(),
                     efl_mm=float(paraxial_data(moved).efl_mm),
                     closest_focus_mm=float(closest_focus_mm(moved)))


def grouped_entry(entry: LensEntry, position: int) -> LensEntry:
    """The entry of a lens with its focusing groups at a tabulated focus position (the lens a
    model trained there learned: camera.models finds models by its content hash)."""
    from ..core.paraxial import paraxial_data
    from ..core.variable_gaps import lens_at
    moved = lens_at(entry.lens, focus=float(position))
    return LensEntry(lens=moved, path=entry.path, file_hash=entry.file_hash,
                     content_hash=moved.content_hash(), efl_mm=float(paraxial_data(moved).efl_mm),
                     closest_focus_mm=entry.closest_focus_mm)


def preset_names() -> list[str]:
    return sorted(p.stem for p in PRESETS_DIR.glob("*.toml"))


def library_path(lens_id: str, user_lenses_dir) -> str:
    """The file of a library identifier. Raises LensError for an unknown identifier."""
    lens_id = str(lens_id)
    if lens_id.startswith(USER_PREFIX):
        name, folder = lens_id[len(USER_PREFIX):], Path(user_lenses_dir)
    else:
        name, folder = lens_id + ".toml", PRESETS_DIR
    if not name or "/" in name or "\\" in name or name in (".", ".."):
        raise LensError(f"'{lens_id}' is not a lens of the library")
    path = folder / name
    if not (path.is_file() or (name.endswith(MODEL_SUFFIX) and path.is_dir())):
        where = ("your lens folder " + str(folder) if lens_id.startswith(USER_PREFIX)
                 else "the shipped presets")
        raise LensError(f"lens '{lens_id}' is not in {where} (was it renamed or removed?)")
    return str(path)


def resolve_lens_path(name_or_path: str) -> Path:
    """A preset name or a lens-file path -> the file; LensError when neither exists."""
    s = str(name_or_path).strip()
    if not s:
        raise LensError("no lens given: expected a preset name or a .toml / .dat / .zmx path")
    p = Path(s).expanduser()
    if p.is_file() or (p.is_dir() and p.name.endswith(MODEL_SUFFIX)):
        return p
    preset = PRESETS_DIR / (s if s.endswith(".toml") else s + ".toml")
    if preset.is_file():
        return preset
    raise LensError(f"lens '{s}' not found: expected a preset name "
                    f"({', '.join(preset_names())}) or the path of a lens file")


def preset_id(path) -> str | None:
    """The library identifier of a lens file when it is a shipped preset, else None."""
    path = Path(path)
    return path.stem if path.suffix == ".toml" and \
        path.resolve().parent == PRESETS_DIR.resolve() else None


def preset_model_dir(lens_id: str | None) -> Path | None:
    """The shipped model directory of a preset (None for a user's lens)."""
    if not lens_id or lens_id.startswith(USER_PREFIX):
        return None
    return PRESET_MODELS_DIR / f"{lens_id}.neurolens"


def _file_hash(path: str) -> str:
    from ..core.errors import LensError
    from ..core.lensfile import MAX_FILE_BYTES
    from ..core.safe_io import UnreadableFile, read_regular
    try:
        data = read_regular(path, MAX_FILE_BYTES, "lens file")
    except UnreadableFile as exc:
        raise LensError(exc.reason, path=exc.path) from None
    return hashlib.sha256(data).hexdigest()[:16]


def load_lens_entry(path) -> LensEntry:
    """Load (or fetch from the cache) the lens file at `path`.

    Raises LensError naming the file for a missing, unreadable or malformed file.
    """
    if path is None or str(path).strip() == "":
        raise LensError("no lens file chosen: pick a preset or load a .toml / .dat / .zmx lens file")
    p = os.path.realpath(os.fspath(path))
    try:
        st = os.stat(p)
    except OSError as exc:
        raise LensError(f"cannot read the lens file: {exc.strerror or exc}", path=str(path)) \
            from None
    if os.path.isdir(p) and p.endswith(MODEL_SUFFIX):
        return _table_entry(p)
    if not os.path.isfile(p):
        raise LensError("not a file: expected a .toml, .dat or .zmx lens file (or the "
                        f"{MODEL_SUFFIX} model of a lens known only from a ray table)",
                        path=str(path))
    key = (p, st.st_mtime_ns, st.st_size)
    digest = _BY_STAT.get_lru(key)
    if digest is None:
        try:
            digest = _file_hash(p)
        except OSError as exc:
            raise LensError(f"cannot read the lens file: {exc.strerror or exc}",
                            path=str(path)) from None
        _BY_STAT.put(key, digest)
    hkey = (digest, p)      # keyed by path too: a lens remembers its file (errors, names)
    entry = _BY_HASH.get_lru(hkey)
    if entry is not None:
        return entry
    from ..core.focus import closest_focus_mm
    from ..core.lensfile import load_lens
    from ..core.paraxial import paraxial_data

    stats["lens_reads"] += 1
    lens = load_lens(p)
    entry = LensEntry(lens=lens, path=p, file_hash=digest, content_hash=lens.content_hash(),
                      efl_mm=float(paraxial_data(lens).efl_mm),
                      closest_focus_mm=float(closest_focus_mm(lens)))
    return _BY_HASH.put(hkey, entry)


def _table_entry(directory: str) -> LensEntry:
    """The entry of a lens known only from a ray table: its model directory
    (camera.table_lens), cached by its model.json's stat; the figures are measured through the
    model."""
    from .table_lens import TABLE_PREFIX, TableLens
    meta = os.path.join(directory, "model.json")
    try:
        st = os.stat(meta)
    except OSError:
        raise LensError("not a lens file or a model directory with a model.json",
                        path=directory) from None
    key = (meta, st.st_mtime_ns, st.st_size)
    hit = _TABLES.get_lru(key)
    if hit is not None:
        return hit
    lens = TableLens(directory)
    entry = LensEntry(lens=lens, path=directory,
                      file_hash=lens.content_hash()[len(TABLE_PREFIX):],
                      content_hash=lens.content_hash(), efl_mm=lens.efl_mm,
                      closest_focus_mm=lens.focus_mm)
    return _TABLES.put(key, entry)
