"""The learned-lens model file, in one place: its names, its skip and occupancy layouts, its
checked readers and the discovery of model directories. No onnxruntime, torch or bpy.

A model is a directory `NAME.neurolens/` holding model.json (schema below, every number
float64) and the ONNX graphs forward.onnx, forward_jacobian.onnx and, in models written since
it exists, forward_fast.onnx (written by onnx_export; semantics in neural.reference;
inputs and outputs in GRAPH_IO). model.json keys:
  format "neurolens-model", version 1, lens {name, content_hash},
  [frame "radial" | "cartesian"] (core.irf; absent: radial, as every model written before it;
   cartesian when any stage is),
  planes {input_z, stop_z, output_z[, stop_radius_mm (null: no stop, a ray-table model)]},
  domain {film_radius_mm, sensor_z_range, wavelength_range_nm, dispersion
          [, stop_radius_mm, film_radius_min_mm]},
  stages [rear, front] each {name[, frame (absent: the model's)], propagate: true} (no
         surfaces: exact free flight) or
         {name[, frame], bounds {lo, hi} (d_in), occupancy {lo, hi, shape, bits} (one axis per base
          column of the frame: 3 radial, 4 cartesian), tree,
          cells [{x_norm {mean, scale[, wavelength_ref_nm][, w_residual_column]},
                  y_norm {mean, scale},
                  members [{W1, b1, W2, b2, W3, b3, L, skip_degree or skip_terms}]}]},
  ensemble_size, theta, skip_degree, files {filename: sha256 hex} (forward_fast.onnx optional),
  [evaluation {image_error_um_p99, onnx_rays_per_s, ...}] (`trainer evaluate --record`),
  [costs {neurolens, cycles: {exact_us, learned_us, date, machine, ...}}]: what a camera ray
   costs per renderer through the exact trace and through the model, measured in one run on
   one machine (`trainer cost --record`).
Unknown keys are ignored. d_in: radial 5 with dispersion (r, u_r, u_t, w, lambda), else 4;
cartesian 6 (x, y, u, v, w, lambda), else 5. A model whose stage is radial where the lens's
group holds an anamorphic surface is refused (the frame assumes rotational symmetry); a
cartesian stage fits any group.
A member's skip phi(x) lists its skip_terms, else monomial_terms(d_in, skip_degree); L has one
column per monomial in that order. Occupancy bits: np.packbits of the C-order grid, base64.

Readers (both raise core.errors.ModelError naming the file and the field):
  read_header(directory): the few checked fields that decide whether and which model to use,
    cached by model.json's (path, mtime_ns, size);
  read_model_json(directory, lens=None): everything checked, with each stage's domain guard.
Discovery: model_dirs(candidates) lists the models among model directories and folders of
`*.neurolens` directories; find_model(lens_hash, candidates) is the most accurate made for a
lens.
"""

from __future__ import annotations

import base64
import functools
import itertools
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np

from ..core.errors import ModelError
from ..core.irf import FRAMES, RADIAL, StageFrame, stage_frames
from .schema import Checker, check_stage

#: the renderers a model's costs are measured for: the NEUROLENS engine and Cycles
RENDERERS = ("neurolens", "cycles")
#: the least cost a ray can be recorded with (us): a measured zero is a failed measurement
MIN_COST_US = 1e-4

FORMAT = "neurolens-model"
VERSION = 1
MODEL_SUFFIX = ".neurolens"
MODEL_FILE = "model.json"
FORWARD_FILE = "forward.onnx"
JACOBIAN_FILE = "forward_jacobian.onnx"
FAST_FILE = "forward_fast.onnx"
#: model.json and graph files larger than these are refused before reading (core.safe_io)
MAX_MODEL_JSON_BYTES = 64 << 20
MAX_GRAPH_BYTES = 256 << 20
# |d|^2 whose float32 normalisation in forward_fast.onnx is exact to rounding; the runtime
# redoes the flight in float64 for rays outside it
N2_RANGE = (1e-30, 1e30)

# graph file -> (inputs, outputs), each [(name, element type, shape)]; "N", "M" are dynamic
GRAPH_IO = {
    FORWARD_FILE: ([("rays", "float", ["N", 6])],
                   [("stop_rays", "float", ["N", 5]), ("out_rays", "float", ["N", 5]),
                    ("spread", "float", ["N", 2])]),
    JACOBIAN_FILE: ([("rays", "float", ["N", 6])],
                    [("stop_rays", "float", ["N", 5]), ("out_rays", "float", ["N", 5]),
                     ("spread", "float", ["N", 2]), ("jacobian", "float", ["N", 4, 4])]),
    FAST_FILE: ([("rays", "float", [6, "N"]), ("sensor_z", "float", ["M"]),
                 ("stop_r2", "double", [1])],
                [("stop_xy", "float", [2, "N"]), ("out_rays", "float", [5, "N"]),
                 ("in_domain", "uint8", ["N"]), ("status", "uint8", ["N"])]),
}


# ---------------------------------------------------------------- layouts

def monomial_terms(d_in: int, degree: int) -> list[tuple[int, ...]]:
    """Every monomial of degree 1..degree as a non-decreasing index tuple ((2, 2, 4) =
    x_2^2 x_4), degree by degree: the skip columns of a member with skip_degree = degree."""
    out = []
    for deg in range(1, degree + 1):
        out.extend(itertools.combinations_with_replacement(range(d_in), deg))
    return out


def member_terms(net: dict, d_in: int) -> list[tuple[int, ...]]:
    """The monomials of a member's skip: its "skip_terms", else all of degree 1..skip_degree."""
    terms = net.get("skip_terms")
    if terms is None:
        return monomial_terms(d_in, int(net.get("skip_degree", 1)))
    return [tuple(int(i) for i in t) for t in terms]


def encode_occupancy(grid: np.ndarray, lo, hi) -> dict:
    """A stage's occupancy entry for a boolean grid over the frame's base columns ((r, u_r,
    u_t) or (x, y, u, v)) in [lo, hi]."""
    return {"lo": [float(v) for v in lo], "hi": [float(v) for v in hi],
            "shape": list(grid.shape),
            "bits": base64.b64encode(np.packbits(grid.ravel())).decode("ascii")}


def occupancy_bytes(occ: dict) -> np.ndarray:
    """The packed grid bytes of an occupancy entry (bit j is bit 7 - j % 8 of byte j // 8)."""
    return np.frombuffer(base64.b64decode(occ["bits"]), dtype=np.uint8)


def decode_occupancy(occ: dict) -> np.ndarray:
    """The boolean grid of an occupancy entry (read_model_json checks it)."""
    return _unpack(occupancy_bytes(occ), [int(s) for s in occ["shape"]])


def _unpack(raw: np.ndarray, shape) -> np.ndarray:
    return np.unpackbits(raw)[:int(np.prod(shape))].astype(bool).reshape(shape)


# ---------------------------------------------------------------- checks

def _check_frame(ck: Checker, meta, default: str = RADIAL.name,
                 where: str = "frame") -> StageFrame:
    """The frame a model.json object (the model, or a stage) names (absent: `default`)."""
    name = meta.get("frame", default)
    if not isinstance(name, str) or name not in FRAMES:
        ck.fail(where, f"expected one of {', '.join(repr(f) for f in FRAMES)}, "
                       f"got {name!r:.40}")
    return FRAMES[name]


def _check_head(ck: Checker, meta) -> dict:
    """Check format, version, lens, frame, domain and evaluation (all read_header reads); the
    domain."""
    if not isinstance(meta, dict):
        ck.fail(None, "expected a JSON object")
    fmt = meta.get("format")
    if fmt != FORMAT:
        ck.fail("format", f"expected '{FORMAT}', got {fmt!r}: not a NeuroLens model")
    ver = meta.get("version")
    if ver != VERSION:
        ck.fail("version", f"version {ver!r} is not supported (this add-on reads {VERSION})")
    lens = ck.get(meta, "lens", "", "dict")
    ck.get(lens, "name", "lens", "str")
    ck.get(lens, "content_hash", "lens", "str")
    _check_frame(ck, meta)
    dom = ck.get(meta, "domain", "", "dict")
    ck.number(dom, "film_radius_mm", "domain", 1e-3, 1e3, " mm")
    zs = ck.array(ck.get(dom, "sensor_z_range", "domain"), "domain.sensor_z_range", (2,))
    if not (zs[0] <= zs[1] and np.abs(zs).max() <= 1e4):
        ck.fail("domain.sensor_z_range", f"{zs.tolist()} is not an increasing range of mm")
    wl = ck.array(ck.get(dom, "wavelength_range_nm", "domain"), "domain.wavelength_range_nm",
                  (2,))
    if wl[0] > wl[1] or wl[0] < 200.0 or wl[1] > 2000.0:
        ck.fail("domain.wavelength_range_nm", f"{wl.tolist()} is not an increasing range "
                                              "within 200-2000 nm")
    ck.get(dom, "dispersion", "domain", "bool")
    for key in ("stop_radius_mm", "film_radius_min_mm"):
        if key in dom:
            v = ck.get(dom, key, "domain", "num")
            if not (math.isfinite(v) and v >= 0 and (v > 0 or key != "stop_radius_mm")):
                ck.fail("domain." + key, f"expected a finite positive number of mm, got {v!r}")
    ev = meta.get("evaluation")
    if ev is not None:
        ck.get(meta, "evaluation", "", "dict")
        for key, hi in (("image_error_um_p99", 1e9), ("onnx_rays_per_s", 1e13)):
            if ev.get(key) is not None:
                ck.number(ev, key, "evaluation", 0.0, hi)
    costs = meta.get("costs")
    if costs is not None:
        ck.get(meta, "costs", "", "dict")
        for renderer in RENDERERS:
            if costs.get(renderer) is not None:
                c = ck.get(costs, renderer, "costs", "dict")
                for key in ("exact_us", "learned_us"):
                    ck.number(c, key, f"costs.{renderer}", MIN_COST_US, 1e6, " us")
                for key in ("date", "machine"):
                    if key in c:
                        ck.get(c, key, f"costs.{renderer}", "str")
    return dom


def _check_meta(ck: Checker, meta, dom: dict) -> tuple[list, dict]:
    """Every field read_model_json promises beyond the head (_check_head, whose domain is
    `dom`): (stage guards, files)."""
    planes = ck.get(meta, "planes", "", "dict")
    for k in ("input_z", "stop_z", "output_z"):
        ck.number(planes, k, "planes", -1e4, 1e4, " mm")
    if planes.get("stop_radius_mm") is not None:       # null: no stop (a ray-table model)
        r = ck.get(planes, "stop_radius_mm", "planes", "num")
        if not r > 0:
            ck.fail("planes.stop_radius_mm", f"must be > 0, got {r}")
    for k, lo, hi in (("ensemble_size", 1, 64), ("theta", 1, 4096), ("skip_degree", 0, 8)):
        ck.integer(meta, k, "", lo, hi)
    stages = ck.get(meta, "stages", "", "list")
    if len(stages) != 2:
        ck.fail("stages", f"expected 2 stages (rear, front), got {len(stages)}")
    default = _check_frame(ck, meta).name
    guards, frames = [], []
    for k, st in enumerate(stages):
        frame = _check_frame(ck, st if isinstance(st, dict) else {}, default,
                             f"stages[{k}].frame")
        frames.append(frame)
        guards.append(check_stage(ck, st, k, frame.d_in(dom["dispersion"]), frame))
    # the model's frame (what read_header reports without reading the stages) is cartesian
    # exactly when a stage is
    whole = "cartesian" if any(not f.rotates for f in frames) else RADIAL.name
    if default != whole:
        ck.fail("frame", f"{default!r}, but its stages are {[f.name for f in frames]}: the "
                         f"model's frame must be {whole!r}")
    files = ck.get(meta, "files", "", "dict")
    for f in (FORWARD_FILE, JACOBIAN_FILE) + ((FAST_FILE,) if FAST_FILE in files else ()):
        h = ck.get(files, f, "files", "str")
        if len(h) != 64 or any(ch not in "0123456789abcdef" for ch in h.lower()):
            ck.fail(f"files.{f}", f"expected a sha256 hex digest, got {h!r:.70}")
    return guards, files


# ---------------------------------------------------------------- readers

def _locate(directory) -> tuple[Path, Path]:
    """(model directory, its model.json) for a model directory or its model.json."""
    directory = Path(directory)
    if directory.name == MODEL_FILE and directory.is_file():
        directory = directory.parent
    return directory, directory / MODEL_FILE


class _NonFinite(ValueError):
    """NaN, Infinity or -Infinity in a JSON file (Python's reader would accept them)."""


def _no_constant(name: str):
    raise _NonFinite(name)


def _load(path: Path):
    from ..core.safe_io import UnreadableFile, read_regular
    try:
        text = read_regular(path, MAX_MODEL_JSON_BYTES, MODEL_FILE).decode("utf-8")
        return json.loads(text, parse_constant=_no_constant)
    except RecursionError:
        raise ModelError("nested too deeply to be a NeuroLens model", path=str(path)) from None
    except _NonFinite as e:
        raise ModelError(f"'{e}' is not a number JSON allows (NaN and Infinity are refused)",
                         path=str(path)) from None
    except json.JSONDecodeError as e:
        raise ModelError(f"not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})",
                         path=str(path)) from None
    except UnreadableFile as e:
        raise ModelError(e.reason, path=str(path)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ModelError(f"cannot read: {e}", path=str(path)) from None
    except ValueError:      # (after the two above: an integer of over 4300 digits)
        raise ModelError("not valid here: an integer of more than 4300 digits",
                         path=str(path)) from None


def read_model_json(directory, lens=None):
    """(directory, meta, stage guards, files) of a model directory (or its model.json),
    schema-checked, and refused when `lens` is given and the model was trained for another
    prescription or its frame cannot represent it (check_frame_fits). Reads only model.json:
    needs neither onnxruntime nor the graphs."""
    directory, path = _locate(directory)
    if not os.path.lexists(path):
        raise ModelError(f"no {MODEL_FILE} in the model directory", path=str(directory))
    meta = _load(path)
    ck = Checker(path)
    dom = _check_head(ck, meta)
    if lens is not None:        # which lens, and whether the frame can hold it, say most
        want, have = meta["lens"]["content_hash"], lens.content_hash()
        if want != have:
            raise ModelError(
                f"model '{directory.name}' was trained for lens '{meta['lens']['name']}' "
                f"(hash {want}), not '{lens.name}' (hash {have})", path=str(path),
                field="lens.content_hash")
        check_frame_fits(meta, lens, path)
    guards, files = _check_meta(ck, meta, dom)
    return directory, meta, guards, files


def check_frame_fits(meta: dict, lens, path) -> None:
    """ModelError unless each stage's frame can represent its group of `lens`: the radial
    frame assumes rotational symmetry, which a group with an anamorphic surface breaks."""
    if not getattr(lens, "anamorphic", False):
        return
    default = meta.get("frame", RADIAL.name)
    stages = meta.get("stages") if isinstance(meta.get("stages"), list) else []
    for k, (needed, group) in enumerate(zip(stage_frames(lens), ("rear", "front"))):
        st = stages[k] if k < len(stages) and isinstance(stages[k], dict) else {}
        name = st.get("frame", default)
        if name == RADIAL.name and needed is not RADIAL:
            raise ModelError(
                f"a {name} stage (rotational symmetry) cannot represent the {group} group of "
                f"the anamorphic lens '{lens.name}': retrain it (the trainer learns such a "
                "group in the cartesian frame)", path=str(path),
                field=f"stages[{k}].frame" if "frame" in st else "frame")


@dataclass(frozen=True)
class ModelHeader:
    """What choosing a model needs from its model.json, without its weights or graphs."""

    directory: Path
    lens_name: str
    lens_content_hash: str
    dispersion: bool
    sensor_z_range: tuple[float, float]
    film_radius_mm: float
    wavelength_range_nm: tuple[float, float]
    domain: Mapping = field(hash=False)                     # model.json's domain, read-only
    evaluation: Mapping | None = field(default=None, hash=False)    # None: never evaluated
    frame: str = RADIAL.name                                # core.irf frame name
    costs: Mapping | None = field(default=None, hash=False)         # None: never measured

    @property
    def name(self) -> str:
        return self.directory.name

    @property
    def image_error_um_p99(self) -> float | None:
        """The recorded image error (99th percentile, um on the sensor); None: not measured."""
        v = (self.evaluation or {}).get("image_error_um_p99")
        return None if v is None else float(v)

    @property
    def onnx_rays_per_s(self) -> float | None:
        """The recorded speed of the whole learned lens; None: not measured."""
        v = (self.evaluation or {}).get("onnx_rays_per_s")
        return None if v is None else float(v)

    def ray_cost_us(self, renderer: str) -> tuple[float, float] | None:
        """(exact trace, this model) microseconds a camera ray in `renderer` (one of
        RENDERERS), measured in one run; None: not measured for that renderer."""
        c = (self.costs or {}).get(renderer)
        return None if c is None else (float(c["exact_us"]), float(c["learned_us"]))

    def costs_measured(self, renderer: str) -> str:
        """When and where the renderer's costs were measured, in words ("" when unknown)."""
        c = (self.costs or {}).get(renderer) or {}
        return ", ".join(str(c[k]) for k in ("date", "machine") if c.get(k))


def read_header(directory) -> ModelHeader:
    """The checked header of a model directory (or its model.json), cached by model.json's
    (path, mtime_ns, size): one stat per call once read. Raises ModelError."""
    directory, path = _locate(directory)
    try:
        st = os.stat(path)
    except OSError:
        raise ModelError(f"no {MODEL_FILE} in the model directory", path=str(directory)) from None
    return _cached_header(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=256)
def _cached_header(path: str, _mtime_ns: int, _size: int) -> ModelHeader:
    """The header of model.json at `path`; the stat figures only key the cache."""
    meta = _load(Path(path))
    dom = _check_head(Checker(Path(path)), meta)
    ev = meta.get("evaluation")
    costs = meta.get("costs")
    return ModelHeader(
        Path(path).parent, meta["lens"]["name"], meta["lens"]["content_hash"],
        dom["dispersion"], tuple(float(v) for v in dom["sensor_z_range"]),
        float(dom["film_radius_mm"]), tuple(float(v) for v in dom["wavelength_range_nm"]),
        MappingProxyType(dict(dom)), None if ev is None else MappingProxyType(dict(ev)),
        meta.get("frame", RADIAL.name),
        None if costs is None else MappingProxyType(
            {k: MappingProxyType(dict(v)) if isinstance(v, dict) else v
             for k, v in costs.items()}))


def clear_header_cache() -> None:
    """Forget every header read (e.g. when the add-on unregisters)."""
    _cached_header.cache_clear()


# ---------------------------------------------------------------- discovery

def _walk(candidates):
    """(model directory, stat key) of each model among `candidates`, once, lazily."""
    seen = set()

    def stat_key(folder: str):
        try:
            st = os.stat(os.path.join(folder, MODEL_FILE))
        except OSError:
            return None
        return os.path.join(folder, MODEL_FILE), st.st_mtime_ns, st.st_size

    for cand in candidates:
        if cand is None:
            continue
        folder = os.path.normpath(os.fspath(cand))
        key = stat_key(folder)
        if key is not None:
            paths = [(folder, key)]
        else:
            try:
                with os.scandir(folder) as it:
                    names = sorted(e.path for e in it if e.name.endswith(MODEL_SUFFIX))
            except OSError:
                continue
            paths = [(p, stat_key(p)) for p in names]
        for path, key in paths:
            if key is not None and path not in seen:
                seen.add(path)
                yield Path(path), key


def model_dirs(candidates) -> list[tuple[Path, tuple]]:
    """(model directory, stat key) for every model among `candidates`: model directories, or
    folders holding `*.neurolens` directories (a folder's models in path order; None and
    missing candidates skipped), each model once. A directory counts once it holds a
    model.json, so a half-written one (the trainer writes under a temporary name) never does.
    The stat key (model.json path, mtime_ns, size) changes whenever model.json does: caches of
    anything derived from the models can key on it. Cheap: one scandir per folder and one stat
    per model; nothing is read."""
    return list(_walk(candidates))


def find_model(lens_content_hash: str, candidates) -> ModelHeader | None:
    """The header of the most accurate model among `candidates` (as for model_dirs) trained
    for the lens with this content hash: the lowest recorded image error p99, a model never
    evaluated after every evaluated one, then the first found (a lens may have a full and a
    cheaper, less accurate model: LEARNED means the best it has; AUTO weighs them all).
    Unreadable models are passed over. None: no such model."""
    mine = []
    for _directory, key in _walk(candidates):
        try:
            header = _cached_header(*key)
        except ModelError:
            continue
        if header.lens_content_hash == lens_content_hash:
            mine.append(header)
    p99 = [h.image_error_um_p99 for h in mine]
    order = sorted(range(len(mine)), key=lambda i: (p99[i] is None, p99[i] or 0.0, i))
    return mine[order[0]] if mine else None
