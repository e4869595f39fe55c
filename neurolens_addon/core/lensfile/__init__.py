"""Lens files: our TOML prescription format (read and write) and pbrt-v3/v4 `.dat` lens files.

Public API
- `load_lens(path)`: read a `.toml` (our format) or `.dat` (pbrt RealisticCamera) file.
- `loads_lens(text, path=None)`: parse our TOML format from a string (toml_reader).
- `dump_lens(lens)`: TOML text that `loads_lens` turns back into an equal `Lens` (toml_writer).
- `load_pbrt_dat(path)` / `loads_pbrt_dat(text, path=None)`: import a pbrt lens file (pbrt).
- `load_zmx(path)` / `loads_zmx(text, path=None)` / `dump_zmx(lens)`: Zemax sequential `.zmx`
  files, import and export (zemax); `loads_zmx_system(text)`: a `.zmx` text's glass
  catalogues, fields, wavelengths and entrance pupil (zemax_system).
- `validate_lens(lens, path=None)`: the value checks every loaded lens passes (usable on a
  `Lens` built in code) (checks).

The format, its conventions and every validation rule are documented in `docs/lens-format.md`.
Every problem raises `LensError` (and only that: a hostile file costs its reader one clear
line, never another exception or a hang) naming the file, the 1-based surface number and the
field (core.lensfields). Every reader is bounded before it allocates: file size and surface
count (source), table positions (core.variable_gaps.MAX_POSITIONS), .zmx configurations and
NOTE nesting (zemax_configs, zemax), integer digits and control characters in line-based
files (tokens). Each surface kind reads, checks and writes its own keys (core.surfaces).
Pure Python + numpy; never imports bpy.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import LensError
from ..prescription import Lens
from .checks import OVERLAP_TOLERANCE_MM, validate_lens
from .pbrt import load_pbrt_dat, loads_pbrt_dat
from .source import MAX_FILE_BYTES, MAX_SURFACES, read_text
from .toml_reader import loads_lens
from .toml_writer import dump_lens
from .zemax import dump_zmx, load_zmx, loads_zmx, loads_zmx_system

__all__ = [
    "MAX_FILE_BYTES", "MAX_SURFACES", "OVERLAP_TOLERANCE_MM",
    "load_lens", "loads_lens", "dump_lens", "load_pbrt_dat", "loads_pbrt_dat", "validate_lens",
    "load_zmx", "loads_zmx", "loads_zmx_system", "dump_zmx",
]


def load_lens(path) -> Lens:
    """Load a lens file: `.toml` is our format, `.dat` a pbrt RealisticCamera lens file,
    `.zmx` a Zemax sequential file."""
    suffix = Path(path).suffix.lower()
    if suffix == ".toml":
        return loads_lens(read_text(path), path=str(path))
    if suffix == ".dat":
        return load_pbrt_dat(path)
    if suffix == ".zmx":
        return load_zmx(path)
    raise LensError(f"unknown lens file extension '{suffix}': expected .toml (NeuroLens "
                    "prescription), .dat (pbrt lens file) or .zmx (Zemax)", path=str(path))
