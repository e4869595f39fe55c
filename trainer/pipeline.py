"""Learn a lens end to end: exact training rays -> two fitted stages -> model directory.

The model directory `NAME.neurolens/` holds model.json (metadata and weights) and the ONNX
graphs. It is written into a temporary sibling and renamed into place, so an interrupted run
never leaves a directory that loads as a model. Cells are checkpointed as they finish in
`NAME.neurolens.partial/`, and a rerun with the same settings resumes from them.
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

from neurolens_addon.core.prescription import Lens

from .data import Domain, default_domain, stage_samples
from .fit import CellFit, FitConfig, fit_stage
from .occupancy import encode, occupancy_grid

FORMAT = "neurolens-model"
VERSION = 1


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
        stamp.write_text(fingerprint)

    def get(self, key: str):
        f = self.dir / f"{key}.json"
        if not f.exists():
            return None
        try:
            d = json.loads(f.read_text())
            return CellFit(d["cell"], d["test_error"], d["hidden"], d["n_train"], d["seconds"])
        except (ValueError, KeyError):
            return None

    def put(self, key: str, fit: CellFit) -> None:
        atomic_write_text(self.dir / f"{key}.json", json.dumps(asdict(fit)))


def atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def model_path_for(out: str | Path) -> Path:
    out = Path(out)
    return out if out.name.endswith(".neurolens") else out.with_name(out.name + ".neurolens")


def fit_lens(lens: Lens, out: str | Path, cfg: FitConfig | None = None, *, n_rays: int = 400_000,
             dispersion: bool = True, domain: Domain | None = None, log=print) -> dict:
    """Train both stages of a learned lens and write the model directory; returns model.json."""
    cfg = cfg or FitConfig()
    out = model_path_for(out)
    domain = domain or default_domain(lens, dispersion)
    t0 = time.perf_counter()
    log(f"[1/4] exact training rays: {n_rays} Latin-hypercube sensor rays through '{lens.name}'")
    planes, st1, st2 = stage_samples(lens, domain, n_rays, seed=cfg.seed)
    log(f"      stage 1: {st1.x.shape[0]} samples, stage 2: {st2.x.shape[0]} samples")
    fingerprint = json.dumps([lens.content_hash(), asdict(cfg), n_rays, domain.as_dict()])
    ckpt = CellCheckpoints(out.with_name(out.name + ".partial"), fingerprint)
    stages = []
    stop = lens.stop_index
    groups = [("rear", (stop, len(lens.surfaces)), planes.input_z, st1),
              ("front", (0, stop), planes.stop_z, st2)]
    for k, (name, surfaces, plane_z, st) in enumerate(groups):
        if surfaces[0] == surfaces[1]:
            log(f"[{2 + k}/4] stage {k + 1} ({name} group): no surfaces, exact propagation")
            stages.append({"name": name, "propagate": True,
                           "bounds": {"lo": st.x.min(axis=0).tolist(),
                                      "hi": st.x.max(axis=0).tolist()}})
            continue
        log(f"[{2 + k}/4] stage {k + 1} ({name} group): kd-tree of ensembles")
        sf = fit_stage(st.x, st.y, cfg, stage=k, log=log, cache=ckpt)
        lo3, hi3 = st.x[:, :3].min(axis=0), st.x[:, :3].max(axis=0)
        pad = 0.02 * (hi3 - lo3)
        lo3, hi3 = lo3 - pad, hi3 + pad
        grid = occupancy_grid(lens, surfaces, plane_z, lo3, hi3,
                              stop_radius=lens.stop_radius_mm)
        stages.append({"name": name,
                       "bounds": {"lo": st.x.min(axis=0).tolist(), "hi": st.x.max(axis=0).tolist()},
                       "occupancy": encode(grid, lo3, hi3),
                       "tree": sf.tree, "cells": sf.cells,
                       "test_errors": [f.test_error for f in sf.fits]})
    model = {
        "format": FORMAT, "version": VERSION,
        "lens": {"name": lens.name, "content_hash": lens.content_hash(),
                 "source": lens.source},
        "planes": {**planes.as_dict(), "stop_radius_mm": lens.stop_radius_mm},
        "domain": domain.as_dict(),
        "stages": stages,
        "ensemble_size": cfg.ensemble, "theta": cfg.theta, "skip_degree": cfg.skip_degree,
        "training": {"config": asdict(cfg), "n_rays": n_rays,
                     "samples": [int(st1.x.shape[0]), int(st2.x.shape[0])],
                     "seconds": time.perf_counter() - t0},
    }
    log("[4/4] exporting ONNX and writing the model")
    write_model(model, out)
    shutil.rmtree(ckpt.dir, ignore_errors=True)
    log(f"wrote {out} in {time.perf_counter() - t0:.1f} s")
    return model


def write_model(model: dict, out: Path) -> None:
    """ONNX graphs + model.json into a temporary directory, then renamed into place."""
    from .export_onnx import write_onnx_files
    out = Path(out)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=out.name + ".", suffix=".tmp"))
    try:
        model["files"] = write_onnx_files(model, tmp)
        (tmp / "model.json").write_text(json.dumps(model))
        if out.exists():
            old = out.with_name(out.name + ".old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def model_storage_bytes(out: Path) -> int:
    return sum(f.stat().st_size for f in Path(out).glob("*.onnx"))
