"""Learn a lens end to end: exact training rays -> two fitted stages -> model directory.

The model directory `NAME.neurolens/` holds model.json (metadata and weights) and the ONNX
graphs. It is written into a temporary sibling and renamed into place, so an interrupted run
never leaves a directory that loads as a model. Cells are checkpointed as they finish in
`NAME.neurolens.partial/`, and a rerun with the same settings resumes from them.
Each stage is learned in its group's frame (core.irf.stage_frames): radial, or cartesian for a
group with an anamorphic surface; model.json records each (stages[k].frame) and, as "frame",
cartesian when any stage is.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from neurolens_addon.core.atomic import (atomic_write_text, mode_for, replace_directory,
                                         write_checked)
from neurolens_addon.core.irf import CARTESIAN, RADIAL, stage_frames
from neurolens_addon.core.jsonout import dumps_strict
from neurolens_addon.core.prescription import Lens
from neurolens_addon.neural.modelfile import (FORMAT, MODEL_FILE, MODEL_SUFFIX, VERSION,
                                              encode_occupancy)

from .data import Domain, default_domain, stage_samples
from .fit import CellFit, FitConfig, fit_stage
from .occupancy import occupancy_grid, table_occupancy


class CellCheckpoints:
    """One JSON file per finished cell, keyed by stage and tree path, valid for one settings
    fingerprint (lens hash, config, sample count)."""

    def __init__(self, directory: Path, fingerprint: str):
        self.dir = Path(directory)
        self.fingerprint = fingerprint
        self.dir.mkdir(parents=True, exist_ok=True)
        stamp = self.dir / "fingerprint.txt"
        if stamp.exists() and stamp.read_text() != fingerprint:
            for f in self.dir.glob("*.json"):
                f.unlink()
        atomic_write_text(stamp, fingerprint)

    def get(self, key: str):
        f = self.dir / f"{key}.json"
        if not f.exists():
            return None
        try:
            d = json.loads(f.read_text())
            return CellFit(d["cell"], d["test_error"], d["hidden"], d["n_train"], d["seconds"],
                           d.get("relative_error", 0.0))
        except (ValueError, KeyError):
            return None

    def put(self, key: str, fit: CellFit) -> None:
        atomic_write_text(self.dir / f"{key}.json", json.dumps(asdict(fit)))


def model_path_for(out: str | Path) -> Path:
    out = Path(out)
    return out if out.name.endswith(MODEL_SUFFIX) else out.with_name(out.name + MODEL_SUFFIX)


def fit_lens(lens: Lens, out: str | Path, cfg: FitConfig | None = None, *, n_rays: int = 400_000,
             dispersion: bool = True, domain: Domain | None = None, log=print) -> dict:
    """Train both stages of a learned lens and write the model directory; returns model.json."""
    frames = stage_frames(lens)
    cfg = cfg or FitConfig()
    out = model_path_for(out)
    domain = domain or default_domain(lens, dispersion)
    t0 = time.perf_counter()
    log(f"[1/4] exact training rays: {n_rays} Latin-hypercube sensor rays through '{lens.name}'"
        f" (frames: rear group {frames[0].name}, front group {frames[1].name})")
    planes, st1, st2 = stage_samples(lens, domain, n_rays, seed=cfg.seed)
    log(f"      stage 1: {st1.x.shape[0]} samples, stage 2: {st2.x.shape[0]} samples")
    fingerprint = json.dumps([lens.content_hash(), asdict(cfg), n_rays, domain.as_dict()])
    ckpt = CellCheckpoints(out.with_name(out.name + ".partial"), fingerprint)
    stages = []
    stop = lens.stop_index
    groups = [("rear", (stop, len(lens.surfaces)), planes.input_z, st1),
              ("front", (0, stop), planes.stop_z, st2)]
    for k, ((name, surfaces, plane_z, st), frame) in enumerate(zip(groups, frames)):
        if surfaces[0] == surfaces[1]:
            log(f"[{2 + k}/4] stage {k + 1} ({name} group): no surfaces, exact propagation")
            stages.append({"name": name, "frame": frame.name, "propagate": True,
                           "bounds": padded_bounds(st.x, radial=frame.rotates)})
            continue
        log(f"[{2 + k}/4] stage {k + 1} ({name} group): kd-tree of ensembles")
        sf = fit_stage(st.x, st.y, cfg, stage=k, log=log, cache=ckpt, frame=frame)
        nb = frame.base                       # the occupancy grid's axes
        lo_b, hi_b = st.x[:, :nb].min(axis=0), st.x[:, :nb].max(axis=0)
        pad = 0.02 * (hi_b - lo_b)
        lo_b, hi_b = lo_b - pad, hi_b + pad
        grid = occupancy_grid(lens, surfaces, plane_z, lo_b, hi_b,
                              stop_radius=domain.stop_radius_mm or lens.stop_radius_mm,
                              frame=frame)
        stages.append({"name": name, "frame": frame.name,
                       "bounds": padded_bounds(st.x, radial=frame.rotates),
                       "occupancy": encode_occupancy(grid, lo_b, hi_b),
                       "tree": sf.tree, "cells": sf.cells,
                       "test_errors_mm_at_1m": [f.test_error for f in sf.fits],
                       "relative_errors": [f.relative_error for f in sf.fits]})
    model = {
        "format": FORMAT, "version": VERSION,
        "lens": {"name": lens.name, "content_hash": lens.content_hash(),
                 "source": lens.source},
        "frame": (CARTESIAN if CARTESIAN in frames else RADIAL).name,
        "planes": {**planes.as_dict(), "stop_radius_mm": lens.stop_radius_mm},
        "domain": domain.as_dict(),
        "stages": stages,
        "ensemble_size": cfg.ensemble, "theta": cfg.theta, "skip_degree": cfg.skip_degree,
        "skip_basis": cfg.skip_basis,
        "training": {"config": asdict(cfg), "n_rays": n_rays,
                     "samples": [int(st1.x.shape[0]), int(st2.x.shape[0])],
                     "seconds": time.perf_counter() - t0},
    }
    log("[4/4] exporting ONNX and writing the model")
    write_model(model, out)
    shutil.rmtree(ckpt.dir, ignore_errors=True)
    log(f"wrote {out} in {time.perf_counter() - t0:.1f} s")
    return model


def padded_bounds(X: np.ndarray, pad: float = 0.02, radial: bool = True) -> dict:
    """The samples' box grown by 2 % of its size per side (the networks were fitted on cell
    boxes grown by 10 %), with r (axis 0 of the radial frame) kept >= 0 so the axis itself is
    inside."""
    lo, hi = X.min(axis=0), X.max(axis=0)
    span = hi - lo
    lo, hi = lo - pad * span, hi + pad * span
    if radial:
        lo[0] = max(lo[0], 0.0)
    return {"lo": lo.tolist(), "hi": hi.tolist()}


def write_model(model: dict, out: Path) -> None:
    """ONNX graphs + model.json into a temporary directory, each file flushed and read back
    (core.atomic.write_checked), then renamed into place; the directory gets the old one's
    mode, or the umask's (mkdtemp's 0700 would hide a shared model from the other users)."""
    from onnx_export import write_onnx_files
    out = Path(out)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=out.name + ".", suffix=".tmp"))
    try:
        os.chmod(tmp, mode_for(out, directory=True))
        model["files"] = write_onnx_files(model, tmp, shown=out)
        write_checked(tmp / MODEL_FILE, dumps_strict(model).encode("utf-8"),
                      shown=out / MODEL_FILE)
        replace_directory(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def model_storage_bytes(out: Path) -> int:
    return sum(f.stat().st_size for f in Path(out).glob("*.onnx"))


def load_ray_table(path: str | Path):
    """An external ray table (.npz, never pickled) for a lens whose interior is unknown:
    inputs (N, 6) = x, y, u, v, w, lambda_nm on the plane z = input_z (sensor side);
    outputs (N, 5) = x', y', u', v', w' on the plane z = output_z (scene side);
    scalars input_z and output_z (mm); optional valid (N,) bool and name (str)."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable .npz ray table ({exc})") from exc
    for key in ("inputs", "outputs", "input_z", "output_z"):
        if key not in data:
            raise ValueError(f"{path}: ray table has no '{key}' array")
    x, y = np.asarray(data["inputs"], float), np.asarray(data["outputs"], float)
    if x.ndim != 2 or x.shape[1] != 6 or y.shape != (x.shape[0], 5):
        raise ValueError(f"{path}: expected inputs (N, 6) and outputs (N, 5), got "
                         f"{x.shape} and {y.shape}")
    keep = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1)
    if "valid" in data:
        keep &= np.asarray(data["valid"], bool)
    if keep.sum() < 1000:
        raise ValueError(f"{path}: only {int(keep.sum())} usable rays; need at least 1000")
    name = str(data["name"]) if "name" in data else path.stem
    return x[keep], y[keep], float(data["input_z"]), float(data["output_z"]), name


#: the share of its span a ray table's box of directions is padded by on each side
TABLE_PAD = 0.1


def fit_table(table: str | Path, out: str | Path, cfg: FitConfig | None = None, *,
              log=print) -> dict:
    """Learn a lens from a ray table: one learned stage from the input to the output plane
    (no stop is known, so none is tested) followed by a zero-length propagation stage.
    The domain is the table's own coverage: cells of (r, u_r, u_t) holding table rays, each
    film-radius slice's convex hull (occupancy.table_occupancy)."""
    import hashlib

    from neurolens_addon.core.irf import stage_targets
    from neurolens_addon.neural.reference import stage_inputs
    cfg = cfg or FitConfig()
    out = model_path_for(out)
    t0 = time.perf_counter()
    x, y, z_in, z_out, name = load_ray_table(table)
    wl = x[:, 5]
    dispersion = bool(np.ptp(wl) > 0)
    X, rot = stage_inputs(x[:, :2], x[:, 2:5], wl, dispersion)
    o_out = np.stack([y[:, 0], y[:, 1], np.full(len(y), z_out)])
    Y = stage_targets(o_out, y[:, 2:5].T, rot)
    log(f"ray table {name}: {len(X)} rays, dispersion {'on' if dispersion else 'off'}")
    sf = fit_stage(X, Y, cfg, stage=0, log=log)
    # the directions' box padded: a slice's hull (grown for what its rays miss, moved along
    # the bundle's centre) reaches past what the table's rays reached; the film's centre is in
    # the domain, however near the table came to it
    box = padded_bounds(X, pad=TABLE_PAD)
    lo3, hi3 = np.array(box["lo"][:3]), np.array(box["hi"][:3])
    lo3[0], hi3[0] = 0.0, X[:, 0].max()
    domain = table_occupancy(X[:, :3], lo3, hi3)
    digest = hashlib.sha256(Path(table).read_bytes()).hexdigest()[:16]
    model = {
        "format": FORMAT, "version": VERSION,
        "lens": {"name": name, "content_hash": f"table-{digest}", "source": str(table)},
        "planes": {"input_z": z_in, "stop_z": z_out, "output_z": z_out, "stop_radius_mm": None},
        "domain": {"film_radius_mm": float(X[:, 0].max()), "sensor_z_range": [z_in, z_in],
                   "wavelength_range_nm": [float(wl.min()), float(wl.max())],
                   "dispersion": dispersion},
        "stages": [{"name": "whole", "bounds": box,
                    "occupancy": encode_occupancy(domain, lo3, hi3), "tree": sf.tree,
                    "cells": sf.cells,
                    "test_errors_mm_at_1m": [ft.test_error for ft in sf.fits]},
                   {"name": "front", "propagate": True}],
        "ensemble_size": cfg.ensemble, "theta": cfg.theta, "skip_degree": cfg.skip_degree,
        "skip_basis": cfg.skip_basis,
        "training": {"config": asdict(cfg), "n_rays": int(len(X)), "samples": [int(len(X)), 0],
                     "seconds": time.perf_counter() - t0, "from_table": str(table)},
    }
    write_model(model, out)
    log(f"wrote {out} in {time.perf_counter() - t0:.1f} s")
    return model
