"""A lens known only from a ray table: the Tessar's exact rays at infinity focus, written as
an external table (trainer.pipeline.load_ray_table's .npz: the film is its input plane) and
learned from it by `trainer fit-table`, as a user with a measured or foreign lens would.

    build_model(folder) -> the model directory (real torch training on small data)
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.irf import propagate_to_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace

ROOT = Path(__file__).resolve().parents[1]
LENS_FILE = ROOT / "presets" / "lenses" / "tessar_f4_5.toml"
NAME = "measured tessar"


def lens():
    return load_lens(LENS_FILE)


def write_table(path: Path, n: int = 120_000, seed: int = 5) -> Path:
    """The table of `n` camera rays of the Tessar focused at infinity (d line): film points
    uniform over its design field, aimed uniformly over its rear disc; invalid rays flagged."""
    from neurolens_addon.core.field import design_film_radius_mm
    from trainer.data import Domain, aim_disc
    tessar = lens()
    z_s = focus_sensor_z(tessar, math.inf)
    film = design_film_radius_mm(tessar)
    dom = Domain(film, (z_s, z_s), (587.5618, 587.5618), False)
    rng = np.random.default_rng(seed)
    u = rng.random((4, n))
    r, phi = film * np.sqrt(u[0]), 2.0 * np.pi * u[1]
    plane_z, radius = aim_disc(tessar, dom)
    rr, rphi = radius * np.sqrt(u[2]), 2.0 * np.pi * u[3]
    o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, z_s)])
    d = np.stack([rr * np.cos(rphi), rr * np.sin(rphi), np.full(n, plane_z)]) - o
    d /= np.linalg.norm(d, axis=0)
    wl = np.full(n, 587.5618)
    res = trace(tessar, Rays(o, d, wl), from_sensor=True)
    z_out = tessar.front_vertex_z + 1.0
    oo = propagate_to_z(res.rays.o, res.rays.d, z_out)
    inputs = np.concatenate([o[:2], d, wl[None]]).T
    outputs = np.nan_to_num(np.concatenate([oo[:2], res.rays.d]).T)
    np.savez(path, inputs=inputs, outputs=outputs, valid=res.valid, input_z=z_s,
             output_z=z_out, name=NAME)
    return Path(path)


def build_model(folder: Path) -> Path:
    """The table written and learned in `folder`: the model directory."""
    from trainer.fit import FitConfig
    from trainer.pipeline import fit_table
    folder = Path(folder)
    table = write_table(folder / "tessar_rays.npz")
    cfg = FitConfig(theta=8, ensemble=2, skip_degree=3, max_depth=0, member_samples=20000,
                    lm_iterations=25, cell_time_budget_s=120)
    fit_table(table, folder / "measured_tessar", cfg, log=lambda *a: None)
    return folder / "measured_tessar.neurolens"
