"""Lens drawings: a cross-section with ray fans, and spot diagrams across the field.

matplotlib is imported inside the functions (the add-on never needs it at import time) with
the non-interactive Agg backend, so this works headless.
"""

from __future__ import annotations

import math

import numpy as np

from .atomic import atomic_path
from .field import field_beam, half_field_deg
from .focus import focus_sensor_z
from .paraxial import paraxial_data
from .prescription import Lens
from .rays import Rays
from .spectrum import WAVELENGTHS_NM, wavelength_to_display_rgb
from .trace import trace, trace_path

def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _surface_profile(lens: Lens, i: int, m: int = 81):
    """The surface's y-z section: (y, z = z_vertex - sag(0, y))."""
    s = lens.surfaces[i]
    y = np.linspace(-s.semi_diameter_mm, s.semi_diameter_mm, m)
    z = lens.vertex_z[i] - s.shape.sag(0.0, y)
    return y, z


def fan_paths(lens: Lens, field_deg: float, n_rays: int, rays_per_fan: int, sensor_z: float,
              threads: int | None = None):
    """One field's meridional fan for a drawing: (z, y) of `rays_per_fan` evenly chosen rays
    of the `n_rays` that pass, at every surface from the scene to the sensor plane (arrays
    (surfaces + 1, rays)), or None when no ray passes. Pure numpy (the add-on's thumbnails
    use it too)."""
    rays = field_beam(lens, field_deg, n_rays)
    res = trace(lens, rays, from_sensor=False, sensor_z=sensor_z, threads=threads)
    idx = np.flatnonzero(res.valid)
    if idx.size == 0:
        return None
    pick = idx[np.linspace(0, idx.size - 1, min(rays_per_fan, idx.size)).astype(int)]
    sub = Rays(rays.o[:, pick], rays.d[:, pick], rays.wavelength[pick])
    path, _ = trace_path(lens, sub, from_sensor=False)
    pts = [p for p, _ in path] + [res.rays.o[:, pick]]
    return np.array([p[2] for p in pts]), np.array([p[1] for p in pts])


def lens_diagram(lens: Lens, out_path: str, *, fields=(0.0, 0.5, 0.75, 1.0), rays_per_fan=9,
                 sensor_z: float = 0.0, dpi: int = 150) -> None:
    """Cross-section (y-z) of the lens with fans of rays from several field angles."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 5))
    # Glass elements: fill between consecutive surfaces with glass after the first.
    for i, s in enumerate(lens.surfaces[:-1]):
        if s.material.is_air:
            continue
        y1, z1 = _surface_profile(lens, i)
        y2, z2 = _surface_profile(lens, i + 1)
        sd = min(lens.surfaces[i].semi_diameter_mm, lens.surfaces[i + 1].semi_diameter_mm)
        k1, k2 = np.abs(y1) <= sd + 1e-9, np.abs(y2) <= sd + 1e-9
        poly_z = np.concatenate([z1[k1], z2[k2][::-1]])
        poly_y = np.concatenate([y1[k1], y2[k2][::-1]])
        ax.fill(poly_z, poly_y, color="#bcd7ee", edgecolor="#2a5d8a", lw=0.8, zorder=1)
    for i, s in enumerate(lens.surfaces):
        y, z = _surface_profile(lens, i)
        if s.stop:
            zs = lens.vertex_z[i]
            top = 1.4 * s.semi_diameter_mm
            ax.plot([zs, zs], [s.semi_diameter_mm, top], color="k", lw=2.5)
            ax.plot([zs, zs], [-s.semi_diameter_mm, -top], color="k", lw=2.5)
        elif s.material.is_air and (i == 0 or lens.surfaces[i - 1].material.is_air):
            ax.plot(z, y, color="#2a5d8a", lw=0.8)
    # Ray fans.
    hf = half_field_deg(lens)
    colours = plt.get_cmap("viridis")(np.linspace(0.05, 0.85, len(fields)))
    for frac, col in zip(fields, colours):
        field = frac * hf * (0.98 if frac == 1.0 else 1.0)
        fan = fan_paths(lens, field, 401, rays_per_fan, sensor_z)
        if fan is None:
            continue
        zz, yy = fan
        ax.plot(zz, yy, color=col, lw=0.6, zorder=2)
        ax.plot([], [], color=col, label=f"{field:.1f} deg")
    ax.axhline(0.0, color="0.6", lw=0.5, ls="--")
    ax.axvline(sensor_z, color="k", lw=1.0)
    ax.set_xlabel("z (mm, scene to the right)")
    ax.set_ylabel("y (mm)")
    pd = paraxial_data(lens)
    ax.set_title(f"{lens.name}: EFL {pd.efl_mm:.2f} mm, F/{pd.f_number:.2f}")
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8, title="field")
    fig.tight_layout()
    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=_image_format(out_path))
    plt.close(fig)


def _image_format(path) -> str:
    """matplotlib's format for `path` (its suffix; PNG without one): the temporary file it is
    written to first (core.atomic) has another suffix."""
    import os
    return os.path.splitext(str(path))[1].lstrip(".").lower() or "png"


def spot_data(lens: Lens, field_deg: float, focus_sensor: float, wavelengths, n: int = 2500,
              stop_radius=None):
    """Sensor hits (x, y, wavelength) of a parallel beam from one field angle."""
    xs, ys, ws = [], [], []
    for wl in wavelengths:
        rays = field_beam(lens, field_deg, n, wl, two_d=False)
        res = trace(lens, rays, from_sensor=False, sensor_z=focus_sensor, stop_radius=stop_radius)
        v = res.valid
        xs.append(res.rays.o[0, v])
        ys.append(res.rays.o[1, v])
        ws.append(np.full(int(v.sum()), wl))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(ws)


def spot_diagram(lens: Lens, out_path: str, *, focus_mm: float = math.inf,
                 fields=(0.0, 0.35, 0.7, 1.0), dpi: int = 150) -> dict:
    """Spot diagrams at several field angles and wavelengths (F, d, C and g lines), each centred
    on its d-line centroid, with RMS radii in micrometres. Returns the RMS radii per field."""
    plt = _pyplot()
    z_s = focus_sensor_z(lens, focus_mm)
    hf = half_field_deg(lens)
    wls = [WAVELENGTHS_NM[k] for k in ("g", "F", "d", "C")]
    fig, axes = plt.subplots(1, len(fields), figsize=(3.2 * len(fields), 3.6))
    rms = {}
    for ax, frac in zip(np.atleast_1d(axes), fields):
        field = frac * hf * (0.98 if frac == 1.0 else 1.0)
        x, y, w = spot_data(lens, field, z_s, wls)
        if x.size == 0:
            ax.set_title(f"{field:.1f} deg: vignetted")
            continue
        dline = w == WAVELENGTHS_NM["d"]
        cx, cy = (x[dline].mean(), y[dline].mean()) if dline.any() else (x.mean(), y.mean())
        dx_um, dy_um = (x - cx) * 1000.0, (y - cy) * 1000.0
        r = float(np.sqrt(np.mean(dx_um ** 2 + dy_um ** 2)))
        rms[float(field)] = r
        ax.scatter(dx_um, dy_um, s=0.5, c=wavelength_to_display_rgb(w), linewidths=0)
        lim = max(5.0, 1.1 * float(np.max(np.hypot(dx_um, dy_um))))
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_title(f"{field:.1f} deg\nRMS {r:.1f} um, y = {cy:.2f} mm", fontsize=9)
        ax.set_xlabel("um")
    focus_txt = "infinity" if math.isinf(focus_mm) else f"{focus_mm / 1000.0:g} m"
    fig.suptitle(f"{lens.name}: spots at focus {focus_txt} (g, F, d, C lines)", fontsize=10)
    fig.tight_layout()
    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=_image_format(out_path))
    plt.close(fig)
    return rms
