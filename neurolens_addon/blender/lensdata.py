"""Lens data the Blender glue asks for on every redraw and frame, computed once and cached.

Pure Python + numpy (no bpy), so it is testable outside Blender. Everything is cached by
*content*, never by camera: two cameras showing the same lens file share the same immutable
`LensEntry`; different lenses can never see each other's numbers.

- `load_lens_entry(path)`: a lens file (TOML or pbrt .dat) read with core.lensfile, cached by
  the file's bytes (sha256). A stat() per call decides whether the file must be re-read.
- `focus_sensor_z_mm(entry, distance_mm, stop_radius_mm)`: core.focus.focus_sensor_z, cached by
  (lens content hash, distance, stop radius), so replaying keyframed focus is a dict look-up.
- `field_of_view_deg(entry, sensor_z_mm, half_extent_mm)`: the full angle the lens really
  images onto a sensor half-extent (exact trace; distortion and focus breathing included).
- `frame_size_mm(...)`: the film gate Blender's sensor settings give for a render aspect.
- `model_info(directory)` / `find_model(entry, candidates)`: learned models (model.json) that
  belong to a lens (their `lens.content_hash` must match).
- `onnxruntime_status()`: whether onnxruntime can be imported (learned lens), with a message.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import FocusError, LensError, ModelError
from ..core.prescription import Lens

#: The message shown when onnxruntime cannot be imported (the learned lens needs it).
ONNXRUNTIME_MISSING = "onnxruntime not available: learned lens disabled; exact and thin work"

_LOCK = threading.RLock()


class _Bounded(OrderedDict):
    """A small LRU dict: the oldest entries go once `maxsize` is exceeded."""

    def __init__(self, maxsize: int):
        super().__init__()
        self.maxsize = maxsize

    def get_lru(self, key):
        with _LOCK:
            if key in self:
                self.move_to_end(key)
                return self[key]
        return None

    def put(self, key, value):
        with _LOCK:
            self[key] = value
            self.move_to_end(key)
            while len(self) > self.maxsize:
                self.popitem(last=False)
        return value


_BY_STAT = _Bounded(256)      # (realpath, mtime_ns, size) -> file hash
_BY_HASH = _Bounded(128)      # file hash (+ path for errors/names) -> LensEntry
_FOCUS = _Bounded(4096)       # (content hash, distance, stop radius) -> sensor z
_FOV = _Bounded(1024)         # (content hash, sensor z, extents) -> degrees
_HEIGHTS = _Bounded(256)      # (content hash, sensor z) -> (angles, image heights)
_MODELS = _Bounded(256)       # (model.json path, mtime_ns, size) -> ModelInfo
_ORT: list = []               # [(available, message)] once probed

#: statistics, for tests and for anyone profiling the panel
stats = {"lens_reads": 0, "focus_solves": 0, "fov_traces": 0, "model_reads": 0}


def clear_caches() -> None:
    """Forget every cached lens, focus, field of view and model (e.g. on unregister)."""
    with _LOCK:
        for cache in (_BY_STAT, _BY_HASH, _FOCUS, _FOV, _HEIGHTS, _MODELS):
            cache.clear()
        _ORT.clear()
        for key in stats:
            stats[key] = 0


# =============================================================================================
# lenses
# =============================================================================================
@dataclass(frozen=True)
class LensEntry:
    """A loaded lens with the figures the panel shows. Immutable and shared by content."""

    lens: Lens
    path: str
    file_hash: str          # sha256 of the file's bytes (first 16 hex digits)
    content_hash: str       # Lens.content_hash(): what changes the rays
    efl_mm: float           # paraxial effective focal length at the d line
    f_number: float         # the designer's stated f-number (the widest the lens opens)
    closest_focus_mm: float  # from the sensor
    sensor_z_infinity_mm: float | None = None

    @property
    def name(self) -> str:
        return self.lens.name

    @property
    def focal_length_mm(self) -> float:
        """The designer's stated focal length."""
        return float(self.lens.focal_length_mm)


def _file_hash(path: str) -> str:
    from ..core.lensfile import MAX_FILE_BYTES
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read(MAX_FILE_BYTES + 1))
    return h.hexdigest()[:16]


def load_lens_entry(path) -> LensEntry:
    """Load (or fetch from the cache) the lens file at `path`.

    Raises LensError naming the file for a missing, unreadable or malformed file.
    """
    if path is None or str(path).strip() == "":
        raise LensError("no lens file chosen: pick a preset or load a .toml / .dat lens file")
    p = os.path.realpath(os.fspath(path))
    try:
        st = os.stat(p)
    except OSError as exc:
        raise LensError(f"cannot read the lens file: {exc.strerror or exc}", path=str(path)) \
            from None
    if not os.path.isfile(p):
        raise LensError("not a file: expected a .toml or .dat lens file", path=str(path))
    key = (p, st.st_mtime_ns, st.st_size)
    digest = _BY_STAT.get_lru(key)
    if digest is None:
        try:
            digest = _file_hash(p)
        except OSError as exc:
            raise LensError(f"cannot read the lens file: {exc.strerror or exc}",
                            path=str(path)) from None
        _BY_STAT.put(key, digest)
    # keyed by path too: a lens remembers its file (error messages, names)
    hkey = (digest, p)
    entry = _BY_HASH.get_lru(hkey)
    if entry is not None:
        return entry
    from ..core.focus import closest_focus_mm
    from ..core.lensfile import load_lens
    from ..core.paraxial import paraxial_data

    stats["lens_reads"] += 1
    lens = load_lens(p)
    pd = paraxial_data(lens)
    entry = LensEntry(lens=lens, path=p, file_hash=digest, content_hash=lens.content_hash(),
                      efl_mm=float(pd.efl_mm), f_number=float(lens.f_number),
                      closest_focus_mm=float(closest_focus_mm(lens)))
    return _BY_HASH.put(hkey, entry)


# =============================================================================================
# focus
# =============================================================================================
def focus_sensor_z_mm(entry: LensEntry, distance_mm: float, stop_radius_mm: float) -> float:
    """The exact sensor position focusing `distance_mm` (from the sensor; inf allowed).

    Raises FocusError nearer than the closest focus (callers clamp first).
    """
    from ..core.focus import focus_sensor_z

    d = float(distance_mm)
    key = (entry.content_hash, "inf" if math.isinf(d) else round(d, 6),
           round(float(stop_radius_mm), 9))
    z = _FOCUS.get_lru(key)
    if z is None:
        stats["focus_solves"] += 1
        z = float(focus_sensor_z(entry.lens, d, stop_radius=float(stop_radius_mm)))
        _FOCUS.put(key, z)
    return z


def clamp_focus_mm(entry: LensEntry, distance_mm: float) -> tuple[float, str | None]:
    """(usable distance, message or None): nearer than the closest focus is refused and the
    closest focus used instead. Non-positive distances are refused the same way."""
    d = float(distance_mm)
    near = entry.closest_focus_mm
    if math.isnan(d) or d < near * (1.0 - 1e-9):
        asked = "nothing" if math.isnan(d) else f"{d / 1000.0:.3f} m"
        return near, (f"'{entry.name}' focuses no closer than {near / 1000.0:.3f} m: "
                      f"focus at {asked} refused, focusing at {near / 1000.0:.3f} m")
    return d, None


# =============================================================================================
# field of view
# =============================================================================================
def frame_size_mm(sensor_width: float, sensor_height: float, sensor_fit: str,
                  aspect_x: float, aspect_y: float) -> tuple[float, float]:
    """(width, height) of the film gate in mm, as Blender maps its sensor onto the frame.

    aspect_x / aspect_y: the render size times the pixel aspect (only their ratio matters).
    AUTO: sensor_width spans the longer side; HORIZONTAL: the width; VERTICAL: sensor_height
    spans the height.
    """
    ax, ay = float(aspect_x), float(aspect_y)
    if not (ax > 0.0 and ay > 0.0):
        raise ValueError(f"render aspect must be positive, got {ax:g} x {ay:g}")
    fit = str(sensor_fit).upper()
    if fit == "VERTICAL":
        h = float(sensor_height)
        return h * ax / ay, h
    if fit == "HORIZONTAL" or ax >= ay:
        w = float(sensor_width)
        return w, w * ay / ax
    h = float(sensor_width)
    return h * ax / ay, h


_FOV_ANGLES = 33
_FOV_BEAM = 144


def _image_heights(entry: LensEntry, sensor_z_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Image height (centroid of a parallel beam on the sensor) for field angles up to the
    lens's coverage; NaN where the whole beam is vignetted. One batched exact trace."""
    key = (entry.content_hash, round(float(sensor_z_mm), 6))
    hit = _HEIGHTS.get_lru(key)
    if hit is not None:
        return hit
    from ..core.field import field_beam, half_field_deg
    from ..core.rays import Rays
    from ..core.trace import trace

    stats["fov_traces"] += 1
    top = min(89.0, 2.0 * half_field_deg(entry.lens) + 5.0)
    angles = np.linspace(0.0, top, _FOV_ANGLES)
    beams = [field_beam(entry.lens, float(a), _FOV_BEAM, two_d=False) for a in angles]
    sizes = [b.n for b in beams]
    rays = Rays(np.concatenate([b.o for b in beams], axis=1),
                np.concatenate([b.d for b in beams], axis=1),
                np.concatenate([b.wavelength for b in beams]))
    res = trace(entry.lens, rays, from_sensor=False, sensor_z=float(sensor_z_mm), threads=1)
    heights = np.full(angles.size, np.nan)
    start = 0
    for k, n in enumerate(sizes):
        v = res.valid[start:start + n]
        if v.any():
            heights[k] = abs(float(res.rays.o[1, start:start + n][v].mean()))
        start += n
    heights[0] = 0.0
    return _HEIGHTS.put(key, (angles, heights))


def image_circle_mm(entry: LensEntry, sensor_z_mm: float) -> float:
    """Diameter of the image circle: twice the largest image height reached before the beam
    is vignetted away (or the image height turns back)."""
    angles, heights = _image_heights(entry, sensor_z_mm)
    best = 0.0
    for k in range(1, angles.size):
        if not math.isfinite(heights[k]) or heights[k] < heights[k - 1]:
            break
        best = float(heights[k])
    return 2.0 * best


def field_of_view_deg(entry: LensEntry, sensor_z_mm: float, half_extent_mm: float) -> float | None:
    """Full angle (degrees) between the scene directions imaged at -half_extent and
    +half_extent on the sensor, by the exact lens focused with its sensor at `sensor_z_mm`.

    None when the extent reaches beyond the lens's image circle (vignetted corners).
    """
    half = float(half_extent_mm)
    if not half > 0.0:
        return 0.0
    key = (entry.content_hash, round(float(sensor_z_mm), 6), round(half, 6))
    hit = _FOV.get_lru(key)
    if hit is not None:
        return None if hit < 0 else hit
    angles, heights = _image_heights(entry, sensor_z_mm)
    result = -1.0
    for k in range(1, angles.size):
        h0, h1 = heights[k - 1], heights[k]
        if not math.isfinite(h1) or h1 < h0:
            break           # vignetted, or the image height turns back: the coverage ends
        if h1 >= half:
            t = (half - h0) / (h1 - h0) if h1 > h0 else 0.0
            result = 2.0 * float(angles[k - 1] + t * (angles[k] - angles[k - 1]))
            break
    _FOV.put(key, result)
    return None if result < 0 else result


# =============================================================================================
# learned models
# =============================================================================================
@dataclass(frozen=True)
class ModelInfo:
    """What the glue needs from a model.json without loading its graphs."""

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
        lens = meta["lens"]
        domain = meta["domain"]
        zr = domain["sensor_z_range"]
        info = ModelInfo(directory=str(Path(directory)),
                         lens_content_hash=str(lens["content_hash"]),
                         dispersion=bool(domain.get("dispersion", False)),
                         sensor_z_range=(float(zr[0]), float(zr[1])),
                         film_radius_mm=float(domain["film_radius_mm"]))
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise ModelError(f"not a readable NeuroLens model.json ({exc.__class__.__name__}: "
                         f"{exc})", path=str(path)) from None
    return _MODELS.put(key, info)


def find_model(entry: LensEntry, candidates) -> ModelInfo | None:
    """The first model directory among `candidates` (directories that may not exist, or
    folders holding `*.neurolens` directories) trained for this very lens (content hash)."""
    for cand in candidates:
        if cand is None:
            continue
        cand = Path(cand)
        dirs = [cand] if (cand / "model.json").is_file() else (
            sorted(cand.glob("*.neurolens")) if cand.is_dir() else [])
        for d in dirs:
            try:
                info = model_info(d)
            except ModelError:
                continue
            if info.lens_content_hash == entry.content_hash:
                return info
    return None


def onnxruntime_status() -> tuple[bool, str]:
    """(available, message): whether `import onnxruntime` works here (probed once)."""
    if not _ORT:
        try:
            import onnxruntime
            _ORT.append((True, f"onnxruntime {getattr(onnxruntime, '__version__', '?')}"))
        except Exception as exc:  # noqa: BLE001 - ImportError, or a broken native library
            _ORT.append((False, f"{ONNXRUNTIME_MISSING} ({exc.__class__.__name__}: {exc})"))
    return _ORT[0]


__all__ = [
    "ONNXRUNTIME_MISSING",
    "FocusError",
    "LensEntry",
    "ModelInfo",
    "clamp_focus_mm",
    "clear_caches",
    "field_of_view_deg",
    "find_model",
    "focus_sensor_z_mm",
    "frame_size_mm",
    "image_circle_mm",
    "load_lens_entry",
    "model_info",
    "onnxruntime_status",
    "stats",
]
