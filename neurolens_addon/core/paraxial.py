"""First-order (paraxial) data of a lens from y-nu ray traces.

Along the travel direction (scene -> sensor, lens-space -z), at each surface with paraxial
curvature c (its shape's paraxial_curvature: 1/R, plus 2 A_2 for an asphere's r^2 term) between
indices n and n', and over each gap t:
    n' u' = n u - y c (n' - n)        (refraction)
    y_next = y + t u'                 (transfer)
A ray from infinity (y = 1, u = 0) gives the effective focal length f = -1 / u'_last and the
back focal distance BFD = -y_last / u'_last; the same trace through the reversed lens gives the
front focal distance. Principal planes sit f from the focal points. The entrance (exit) pupil
is the stop imaged through the surfaces in front of (behind) it: a ray from the stop centre
locates it, a ray from the stop edge parallel to the axis sizes it.

Lens-space positions returned here are z values (+z towards the scene, design image plane 0).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .prescription import WAVELENGTH_D_NM, Lens


@dataclass(frozen=True)
class Pupil:
    z_mm: float
    diameter_mm: float


@dataclass(frozen=True)
class ParaxialData:
    wavelength_nm: float
    efl_mm: float
    bfd_mm: float            # rear vertex to rear focal point (towards the sensor positive)
    ffd_mm: float            # front vertex to front focal point (towards the scene positive)
    rear_focal_z_mm: float
    front_focal_z_mm: float
    rear_principal_z_mm: float
    front_principal_z_mm: float
    entrance_pupil: Pupil
    exit_pupil: Pupil
    f_number: float          # efl / entrance pupil diameter (object at infinity)

    def as_dict(self) -> dict:
        return asdict(self)


def _indices(lens: Lens, wavelength_nm: float, catalog=None) -> list[float]:
    from .glass import resolve_medium
    wl = np.array([wavelength_nm], dtype=np.float64)
    return [float(resolve_medium(m, catalog).index(wl)[0]) for m in lens.media()]


def _curvature(shape, meridian: str) -> float:
    return shape.paraxial_curvature if meridian == "y" else shape.paraxial_curvature_x


def _system(lens: Lens, n: list[float], lo: int, hi: int, reverse: bool, meridian: str = "y"):
    """Surfaces lo..hi-1 as (curvature, n_before, n_after, gap_after) in travel order, the
    curvatures of the y (or x) meridian."""
    rows = []
    surfs = lens.surfaces
    if not reverse:
        for i in range(lo, hi):
            gap = surfs[i].thickness_mm if i < hi - 1 else 0.0
            rows.append((_curvature(surfs[i].shape, meridian), n[i], n[i + 1], gap))
    else:
        for i in range(hi - 1, lo - 1, -1):
            gap = surfs[i - 1].thickness_mm if i > lo else 0.0
            rows.append((-_curvature(surfs[i].shape, meridian), n[i + 1], n[i], gap))
    return rows


def trace_yu(rows, y: float, u: float) -> tuple[float, float]:
    """Paraxial ray through rows; returns (y, u) just after the last surface."""
    for c, n1, n2, gap in rows:
        u = (n1 * u - y * c * (n2 - n1)) / n2
        y_out = y
        y = y + gap * u
    return y_out, u


def paraxial_data(lens: Lens, wavelength_nm: float = WAVELENGTH_D_NM, catalog=None, *,
                  meridian: str = "y") -> ParaxialData:
    """First-order data of the y meridian (the x meridian's with meridian="x": they differ
    only for a lens with anamorphic surfaces, core.surfaces.anamorphic)."""
    if meridian not in ("x", "y"):
        raise ValueError(f"meridian must be 'x' or 'y', got {meridian!r}")
    n = _indices(lens, wavelength_nm, catalog)
    ns = len(lens.surfaces)
    z = lens.vertex_z
    z_front, z_rear = float(z[0]), float(z[-1])

    fwd = _system(lens, n, 0, ns, reverse=False, meridian=meridian)
    y, u = trace_yu(fwd, 1.0, 0.0)
    if not (math.isfinite(u) and abs(u) > 1e-12):
        from .errors import LensError
        raise LensError(f"lens '{lens.name}' has no optical power (its surfaces are flat, or "
                        "their powers cancel): it forms no image", path=lens.path,
                        field="surface")
    efl = -1.0 / u
    bfd = -y / u
    rev = _system(lens, n, 0, ns, reverse=True, meridian=meridian)
    yb, ub = trace_yu(rev, 1.0, 0.0)
    ffd = -yb / ub
    rear_focal = z_rear - bfd
    front_focal = z_front + ffd

    stop = lens.stop_index
    r_stop = lens.surfaces[stop].semi_diameter_mm
    # Entrance pupil: stop seen through surfaces 0..stop-1, travelling towards the scene.
    if stop == 0:
        ep = Pupil(float(z[0]), 2.0 * r_stop)
    else:
        rows = _system(lens, n, 0, stop, reverse=True, meridian=meridian)
        rows_from_stop = [(0.0, n[stop], n[stop], lens.surfaces[stop - 1].thickness_mm)] + rows
        yc, uc = trace_yu(rows_from_stop, 0.0, 0.1)
        dist = -yc / uc                                 # from surface 0, towards the scene
        ye, ue = trace_yu(rows_from_stop, r_stop, 0.0)
        ep = Pupil(z_front + dist, 2.0 * abs(ye + ue * dist))
    # Exit pupil: stop seen through surfaces stop..end (its own refraction included).
    rows = _system(lens, n, stop, ns, reverse=False, meridian=meridian)
    yc, uc = trace_yu(rows, 0.0, 0.1)
    dist = -yc / uc                                     # from the rear vertex, towards the sensor
    ye, ue = trace_yu(rows, r_stop, 0.0)
    xp = Pupil(z_rear - dist, 2.0 * abs(ye + ue * dist))

    return ParaxialData(
        wavelength_nm=float(wavelength_nm), efl_mm=efl, bfd_mm=bfd, ffd_mm=ffd,
        rear_focal_z_mm=rear_focal, front_focal_z_mm=front_focal,
        rear_principal_z_mm=rear_focal + efl, front_principal_z_mm=front_focal - efl,
        entrance_pupil=ep, exit_pupil=xp, f_number=efl / ep.diameter_mm)


def working_f_number(lens: Lens, object_distance_mm: float, sensor_z_mm: float = 0.0,
                     wavelength_nm: float = WAVELENGTH_D_NM, catalog=None) -> float:
    """1 / (2 |u'|) of the paraxial marginal ray from an axial object point (distance from the
    sensor plane; inf for infinity) that fills the entrance pupil."""
    data = paraxial_data(lens, wavelength_nm, catalog)
    if math.isinf(object_distance_mm):
        return data.f_number
    n = _indices(lens, wavelength_nm, catalog)
    z_obj = sensor_z_mm + object_distance_mm
    r_ep = data.entrance_pupil.diameter_mm / 2.0
    # travel coordinate p = -z: y(p) = u (p - p_obj) reaches r_ep at the entrance pupil
    u = r_ep / (z_obj - data.entrance_pupil.z_mm)
    y0 = u * (z_obj - float(lens.vertex_z[0]))
    _, u_out = trace_yu(_system(lens, n, 0, len(lens.surfaces), reverse=False), y0, u)
    return 1.0 / (2.0 * abs(u_out))


def paraxial_magnification(lens: Lens, object_distance_mm: float, sensor_z_mm: float = 0.0,
                           wavelength_nm: float = WAVELENGTH_D_NM, catalog=None) -> float:
    """Lateral magnification of an object at the given distance from the sensor plane, onto
    its paraxial image: by the Lagrange invariant m = u / u' of a ray from the axial object
    point (object and image in air); negative for the inverted real image."""
    if math.isinf(object_distance_mm):
        return 0.0
    n = _indices(lens, wavelength_nm, catalog)
    u = 1e-3
    y0 = u * (sensor_z_mm + object_distance_mm - float(lens.vertex_z[0]))
    _, u_out = trace_yu(_system(lens, n, 0, len(lens.surfaces), reverse=False), y0, u)
    return float(u / u_out) if u_out != 0.0 else math.inf   # (the front focal plane)


def paraxial_image_z(lens: Lens, object_distance_mm: float, sensor_z_mm: float = 0.0,
                     wavelength_nm: float = WAVELENGTH_D_NM, catalog=None, *,
                     meridian: str = "y") -> float:
    """Lens-space z of the paraxial image of an axial object at the given distance from the
    sensor plane (a starting point for exact focusing), in the y (or x) meridian."""
    if math.isinf(object_distance_mm):
        return paraxial_data(lens, wavelength_nm, catalog, meridian=meridian).rear_focal_z_mm
    n = _indices(lens, wavelength_nm, catalog)
    z0 = float(lens.vertex_z[0])
    z_obj = sensor_z_mm + object_distance_mm
    u = 1e-3
    y0 = u * (z_obj - z0)                               # height at the front vertex
    rows = _system(lens, n, 0, len(lens.surfaces), reverse=False, meridian=meridian)
    y, u_out = trace_yu(rows, y0, u)
    return float(lens.vertex_z[-1] - (-y / u_out))


def squeeze(lens: Lens, wavelength_nm: float = WAVELENGTH_D_NM, catalog=None) -> float:
    """An anamorphic lens's squeeze: f_y / f_x, the y meridian's focal length over the x
    meridian's (2 for a lens that takes twice the horizontal field onto the same film; 1 for a
    surface of revolution). The film is desqueezed (stretched in x) by it."""
    fy = paraxial_data(lens, wavelength_nm, catalog).efl_mm
    fx = paraxial_data(lens, wavelength_nm, catalog, meridian="x").efl_mm
    return fy / fx
