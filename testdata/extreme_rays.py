"""Camera rays at the extremes of what a lens is asked, for the robustness counts
(benchmarks/robustness.py) and the extreme-ray tests (tests/neural/test_extremes.py).

For a lens and a count n, rays from the film (origins on the sensor plane, directions toward
+z) in six equal families, each drawn at both ends of the focus range (infinity and closest
focus) and at the wavelength ends 380 and 780 nm, some through a stop closed to f/64:
  grazing         directions up to 89.9 deg from the axis;
  semi-diameters  aimed at the rim of every surface (radius = its semi-diameter, any azimuth);
  beyond field    film points out to 1.5 x the image circle;
  rear            aimed across a disc 1.5 x the stop's size 1 mm behind the rear vertex;
  axis            film points on and next to the axis (r = 0, 1e-12 mm);
  tiny            direction components near the float limits (1e-30 .. 1e-300 off axis).
"""

from __future__ import annotations

import math

import numpy as np

from neurolens_addon.core.field import design_film_radius_mm
from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.rays import Rays

FAMILIES = ("grazing", "semi-diameters", "beyond field", "rear", "axis", "tiny")


def _unit(d):
    return d / np.linalg.norm(d, axis=0)


def extreme_rays(lens: Lens, n: int, seed: int = 0):
    """(rays, sensor_z (N,), stop_radius per half: (full, f/64), family index (N,))."""
    rng = np.random.default_rng(seed)
    k = n // len(FAMILIES)
    film = design_film_radius_mm(lens)
    z_inf = focus_sensor_z(lens, math.inf)
    z_near = focus_sensor_z(lens, closest_focus_mm(lens))
    rear = lens.rear_vertex_z
    out_o, out_d, fam = [], [], []
    for f, name in enumerate(FAMILIES):
        phi = rng.uniform(0, 2 * np.pi, k)
        if name == "grazing":
            r = film * np.sqrt(rng.random(k))
            theta = np.radians(rng.uniform(60.0, 89.9, k))
            psi = rng.uniform(0, 2 * np.pi, k)
            d = np.stack([np.sin(theta) * np.cos(psi), np.sin(theta) * np.sin(psi),
                          np.cos(theta)])
        else:
            r = {"semi-diameters": film * np.sqrt(rng.random(k)),
                 "beyond field": 1.5 * film * np.sqrt(rng.random(k)),
                 "rear": film * np.sqrt(rng.random(k)),
                 "axis": rng.choice([0.0, 1e-12], k),
                 "tiny": film * np.sqrt(rng.random(k))}[name]
            if name == "semi-diameters":
                s = rng.integers(0, len(lens.surfaces), k)
                sd = np.array([sf.semi_diameter_mm for sf in lens.surfaces])[s]
                z = np.asarray(lens.vertex_z)[s]
                tgt = np.stack([sd * np.cos(phi + 1.0), sd * np.sin(phi + 1.0), z])
            elif name == "tiny":
                eps = 10.0 ** rng.uniform(-300, -30, k)
                tgt = None
                d = np.stack([eps, -eps, np.ones(k)])
            else:
                a = lens.stop_radius_mm * 1.5 * np.sqrt(rng.random(k))
                b = rng.uniform(0, 2 * np.pi, k)
                tgt = np.stack([a * np.cos(b), a * np.sin(b), np.full(k, rear + 1.0)])
            o = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(k)])
            if name != "tiny":
                d = tgt - o
        out_o.append(np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(k)]))
        out_d.append(_unit(d) if name != "tiny" else d)
        fam.append(np.full(k, f))
    o = np.concatenate(out_o, axis=1)
    d = np.concatenate(out_d, axis=1)
    fam = np.concatenate(fam)
    m = o.shape[1]
    zs = np.where(rng.random(m) < 0.5, z_inf, z_near)
    o[2] = zs
    wl = rng.choice([380.0, 780.0], m)
    return Rays(o, d, wl), zs, fam


def count_bad(rays_out, valid) -> int:
    """Valid rays with a NaN or infinite component."""
    o, d = rays_out.o[:, valid], rays_out.d[:, valid]
    return int((~np.isfinite(o)).any(axis=0).sum() + (~np.isfinite(d)).any(axis=0).sum())
