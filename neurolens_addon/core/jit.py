"""Compiled kernels (numba), when they can be had: the switch, and where their cache lives.

numba compiles a kernel at its first call (seconds); with `cache=True` it writes the machine
code to a cache folder and later processes load it from there (a fraction of a second). That
folder is the user's, never the add-on's (which Blender may replace on update and which may be
read-only):
    NUMBA_CACHE_DIR where the user set it; else NEUROLENS_CACHE_DIR/numba; else the
    platform's user cache + neurolens/numba: $XDG_CACHE_HOME (default ~/.cache) on Linux,
    ~/Library/Caches on macOS, %LOCALAPPDATA% on Windows (in Blender as anywhere else).
numba reads its cache folder when a kernel is decorated (its cache locator), so the folder is
set in numba's config before this module decorates anything.
numba keys a cached kernel by its own file's time stamp only, not by the functions and
constants it compiled in from other files; so the kernels live in a subfolder named by a
digest of every file they compile code or constants from (KERNEL_SOURCES): a changed
dependency gets a fresh folder (and a compile), never a stale kernel.

Which trace runs (core.trace): NEUROLENS_KERNELS = "numpy" forces the numpy reference,
"compiled" asks for numba (an error where it is absent), "auto" (the default) uses numba where
it imports. Blender builds without numba (e.g. a Python numba has no wheel for yet) take the
numpy path.

Without numba, `njit` leaves a function as plain Python and `prange_or_range()` gives `range`,
so the kernel modules import (and mean the same) everywhere.

numba's default threading layer (workqueue where neither TBB nor OpenMP is present) must not
run two parallel kernels at once from two Python threads; `KERNEL_LOCK` serialises the calls
(each already uses every core).
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

MODES = ("auto", "numpy", "compiled")
KERNEL_LOCK = threading.Lock()
#: the files (relative to core/) whose code or constants the compiled kernels hold
KERNEL_SOURCES = ("jit.py", "trace_compiled.py", "coatings_kernels.py", "rays.py",
                  "surfaces/kernels.py",
                  "surfaces/base.py", "surfaces/asphere.py", "surfaces/anamorphic.py",
                  "../engine/shading_kernels.py", "../engine/light_kernels.py",
                  "../engine/mesh_kernels.py", "../engine/film_kernels.py",
                  "../engine/stage_kernels.py", "../engine/camera_kernels.py")

_state: dict = {}


def default_cache_dir() -> Path:
    """The platform's per-user cache folder for the kernels (module docstring)."""
    own = os.environ.get("NEUROLENS_CACHE_DIR")
    if own:
        return Path(own) / "numba"
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "neurolens" / "numba"


def cache_dir() -> Path:
    """The folder the kernels' cache lives in (numba's own is its sources_digest() subfolder)."""
    if "folder" in _state:
        return _state["folder"].parent
    user = os.environ.get("NUMBA_CACHE_DIR")
    return Path(user) if user else default_cache_dir()


def sources_digest() -> str:
    """A short digest of KERNEL_SOURCES (the kernels' cache subfolder)."""
    import hashlib
    h = hashlib.sha256()
    core = Path(__file__).resolve().parent
    for name in KERNEL_SOURCES:
        h.update(name.encode())
        h.update((core / name).read_bytes())
    return h.hexdigest()[:16]


def numba():
    """The numba module with its cache folder set (cache_dir() / sources_digest()), or None
    where it does not import."""
    if "numba" not in _state:
        folder = cache_dir() / sources_digest()
        _state["folder"] = folder
        try:
            import numba as nb
        except Exception:  # noqa: BLE001 - any failure to import means: no compiled kernels
            nb = None
        if nb is not None:
            # numba's config, not the environment: a child process (the trainer) must not
            # read our subfolder as a folder its user chose
            nb.config.CACHE_DIR = str(folder)
        _state["numba"] = nb
    return _state["numba"]


def available() -> bool:
    return numba() is not None


def mode(requested: str | None = None) -> str:
    """"numpy" or "compiled": the trace to run for `requested` (None: NEUROLENS_KERNELS, else
    "auto")."""
    want = (requested or os.environ.get("NEUROLENS_KERNELS") or "auto").strip().lower()
    if want not in MODES:
        raise ValueError(f"kernels must be one of {', '.join(MODES)}, got {want!r}")
    if want == "numpy":
        return "numpy"
    if available():
        return "compiled"
    if want == "compiled":
        raise RuntimeError("compiled kernels were asked for (NEUROLENS_KERNELS or kernels="
                           "\"compiled\") but numba does not import here")
    return "numpy"


def njit(**options):
    """numba.njit(**options) where numba imports, else a decorator that changes nothing."""
    nb = numba()
    if nb is None:
        return lambda fn: fn
    return nb.njit(**options)


def prange_or_range():
    """numba.prange (the parallel loop numba recognises by identity) or, without numba, range:
    a kernel module binds it as its global `prange`."""
    nb = numba()
    return range if nb is None else nb.prange


def set_threads(n: int | None) -> int | None:
    """Limit this thread's compiled kernels to n threads (None: all); the previous count."""
    nb = numba()
    if nb is None:
        return None
    before = nb.get_num_threads()
    nb.set_num_threads(max(1, min(int(n), nb.config.NUMBA_NUM_THREADS)) if n else
                       nb.config.NUMBA_NUM_THREADS)
    return before
