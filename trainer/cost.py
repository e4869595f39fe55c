"""What a camera ray costs in the NEUROLENS engine through a learned model and through the
exact trace, measured on this machine in one run (`python -m trainer cost MODEL --lens LENS
--record` stores it in model.json's "costs", where model choice, neural.choice, reads it;
Cycles' figure beside it comes from neurolens_addon.blender.cycles_cost, which needs bpy:
benchmarks/model_costs.py records both for the shipped models).

Cost: wall-clock microseconds per camera ray: COST_RAYS camera rays of the model's domain at
its evaluation focus (trainer.evaluate.camera_rays_at_focus) in one batch, as the engine
sends a bundle, through core.trace.trace (the compiled trace where numba is there, as the
engine runs it) and through LearnedLens.trace_from_sensor (onnxruntime), best of REPEATS after
a first call (compilation, session start).
"""

from __future__ import annotations

import math
import time
from datetime import date

COST_RAYS = 1 << 16
REPEATS = 3


def engine_cost(model_dir, lens, rays: int = COST_RAYS, repeats: int = REPEATS) -> dict:
    """{"exact_us", "learned_us", "provider"} of the engine's lens stage (module docstring)."""
    from neurolens_addon.core.trace import trace
    from neurolens_addon.neural.model import LearnedLens

    from .evaluate import camera_rays_at_focus, domain_of, evaluation_focus_mm

    model = LearnedLens.load(model_dir, lens=lens)
    domain = domain_of(model.meta)
    batch, z_s = camera_rays_at_focus(lens, domain, rays, evaluation_focus_mm(lens, domain), 0)

    def exact():
        trace(lens, batch, from_sensor=True, stop_radius=domain.stop_radius_mm, sensor_z=z_s)

    def learned():
        model.trace_from_sensor(batch, z_s, stop_radius=domain.stop_radius_mm)

    best = {}
    for name, run in (("exact", exact), ("learned", learned)):
        run()                                    # compilation, session start: not a ray's cost
        best[name] = math.inf
    for _ in range(repeats):
        for name, run in (("exact", exact), ("learned", learned)):
            t0 = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - t0)
    return {"exact_us": 1e6 * best["exact"] / rays, "learned_us": 1e6 * best["learned"] / rays,
            "provider": model.provider}


def measure(model_dir, lens) -> dict:
    """model.json's "costs" entry of the engine (module docstring), stamped with the date and
    the machine."""
    from neurolens_addon.core.machine import processor
    return {"neurolens": {**engine_cost(model_dir, lens), "date": date.today().isoformat(),
                          "machine": processor()}}


def record_costs(model_dir, costs: dict) -> None:
    """Store the renderers' figures of `costs` in the model's model.json ("costs"; the other
    renderers' kept, with their own stamps), where model choice reads them; nothing measured,
    nothing written (a model.json rewritten would only make the add-on choose again)."""
    if not costs:
        return
    from .evaluate import update_model_json
    update_model_json(model_dir, lambda meta: meta.update(
        costs={**(meta.get("costs") or {}), **costs}))


def summary(costs: dict) -> str:
    parts = []
    for r in ("neurolens", "cycles"):
        c = costs.get(r)
        if c:
            parts.append(f"{r}: exact {c['exact_us']:.3g} us, learned {c['learned_us']:.3g} us "
                         f"a camera ray ({c['learned_us'] / c['exact_us']:.2f}x)")
    return "; ".join(parts) or "nothing measured"
