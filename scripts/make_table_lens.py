"""Build the test fixture of a lens known only from a ray table (testdata/models/
measured_tessar.neurolens): the Tessar's exact rays at infinity focus written as an external
table (trainer.pipeline.load_ray_table's .npz: the film is its input plane) and learned from
it by `trainer fit-table`, as a user with a measured or foreign lens would.

    python scripts/make_table_lens.py      (about 15 s; rerun when the model format changes)
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neurolens_addon.core.field import design_film_radius_mm  # noqa: E402
from neurolens_addon.core.focus import focus_sensor_z  # noqa: E402
from neurolens_addon.core.irf import propagate_to_z  # noqa: E402
from neurolens_addon.core.rays import Rays  # noqa: E402
from neurolens_addon.core.trace import trace  # noqa: E402
from testdata.table_lens import MODEL, NAME, lens  # noqa: E402
from trainer.data import Domain, aim_disc  # noqa: E402
from trainer.fit import FitConfig  # noqa: E402
from trainer.pipeline import fit_table  # noqa: E402

D_LINE_NM = 587.5618


def write_table(path: Path, n: int = 120_000, seed: int = 5) -> Path:
    """The table of `n` camera rays of the Tessar focused at infinity (d line): film points
    uniform over its design field, aimed uniformly over its rear disc; invalid rays flagged."""
    tessar = lens()
    z_s = focus_sensor_z(tessar, math.inf)
    film = design_film_radius_mm(tessar)
    dom = Domain(film, (z_s, z_s), (D_LINE_NM, D_LINE_NM), False)
    rng = np.random.default_rng(seed)
    u = rng.random((4, n))
    r, phi = film * np.sqrt(u[0]), 2.0 * np.pi * u[1]
    plane_z, radius = aim_disc(tessar, dom)
    rr, rphi = radius * np.sqrt(u[2]), 2.0 * np.pi * u[3]
    o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, z_s)])
    d = np.stack([rr * np.cos(rphi), rr * np.sin(rphi), np.full(n, plane_z)]) - o
    d /= np.linalg.norm(d, axis=0)
    wl = np.full(n, D_LINE_NM)
    res = trace(tessar, Rays(o, d, wl), from_sensor=True)
    z_out = tessar.front_vertex_z + 1.0
    oo = propagate_to_z(res.rays.o, res.rays.d, z_out)
    inputs = np.concatenate([o[:2], d, wl[None]]).T
    outputs = np.nan_to_num(np.concatenate([oo[:2], res.rays.d]).T)
    np.savez(path, inputs=inputs, outputs=outputs, valid=res.valid, input_z=z_s,
             output_z=z_out, name=NAME)
    return Path(path)


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        table = write_table(Path(tmp) / "tessar_rays.npz")
        cfg = FitConfig(theta=8, ensemble=2, skip_degree=3, max_depth=0, member_samples=20000,
                        lm_iterations=25, cell_time_budget_s=120)
        fit_table(table, MODEL.with_suffix(""), cfg)
    print(f"wrote {MODEL}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
