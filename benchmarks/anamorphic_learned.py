"""The learned lens of an anamorphic lens (the cartesian frame, core.irf) against the exact
trace: the test lens of testdata.anamorphic_lenses (cylinders before a singlet, squeeze 1.30)
trained at the trainer's default settings (FitConfig(), 400 000 rays), then, in the same run:

* held-out accuracy: a fresh Latin-hypercube draw of sensor rays (seed + 1000, never seen in
  training: trainer.evaluate's draw) through both lenses; where both pass, the distance of the
  rays' points on Pi_2 (mean, p99, max in micrometres) and of their unit directions (mean,
  p99, max in microradians, |d_learned - d_exact|);
* speed: the same camera rays (film points over the domain's disc, aimed over the rear
  element's disc, focused at 2 m) through forward_fast.onnx (LearnedLens.trace_from_sensor,
  the default path) and through the float64 exact trace, best of 3 each.

`python -m benchmarks.run anamorphic_learned`, or `python -m benchmarks.anamorphic_learned
[--rays N]` to print the figures without writing docs/bench.
"""

from __future__ import annotations

import sys
import tempfile
import time

import numpy as np

from .common import best_time, md_table

N_HELD_OUT = 400_000
N_SPEED = 300_000


def measure(n_rays: int = 400_000, log=None) -> dict:
    from neurolens_addon.core.irf import propagate_to_z
    from neurolens_addon.core.rays import Rays
    from neurolens_addon.core.trace import trace
    from neurolens_addon.neural.model import LearnedLens
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    from trainer.data import default_domain, sensor_rays
    from trainer.evaluate import camera_rays_at_focus
    from trainer.fit import FitConfig
    from trainer.pipeline import fit_lens

    lens = cylinder_attachment_lens()
    domain = default_domain(lens)
    cfg = FitConfig()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        meta = fit_lens(lens, f"{tmp}/anamorphic", cfg, n_rays=n_rays, domain=domain,
                        log=log or (lambda *a: None))
        train_s = time.perf_counter() - t0
        model = LearnedLens.load(f"{tmp}/anamorphic.neurolens", lens=lens)
        rng = np.random.default_rng(cfg.seed + 1000)
        o, d, wl = sensor_rays(lens, domain, N_HELD_OUT, rng)
        rays = Rays(o, d, wl)
        ex = trace(lens, rays)
        le = model.trace_from_sensor(rays, sensor_z=o[2])
        v = ex.valid & le.valid
        eo = propagate_to_z(ex.rays.o[:, v], ex.rays.d[:, v], model.planes["output_z"])
        pos_um = 1000.0 * np.hypot(eo[0] - le.rays.o[0, v], eo[1] - le.rays.o[1, v])
        dir_urad = 1e6 * np.linalg.norm(ex.rays.d[:, v] - le.rays.d[:, v], axis=0)
        cam, z_s = camera_rays_at_focus(lens, domain, N_SPEED, 2000.0, seed=1)
        model.trace_from_sensor(cam, sensor_z=z_s)                     # warm the sessions
        t_fast = best_time(lambda: model.trace_from_sensor(cam, sensor_z=z_s))
        t_exact = best_time(lambda: trace(lens, cam))
        cells = [len(st.get("cells", [])) for st in meta["stages"]]
    return {"lens": lens.name, "frame": meta["frame"], "n_rays": n_rays,
            "train_s": train_s, "cells": cells,
            "held_out_rays": int(v.sum()),
            "valid_agreement": float((ex.valid == le.valid).mean()),
            "pos_um_mean": float(pos_um.mean()), "pos_um_p99": float(np.percentile(pos_um, 99)),
            "pos_um_max": float(pos_um.max()),
            "dir_urad_mean": float(dir_urad.mean()),
            "dir_urad_p99": float(np.percentile(dir_urad, 99)),
            "dir_urad_max": float(dir_urad.max()),
            "speed_rays": N_SPEED, "fast_rays_per_s": N_SPEED / t_fast,
            "exact_rays_per_s": N_SPEED / t_exact, "speedup": t_exact / t_fast,
            "provider": model.provider}


def section(f: dict) -> str:
    rows = [[f["lens"], f["frame"], f"{f['n_rays']:,}", " + ".join(map(str, f["cells"])),
             f"{f['train_s']:.0f}", f"{f['valid_agreement'] * 100:.2f}",
             f"{f['pos_um_mean']:.2f}", f"{f['pos_um_p99']:.2f}",
             f"{f['dir_urad_mean']:.1f}", f"{f['dir_urad_p99']:.1f}",
             f"{f['fast_rays_per_s'] / 1e6:.2f} M", f"{f['exact_rays_per_s'] / 1e6:.2f} M",
             f"{f['speedup']:.1f}x"]]
    head = ["lens", "frame", "training rays", "cells (stage 1 + 2)", "train s",
            "same pass/fail %", "Pi_2 error mean um", "p99 um", "direction error mean urad",
            "p99 urad", "forward_fast rays/s", "exact rays/s", "speed-up"]
    return ("## Learned anamorphic lens (cartesian frame)\n\n"
            "The anamorphic test lens (testdata.anamorphic_lenses, squeeze 1.30) learned at the "
            "trainer's default settings in the cartesian frame (x, y, u, v, w, lambda: no "
            "rotational symmetry assumed). Errors on "
            f"{f['held_out_rays']:,} held-out sensor rays valid in both lenses; speeds on the "
            f"same {f['speed_rays']:,} camera rays, forward_fast.onnx ({f['provider']}) "
            "against the float64 exact trace, in one run.\n\n" + md_table(head, rows))


def run() -> tuple[str, dict]:
    figs = measure()
    return section(figs), figs


if __name__ == "__main__":
    n = int(sys.argv[sys.argv.index("--rays") + 1]) if "--rays" in sys.argv else 400_000
    figs = measure(n, log=print)
    print(section(figs))
    for k, v in figs.items():
        print(f"{k}: {v}")
