"""The polynomial baseline the paper compared NeuroLens with: the lens as least-squares
polynomials of the ray, with no networks (Hanika & Dachsbacher 2014, "Efficient Monte Carlo
Rendering with Realistic Lenses", fit their polynomial optics to traced rays by least squares;
their Figure 1 renders with a degree-4 fit).

As there, the map is fitted in two parts around the aperture (sensor side -> stop plane, where
the stop is tested exactly, and stop plane -> front), each one polynomial over the whole input
space (one cell, no kd-tree). The degree is raised, as Hanika & Dachsbacher raise theirs,
until the fit matches the traced rays: here, the lowest degree in DEGREES whose held-out error
meets the same cell threshold the NeuroLens trainer fits to (0.01 mm at 1 m), so both models
are held to one accuracy target. The result is an ordinary model
directory (a one-member "network" with a zero output layer), so it runs through the same
onnxruntime graphs and the same evaluation as NeuroLens.
"""

from __future__ import annotations

from pathlib import Path

from neurolens_addon.core.prescription import Lens

from .data import default_domain, stage_samples
from .fit import FitConfig, _poly_error

DEGREES = (2, 3, 4, 5, 6)


def choose_degree(lens: Lens, n_rays: int = 150_000, seed: int = 0, log=print) -> tuple[int, dict]:
    """(degree, {degree: worst stage error}): the lowest degree whose held-out error (both
    stages, mm at 1 m) meets the NeuroLens trainer's cell threshold, else the best one."""
    import numpy as np
    _, st1, st2 = stage_samples(lens, default_domain(lens), n_rays, seed=seed)
    target = FitConfig().error_threshold
    errors = {}
    for p in DEGREES:
        cfg = FitConfig(skip_degree=p)
        worst = 0.0
        for st in (st1, st2):
            if len(st.x) == 0 or st.x.shape[0] < 100:
                continue
            te = np.random.default_rng(seed).random(len(st.x)) < 0.2
            worst = max(worst, _poly_error(st.x[~te], st.y[~te], st.x[te], st.y[te], cfg))
        errors[p] = worst
        log(f"  polynomial degree {p}: {worst:.4f} mm at 1 m (worst stage)")
        if worst <= target:
            return p, errors
    return min(errors, key=errors.get), errors


def fit_polynomial_baseline(lens: Lens, out, *, degree: int | None = None,
                            n_rays: int = 400_000, seed: int = 0, log=print) -> dict:
    """Fit and write the baseline model (out: a .neurolens directory); returns model.json."""
    from .pipeline import fit_lens
    p = degree or choose_degree(lens, seed=seed, log=log)[0]
    cfg = FitConfig(skip_degree=p, networks=False, ensemble=1, max_depth=0, seed=seed)
    log(f"polynomial baseline for '{lens.name}': degree {p}")
    return fit_lens(lens, Path(out), cfg, n_rays=n_rays, log=log)
