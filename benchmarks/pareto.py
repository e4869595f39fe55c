"""Speed against accuracy for every preset: each lens model on the same rays in one run
(issue 6 figures).

Models, from cheapest to exact:
  thin        Blender's thin lens of the same focal length, focused at the same distance: every
              ray of a film point meets the plane in focus at that point's ideal conjugate
              (-p / m, m the lens's paraxial magnification), so its image error is the real
              lens's distortion and aberrations; timed as the numpy thin-lens ray generation.
  polynomial  the polynomial baseline (trainer.baseline: least-squares polynomials around the
              stop, no networks, degree raised until it meets the trainer's cell threshold, as
              Hanika & Dachsbacher 2014 raise theirs), run by the same onnxruntime graphs.
  neurolens   the shipped model (presets/models: Theta 8, 3 networks, kd depth 1, or 3 for
              the fisheye), its variants (the double Gauss's lean one: one network, degree 3),
              'small' trained here for every lens (Theta 4, 3 networks, one cell per stage),
              and for the paper's four lenses 'sparse' (the sparse skip basis, depth 1).
  exact       the float64 numpy trace (the reference; error 0 by definition).
Figures (trainer.evaluate, same held-out rays for every model of a lens): rays per second of
the whole model (stop test included), relative error (Eq. 4), image-space error on the
sensor (p50 / p99, micrometres), storage. Models trained here are kept in build/bench-models
(never committed) and reused on the next run.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from neurolens_addon.core.lensfile import load_lens

from .common import (ROOT, LensRecords, is_position_model, md_table, measured_inputs,
                     preset_paths)

MODELS = ROOT / "presets" / "models"
BENCH_MODELS = ROOT / "build" / "bench-models"
FIGURE = ROOT / "docs" / "bench" / "pareto.png"
N_RAYS = 300_000
PAPER_FOUR = ("double_gauss_50mm_f2", "wide_angle_f3_4", "fisheye_f4", "biconvex_singlet")


def _thin_lens(lens, domain, n):
    """(image error p50, p99 in um, rays per second) of the ideal thin lens."""
    from neurolens_addon.core.paraxial import paraxial_data
    from neurolens_addon.core.trace import trace
    from neurolens_addon.core.irf import propagate_to_z
    from trainer.evaluate import camera_rays_at_focus, evaluation_focus_mm
    focus = evaluation_focus_mm(lens, domain)
    rays, z_s = camera_rays_at_focus(lens, domain, n, focus, 0)
    res = trace(lens, rays, stop_radius=domain.stop_radius_mm)
    pd = paraxial_data(lens)
    z_obj = z_s + focus
    m = pd.efl_mm / (z_obj - pd.front_principal_z_mm - pd.efl_mm)
    v = res.valid
    pe = propagate_to_z(res.rays.o[:, v], res.rays.d[:, v], z_obj)
    ideal = -rays.o[:2, v] / m
    err = np.hypot(*(pe[:2] - ideal)) * m * 1000.0
    # the thin lens's own work per camera ray: a point on the lens disc toward the conjugate
    film = rays.o[:2]
    lens_pt = rays.o[:2] * 0.1
    s_i = pd.efl_mm * (1 + m)

    def generate():
        conj = -film / m
        d = np.vstack([conj - lens_pt, np.full(film.shape[1], focus - s_i)])
        return d / np.linalg.norm(d, axis=0)
    t = min(_timed(generate) for _ in range(3))
    return float(np.percentile(err, 50)), float(np.percentile(err, 99)), n / t


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _bench_model(kind: str, lens, stem: str, path: Path, log) -> Path:
    """Train a model the benchmark compares (once; reused from build/bench-models)."""
    if (path / "model.json").exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    from trainer.fit import FitConfig
    from trainer.pipeline import fit_lens
    quiet = lambda *a: None
    if kind == "polynomial":
        from trainer.baseline import fit_polynomial_baseline
        fit_polynomial_baseline(lens, path, n_rays=400_000, log=quiet)
    elif kind == "small":
        fit_lens(lens, path, FitConfig(theta=4, ensemble=3, max_depth=0), log=quiet)
    elif kind == "sparse":
        fit_lens(lens, path, FitConfig(skip_basis="sparse", max_depth=1), log=quiet)
    log(f"  trained {path.name}")
    return path


def _models_of(lens, stem: str) -> list[tuple[str, Path, str | None]]:
    """[(label, model directory, kind to train it as or None)] compared for one lens."""
    out = [("polynomial", BENCH_MODELS / f"{stem}.poly.neurolens", "polynomial"),
           ("neurolens", MODELS / f"{stem}.neurolens", None)]
    out += [(f"neurolens {p.name[len(stem) + 1:-len('.neurolens')]}", p, None)
            for p in sorted(MODELS.glob(f"{stem}.*.neurolens"))
            if not is_position_model(p.name)]      # (another lens: learned section)
    for kind in ("small",) + (("sparse",) if stem in PAPER_FOUR else ()):
        out.append((f"neurolens {kind}", BENCH_MODELS / f"{stem}.{kind}.neurolens", kind))
    return out


def _measure_lens(lens_path: Path, lens, models) -> dict:
    """Every model of one lens, the thin lens and the exact trace on the same rays."""
    from neurolens_addon.neural.model import LearnedLens
    from trainer.evaluate import domain_of, evaluate_model
    from trainer.pipeline import model_storage_bytes
    lens_figs, exact_rps, domain = {}, [], None
    for label, mdir, _kind in models:
        model = LearnedLens.load(mdir, lens=lens)
        res = evaluate_model(model, lens, n=N_RAYS)
        meta = json.loads((mdir / "model.json").read_text())
        res["storage_kb"] = model_storage_bytes(mdir) / 1024.0
        res["cells"] = "+".join(str(len(s.get("cells", []))) for s in meta["stages"])
        if label == "polynomial":
            res["degree"] = meta["skip_degree"]
        lens_figs[label] = res
        exact_rps.append(res["exact_rays_per_s"])
        if label == "neurolens":
            domain = domain_of(meta)
    p50, p99, thin_rps = _thin_lens(lens, domain, N_RAYS)
    lens_figs["thin"] = {"image_error_um_p50": p50, "image_error_um_p99": p99,
                         "onnx_rays_per_s": thin_rps, "relative_error_pct": None,
                         "storage_kb": 0.0}
    lens_figs["exact"] = {"image_error_um_p50": 0.0, "image_error_um_p99": 0.0,
                          "onnx_rays_per_s": float(np.median(exact_rps)),
                          "relative_error_pct": 0.0,
                          "storage_kb": lens_path.stat().st_size / 1024.0}
    order = ["thin"] + [m[0] for m in models] + ["exact"]
    return {"name": lens.name, "models": {k: lens_figs[k] for k in order}}


def _rows(lens_figs: dict) -> list[list[str]]:
    rows = []
    for label, r in lens_figs.items():
        name = label + (f" (degree {r['degree']})" if "degree" in r else "") + (
            f" ({r['cells']} cells)" if "cells" in r and label != "polynomial" else "")
        rel = "-" if r["relative_error_pct"] is None else f"{r['relative_error_pct']:.4f}"
        rows.append([name, f"{r['onnx_rays_per_s'] / 1e6:.2f}", rel,
                     f"{r['image_error_um_p50']:.3g}", f"{r['image_error_um_p99']:.3g}",
                     f"{r['storage_kb']:.0f}"])
    return rows


def run(resume: bool = False, only=None) -> tuple[str, dict]:
    records = LensRecords("pareto", resume, only)
    figs, sections = {}, []
    for lens_path in preset_paths():
        stem = lens_path.stem
        lens = load_lens(lens_path)
        models = _models_of(lens, stem)
        inputs = lambda: measured_inputs(lens_path, *(m[1] for m in models))
        figs_lens = records.get(stem, inputs())
        if figs_lens is None:
            for _label, mdir, kind in models:
                if kind is not None:
                    _bench_model(kind, lens, stem, mdir, print)
            figs_lens = records.put(stem, inputs(), _measure_lens(lens_path, lens, models))
            print(f"  {stem}: " + ", ".join(
                f"{k} {v['onnx_rays_per_s'] / 1e6:.2f} M/s {v['image_error_um_p99']:.3g} um"
                for k, v in figs_lens["models"].items()), flush=True)
        else:
            print(f"  {stem}: kept (measured {figs_lens['measured']})", flush=True)
        figs[stem] = figs_lens
        sections.append(f"### {figs_lens['name']}\n\n_measured {figs_lens['measured']}_\n\n"
                        + md_table(["model", "M rays/s", "relative error %",
                                    "image error p50 um", "image error p99 um", "storage KB"],
                                   _rows(figs_lens["models"])))
    _plot({stem: f["models"] for stem, f in figs.items()})
    head = ("## Speed against accuracy (every lens model, same rays, one run per lens)\n\n"
            f"{N_RAYS} held-out camera rays per model (trainer.evaluate); 2 onnxruntime "
            "threads; rays/s for the whole model including the stop test. Every model of a lens "
            "is measured in one run (the date under its name; `--resume` measures only lenses "
            "or models that changed since). Thin lens: image "
            "error = the real lens's departure from an ideal lens (distortion and aberrations). "
            "Pareto plot: ![speed against accuracy](bench/pareto.png)\n")
    return head + "\n" + "\n\n".join(sections), figs


def _plot(figs: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    n = len(figs)
    cols = 4
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(4 * cols, 3.2 * ((n + cols - 1) // cols)))
    for ax, (stem, lf) in zip(axes.ravel(), figs.items()):
        pts = [(k, v["onnx_rays_per_s"] / 1e6, max(v["image_error_um_p99"], 1e-3))
               for k, v in lf.items()]
        for k, x, y in pts:
            ax.scatter(x, y, s=18)
            ax.annotate(k.replace("neurolens", "NL"), (x, y), fontsize=6)
        front = sorted(pts, key=lambda p: -p[1])
        best, line = float("inf"), []
        for k, x, y in front:
            if y < best:
                best = y
                line.append((x, y))
        ax.plot(*zip(*line), lw=0.8, color="0.4")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(stem, fontsize=8)
        ax.set_xlabel("M rays/s", fontsize=7)
        ax.set_ylabel("image error p99 (um)", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.tight_layout()
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURE, dpi=110)
    plt.close(fig)
