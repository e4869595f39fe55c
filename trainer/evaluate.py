"""Accuracy and speed of a learned lens against the exact trace, on the same rays in one run.

* relative_error_pct: the paper's Eq. 4, sqrt(sum |Phi - T|^2 / sum |T|^2) x 100, over output
  rays (x', y', u', v', w') on Pi_2 of held-out sensor rays (a fresh Latin-hypercube draw,
  seed + 1000, never seen in training) valid in both the exact and the learned lens.
* image_error_um_p50 / p99: the sensor focused at 2 m (from the sensor; at the closest focus
  for a lens that focuses no nearer; a model trained for a focus range without it: the middle
  of its range); camera rays from film points of its
  domain (disc or ring, at its stop radius) through the rear pupil (an anamorphic lens: aimed
  over the rear element's disc, core.pupil.RearDiscSampler); where the learned and the exact ray meet the object plane at
  2 m, their distance divided by the lateral magnification, so it reads as a displacement on the
  sensor (micrometres).
* onnx_rays_per_s / exact_rays_per_s: the same N camera rays through onnxruntime (the whole
  two-stage model, stop test included) and through the float64 numpy trace, best of 3.
"""

from __future__ import annotations

import time

import numpy as np

from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.irf import propagate_to_z
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.pupil import camera_ray_sampler
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace

from .data import Domain, sensor_rays


def _exact_front_rays(lens: Lens, rays: Rays, output_z: float, stop_radius=None):
    res = trace(lens, rays, stop_radius=stop_radius)
    o = propagate_to_z(res.rays.o, res.rays.d, output_z)
    return o, res.rays.d, res.valid


def _need_valid(valid: np.ndarray, what: str) -> None:
    """ModelError when no ray passes both the lens and the model: nothing to measure."""
    if not valid.any():
        from neurolens_addon.core.errors import ModelError
        raise ModelError(f"no ray passes both the exact lens and the model, so the {what} "
                         "cannot be measured (is the model for this lens and focus range?)")


def relative_error(model, lens: Lens, domain: Domain, n: int, seed: int) -> tuple[float, int]:
    rng = np.random.default_rng(seed + 1000)
    o, d, wl = sensor_rays(lens, domain, n, rng)
    rays = Rays(o, d, wl)
    eo, ed, ev = _exact_front_rays(lens, rays, model.planes["output_z"], domain.stop_radius_mm)
    sensor_z = o[2]
    lres = model.trace_from_sensor(rays, sensor_z=sensor_z)
    v = ev & lres.valid
    _need_valid(v, "relative error")
    T = np.concatenate([eo[:2, v], ed[:, v]]).T
    P = np.concatenate([lres.rays.o[:2, v], lres.rays.d[:, v]]).T
    return float(np.sqrt(((P - T) ** 2).sum() / (T ** 2).sum())), int(v.sum())


def evaluation_focus_mm(lens: Lens, domain: Domain) -> float:
    """core.focus.evaluation_focus_mm for the model's focus range."""
    from neurolens_addon.core.focus import evaluation_focus_mm as at
    return at(lens, domain.sensor_z_range)


def camera_rays_at_focus(lens: Lens, domain: Domain, n: int, focus_mm: float, seed: int):
    z_s = focus_sensor_z(lens, focus_mm)
    film_r = domain.film_radius_mm
    sampler = camera_ray_sampler(lens, film_r, sensor_z=z_s, stop_radius=domain.stop_radius_mm)
    rng = np.random.default_rng(seed + 2000)
    r0 = domain.film_radius_min_mm
    r = np.sqrt(r0 * r0 + (film_r * film_r - r0 * r0) * rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    u = rng.random((3, n))
    lo, hi = domain.wavelength_range_nm
    wl = rng.uniform(lo, hi, n) if domain.dispersion else np.full(n, lo)
    s = sampler.sample(r * np.cos(phi), r * np.sin(phi), u[0], u[1], u[2], wl)
    return s.rays, z_s


def image_error_um(model, lens: Lens, domain: Domain, n: int, seed: int):
    focus = evaluation_focus_mm(lens, domain)
    rays, z_s = camera_rays_at_focus(lens, domain, n, focus, seed)
    z_obj = z_s + focus
    eo, ed, ev = _exact_front_rays(lens, rays, model.planes["output_z"], domain.stop_radius_mm)
    lres = model.trace_from_sensor(rays, sensor_z=z_s)
    v = ev & lres.valid
    _need_valid(v, "image error")
    pe = propagate_to_z(eo[:, v], ed[:, v], z_obj)
    pl = propagate_to_z(lres.rays.o[:, v], lres.rays.d[:, v], z_obj)
    pd = paraxial_data(lens)
    s_o = z_obj - pd.front_principal_z_mm
    magnification = pd.efl_mm / (s_o - pd.efl_mm)
    err_um = np.hypot(pe[0] - pl[0], pe[1] - pl[1]) * magnification * 1000.0
    return float(np.percentile(err_um, 50)), float(np.percentile(err_um, 99)), int(v.sum())


def speed(model, lens: Lens, domain: Domain, n: int, seed: int, repeats: int = 3):
    rays, z_s = camera_rays_at_focus(lens, domain, n, evaluation_focus_mm(lens, domain), seed)
    t_onnx = t_exact = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        model.trace_from_sensor(rays, sensor_z=z_s)
        t_onnx = min(t_onnx, time.perf_counter() - t0)
        t0 = time.perf_counter()
        trace(lens, rays, stop_radius=domain.stop_radius_mm)
        t_exact = min(t_exact, time.perf_counter() - t0)
    return n / t_onnx, n / t_exact


def domain_of(meta: dict) -> Domain:
    """The training domain recorded in a model.json."""
    dd = meta["domain"]
    return Domain(dd["film_radius_mm"], tuple(dd["sensor_z_range"]),
                  tuple(dd["wavelength_range_nm"]), bool(dd["dispersion"]),
                  float(dd.get("film_radius_min_mm", 0.0)), dd.get("stop_radius_mm"))


def record_evaluation(model_dir, result: dict) -> None:
    """Store an evaluation in the model's model.json ("evaluation"), where model choice
    (neural.choice) reads a model's measured error and speed."""
    update_model_json(model_dir, lambda meta: meta.update(evaluation=result))


def update_model_json(model_dir, change) -> None:
    """Rewrite the model's model.json (checked, atomically) after `change(meta)` edits its
    dict in place: the one writer of the figures the trainer records."""
    from neurolens_addon.core.atomic import atomic_write_text
    from neurolens_addon.core.jsonout import dumps_strict
    from neurolens_addon.neural.modelfile import MODEL_FILE, read_model_json
    directory, meta, _guards, _files = read_model_json(model_dir)
    change(meta)
    atomic_write_text(directory / MODEL_FILE, dumps_strict(meta))


def evaluate_model(model, lens: Lens, n: int = 1_170_000, seed: int = 0,
                   speed_rays: int | None = None) -> dict:
    domain = domain_of(model.meta)
    rel, n_rel = relative_error(model, lens, domain, n, seed)
    p50, p99, n_img = image_error_um(model, lens, domain, n, seed)
    onnx_rps, exact_rps = speed(model, lens, domain, speed_rays or n, seed)
    return {"relative_error_pct": 100.0 * rel, "relative_error_rays": n_rel,
            "image_error_um_p50": p50, "image_error_um_p99": p99, "image_error_rays": n_img,
            "onnx_rays_per_s": onnx_rps, "exact_rays_per_s": exact_rps,
            "speedup": onnx_rps / exact_rps, "provider": getattr(model, "provider", "?")}
