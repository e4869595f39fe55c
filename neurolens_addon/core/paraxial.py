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

Anamorphic surfaces (core.surfaces.anamorphic) have a curvature tensor at the vertex,
K = [[c_xx, c_xy], [c_xy, c_yy]] (sag ~ h^T K h / 2, h = (x, y)), and the trace runs on
height and slope vectors h, u:
    n' u' = n u - (n' - n) K h,       h_next = h + t u'.
A surface turned by other than a multiple of 90 degrees has c_xy != 0, and rays started in the
x (or y) meridian leave it: the meridians couple. `paraxial_data(meridian=m)` traces rays
started in meridian m and reads their m components (exact per meridian when every surface's
c_xy = 0, as for every lens of revolution and every aligned anamorphic lens).
`first_order` gives the coupled system's data. Rays from infinity at entrance heights h leave
the last surface with slopes u' = -Phi h (Phi the 2x2 power matrix, image side in air; Phi is
not symmetric when turned surfaces twist the rays). Then:
- principal focal lengths: the polar decomposition Phi = R(tau) P (R a rotation by the twist
  tau, |tau| < 90 degrees; P symmetric). P's eigenvalues 1/f_1, 1/f_2 and eigenvectors are the
  principal powers and axes on the scene side: rays entering along axis i leave with slopes of
  magnitude |h| / |f_i| (the extremes over the entrance azimuth), turned by tau;
- film focal lengths: the film is read along x and y. By the symplectic (Lagrange) identity,
  a film displacement w from the rear focus sees the field angles Phi^T w, so
      f_x = 1 / |Phi^T e_x| = 1 / hypot(Phi_xx, Phi_xy),  f_y = 1 / hypot(Phi_yx, Phi_yy)
  (signed as Phi_xx, Phi_yy): the field angle per film mm along the film's x and y;
- the squeeze S = f_y / f_x. Both renderers desqueeze the film along x by S (sensor x = frame
  x / S); this S makes the desqueezed frame's angular scales along x and y equal, and it is
  the S that minimises the ratio of the frame's largest to smallest angular scale (the
  condition number of Phi^T diag(1/S, 1)); what remains of that ratio, `frame_anamorphosis`,
  is 1 when the principal film axes are x and y, and above 1 when they are turned: an x
  desqueeze cannot undo a squeeze along turned axes.
For an aligned lens (Phi diagonal) f_x and f_y are the x and y meridians' EFLs and S their
ratio; for a lens of revolution f_x = f_y = EFL and S = 1.

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


@dataclass(frozen=True)
class FirstOrder:
    """The first-order data of a lens whose meridians may couple (module docstring); rays from
    infinity, image side in air."""
    wavelength_nm: float
    power_matrix: tuple[tuple[float, float], tuple[float, float]]  # Phi (1/mm): u' = -Phi h
    f_x_mm: float            # the film's x focal length: field angle |Phi^T w| per film mm
    f_y_mm: float
    squeeze: float           # f_y / f_x: the renderers desqueeze the film along x by it
    principal_f_mm: tuple[float, float]    # (f_1, f_2) along the principal axes
    principal_axis_deg: float  # f_1's axis (scene side) from x towards y, in (-45, 45]
    twist_deg: float         # image-side principal axes = scene-side ones turned by it
    frame_anamorphosis: float  # desqueezed frame's largest / smallest angular scale (1: none)

    @property
    def aligned(self) -> bool:
        """Phi is diagonal: the principal axes are x and y, untwisted (every lens of
        revolution, every anamorphic lens whose surfaces are turned by multiples of 90
        degrees)."""
        (a, b), (c, d) = self.power_matrix
        return abs(b) + abs(c) <= 1e-12 * (abs(a) + abs(d))

    def as_dict(self) -> dict:
        return asdict(self)


def _indices(lens: Lens, wavelength_nm: float, catalog=None) -> list[float]:
    from .glass import resolve_medium
    wl = np.array([wavelength_nm], dtype=np.float64)
    return [float(resolve_medium(m, catalog).index(wl)[0]) for m in lens.media()]


_AXIS = {"x": 0, "y": 1}


def _check_meridian(meridian: str) -> None:
    if meridian not in _AXIS:
        raise ValueError(f"meridian must be 'x' or 'y', got {meridian!r}")


def _tensor(shape) -> tuple[float, float, float]:
    """(c_xx, c_xy, c_yy): the surface's vertex curvature tensor."""
    return (shape.paraxial_curvature_x, shape.paraxial_curvature_xy, shape.paraxial_curvature)


def _system(lens: Lens, n: list[float], lo: int, hi: int, reverse: bool):
    """Surfaces lo..hi-1 as ((c_xx, c_xy, c_yy), n_before, n_after, gap_after) in travel
    order (the reversed lens's curvatures negated)."""
    rows = []
    surfs = lens.surfaces
    if not reverse:
        for i in range(lo, hi):
            gap = surfs[i].thickness_mm if i < hi - 1 else 0.0
            rows.append((_tensor(surfs[i].shape), n[i], n[i + 1], gap))
    else:
        for i in range(hi - 1, lo - 1, -1):
            gap = surfs[i - 1].thickness_mm if i > lo else 0.0
            cxx, cxy, cyy = _tensor(surfs[i].shape)
            rows.append(((-cxx, -cxy, -cyy), n[i + 1], n[i], gap))
    return rows


def trace_hu(rows, x: float, y: float, ux: float, uy: float):
    """Paraxial ray (heights x, y, slopes ux, uy) through rows; returns (x, y, ux, uy) just
    after the last surface."""
    x_out, y_out = x, y
    for (cxx, cxy, cyy), n1, n2, gap in rows:
        dn = n2 - n1
        kx = x * cxx + y * cxy
        ky = x * cxy + y * cyy
        ux = (n1 * ux - kx * dn) / n2
        uy = (n1 * uy - ky * dn) / n2
        x_out, y_out = x, y
        x = x + gap * ux
        y = y + gap * uy
    return x_out, y_out, ux, uy


def trace_yu(rows, y: float, u: float, meridian: str = "y") -> tuple[float, float]:
    """Paraxial ray started in the meridian (height y, slope u) through rows; returns its
    (height, slope) components in that meridian just after the last surface."""
    k = _AXIS[meridian]
    h = (y, 0.0, u, 0.0) if k == 0 else (0.0, y, 0.0, u)
    out = trace_hu(rows, *h)
    return out[k], out[2 + k]


def paraxial_data(lens: Lens, wavelength_nm: float = WAVELENGTH_D_NM, catalog=None, *,
                  meridian: str = "y") -> ParaxialData:
    """First-order data of the y meridian (the x meridian's with meridian="x": they differ
    only for a lens with anamorphic surfaces, core.surfaces.anamorphic). Rays started in the
    meridian, their components in it (module docstring): for a lens whose turned surfaces
    couple the meridians, `first_order` gives the principal and film focal lengths."""
    _check_meridian(meridian)
    n = _indices(lens, wavelength_nm, catalog)
    ns = len(lens.surfaces)
    z = lens.vertex_z
    z_front, z_rear = float(z[0]), float(z[-1])

    fwd = _system(lens, n, 0, ns, reverse=False)
    y, u = trace_yu(fwd, 1.0, 0.0, meridian)
    if not (math.isfinite(u) and abs(u) > 1e-12):
        from .errors import LensError
        raise LensError(f"lens '{lens.name}' has no optical power (its surfaces are flat, or "
                        "their powers cancel): it forms no image", path=lens.path,
                        field="surface")
    efl = -1.0 / u
    bfd = -y / u
    rev = _system(lens, n, 0, ns, reverse=True)
    yb, ub = trace_yu(rev, 1.0, 0.0, meridian)
    ffd = -yb / ub
    rear_focal = z_rear - bfd
    front_focal = z_front + ffd

    stop = lens.stop_index
    r_stop = lens.surfaces[stop].semi_diameter_mm
    # Entrance pupil: stop seen through surfaces 0..stop-1, travelling towards the scene.
    if stop == 0:
        ep = Pupil(float(z[0]), 2.0 * r_stop)
    else:
        rows = _system(lens, n, 0, stop, reverse=True)
        flat = (0.0, 0.0, 0.0)
        rows_from_stop = [(flat, n[stop], n[stop], lens.surfaces[stop - 1].thickness_mm)] + rows
        yc, uc = trace_yu(rows_from_stop, 0.0, 0.1, meridian)
        dist = -yc / uc                                 # from surface 0, towards the scene
        ye, ue = trace_yu(rows_from_stop, r_stop, 0.0, meridian)
        ep = Pupil(z_front + dist, 2.0 * abs(ye + ue * dist))
    # Exit pupil: stop seen through surfaces stop..end (its own refraction included).
    rows = _system(lens, n, stop, ns, reverse=False)
    yc, uc = trace_yu(rows, 0.0, 0.1, meridian)
    dist = -yc / uc                                     # from the rear vertex, towards the sensor
    ye, ue = trace_yu(rows, r_stop, 0.0, meridian)
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
    sensor plane (a starting point for exact focusing), in the y (or x) meridian (module
    docstring: exact per meridian where the meridians do not couple)."""
    _check_meridian(meridian)
    if math.isinf(object_distance_mm):
        return paraxial_data(lens, wavelength_nm, catalog, meridian=meridian).rear_focal_z_mm
    n = _indices(lens, wavelength_nm, catalog)
    z0 = float(lens.vertex_z[0])
    z_obj = sensor_z_mm + object_distance_mm
    u = 1e-3
    y0 = u * (z_obj - z0)                               # height at the front vertex
    rows = _system(lens, n, 0, len(lens.surfaces), reverse=False)
    y, u_out = trace_yu(rows, y0, u, meridian)
    return float(lens.vertex_z[-1] - (-y / u_out))


def _deg(radians: float) -> float:
    return math.degrees(radians) + 0.0


def first_order(lens: Lens, wavelength_nm: float = WAVELENGTH_D_NM, catalog=None) -> FirstOrder:
    """The power matrix, film and principal focal lengths, squeeze, twist and what an x
    desqueeze leaves of the anamorphosis (module docstring), from the coupled paraxial trace
    of two rays from infinity (entrance heights e_x and e_y)."""
    n = _indices(lens, wavelength_nm, catalog)
    rows = _system(lens, n, 0, len(lens.surfaces), reverse=False)
    _, _, ux1, uy1 = trace_hu(rows, 1.0, 0.0, 0.0, 0.0)
    _, _, ux2, uy2 = trace_hu(rows, 0.0, 1.0, 0.0, 0.0)
    a, b, c, d = -ux1, -ux2, -uy1, -uy2                 # Phi = [[a, b], [c, d]]
    gx, gy = math.hypot(a, b), math.hypot(c, d)         # |Phi^T e_x|, |Phi^T e_y|
    for name, g in (("x", gx), ("y", gy)):
        if not (math.isfinite(g) and g > 1e-12):
            from .errors import LensError
            raise LensError(f"lens '{lens.name}' has no optical power along the film's {name} "
                            "(its surfaces are flat there, or their powers cancel): it forms "
                            "no image", path=lens.path, field="surface")
    f_x = math.copysign(1.0, a) / gx
    f_y = math.copysign(1.0, d) / gy
    s = f_y / f_x
    # polar decomposition Phi = R(tau) P, |tau| < 90 degrees
    sign = -1.0 if (a + d) < 0.0 else 1.0
    tau = math.atan2(sign * (c - b), sign * (a + d))
    ct, st = math.cos(tau), math.sin(tau)
    p = ct * a + st * c
    r = -st * b + ct * d
    q = 0.5 * ((ct * b + st * d) + (-st * a + ct * c))
    phi = 0.5 * math.atan2(2.0 * q, p - r)
    if phi > 0.25 * math.pi:
        phi -= 0.5 * math.pi
    elif phi <= -0.25 * math.pi:
        phi += 0.5 * math.pi
    cp, sp = math.cos(phi), math.sin(phi)
    lam1 = p * cp * cp + 2.0 * q * cp * sp + r * sp * sp
    lam2 = p * sp * sp - 2.0 * q * cp * sp + r * cp * cp
    # the desqueezed frame's map, film -> field angle: Phi^T diag(1 / S, 1); its singular
    # values' ratio from its conformal and anticonformal parts
    m00, m01, m10, m11 = a / s, c, b / s, d
    conf = math.hypot(0.5 * (m00 + m11), 0.5 * (m10 - m01))
    anti = math.hypot(0.5 * (m00 - m11), 0.5 * (m01 + m10))
    spread = (conf + anti) / abs(conf - anti) if conf != anti else math.inf
    return FirstOrder(
        wavelength_nm=float(wavelength_nm), power_matrix=((a, b), (c, d)), f_x_mm=f_x,
        f_y_mm=f_y, squeeze=s,
        principal_f_mm=(1.0 / lam1 if lam1 else math.inf, 1.0 / lam2 if lam2 else math.inf),
        principal_axis_deg=_deg(phi), twist_deg=_deg(tau), frame_anamorphosis=spread)


def squeeze(lens: Lens, wavelength_nm: float = WAVELENGTH_D_NM, catalog=None) -> float:
    """An anamorphic lens's squeeze: f_y / f_x, the film's y focal length over its x focal
    length (2 for a lens that takes twice the horizontal field onto the same film; 1 for a
    surface of revolution; `first_order`, module docstring). The film is desqueezed
    (stretched in x) by it."""
    return first_order(lens, wavelength_nm, catalog).squeeze
