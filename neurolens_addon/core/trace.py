"""Exact sequential ray trace through a lens prescription, whole ray arrays at once, float64.

`trace` sends rays from the sensor side (travelling +z; the result is each ray leaving the
front surface) or from the scene (travelling -z; the result is each ray on the sensor plane
z = sensor_z), through all surfaces or a group of them. Each surface's shape intersects the rays
and gives the normal (core.surfaces: the equations per kind); trace_kernel clips them at the
semi-diameters and the stop shape and refracts them by Snell's law in vector form,
    d' = eta d + (eta cos_i - sqrt(1 - eta^2 (1 - cos_i^2))) N,   eta = n1 / n2,
with each medium's index at each ray's wavelength (core.glass). Invalid rays carry zeros and a
RayStatus saying why, never NaN.

Directions are normalised on entry; rays whose origin lies far from the lens are first moved
along their line to 1 mm before the first surface met, where solving the intersection keeps full
precision (B^2 and AC grow as the distance squared).

Two implementations of the same trace (`kernels`; core.jit chooses by default):
- compiled (core.trace_compiled, numba, where it imports): each kind's hit and normal compiled
  (core.surfaces.kernels), blocks of rays through the whole path in parallel, bit for bit the
  numpy trace's arithmetic where the order of operations is the same (its docstring says
  where it is not);
- numpy (trace_kernel), the reference: chunks of CHUNK rays (in-place numpy arithmetic on
  cache-sized arrays), shared among threads (numpy releases the GIL inside its loops).
tests/core/test_trace_compiled.py holds the one to the other. `trace_path` (drawings) and
`intersect` are numpy only.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import jit
from .ghost_path import ghost_steps, ghost_steps_from_scene
from .prescription import WAVELENGTH_D_NM, Lens
from .rays import Rays, RayStatus, TraceResult
from .trace_kernel import Kernel, placed_surfaces

CHUNK = 32768


def _resolve_media(lens: Lens, catalog):
    from .glass import resolve_medium
    return [resolve_medium(m, catalog) for m in lens.media()]


def intersect(lens: Lens, surface_index: int, rays: Rays):
    """Ray parameter of each ray's hit with one surface of the lens, and whether it hits the
    surface's cap (the semi-diameter is not checked)."""
    g = placed_surfaces(lens)[surface_index]
    o = np.asarray(rays.o, dtype=np.float64)
    d = np.asarray(rays.d, dtype=np.float64)
    return g.shape.intersect(g.z, o, d)


def sag(lens: Lens, surface_index: int, r) -> np.ndarray:
    """Sag (mm, along the propagation direction) of one surface at radius r in its y-z section
    (NaN where the surface has no point)."""
    r = np.asarray(r, dtype=np.float64)
    return lens.surfaces[surface_index].shape.sag(0.0, r)


def _copy_rays(rays: Rays):
    """float64 copies (C order) of the origins, directions and wavelengths, checked for shape."""
    o = np.array(rays.o, dtype=np.float64, copy=True, order="C")
    d = np.array(rays.d, dtype=np.float64, copy=True, order="C")
    wl = np.array(rays.wavelength, dtype=np.float64, copy=True).reshape(-1)
    if o.ndim != 2 or o.shape[0] != 3 or d.shape != o.shape or wl.shape[0] != o.shape[1]:
        raise ValueError(f"inconsistent ray arrays: o {o.shape}, d {d.shape}, "
                         f"wavelength {wl.shape}")
    return o, d, wl


def _prepare(rays: Rays, from_sensor: bool):
    """Copy, normalise directions and flag bad input rays (core.trace_compiled.prepare: the
    same per ray)."""
    o, d, wl = _copy_rays(rays)
    with np.errstate(invalid="ignore", over="ignore"):
        norm = np.sqrt((d * d).sum(axis=0))
        bad = (~np.isfinite(o).all(axis=0) | ~np.isfinite(d).all(axis=0) | ~(norm > 0)
               | ~np.isfinite(norm))
        d /= np.where(bad, 1.0, norm)
    bad |= ~(d[2] > 0.0) if from_sensor else ~(d[2] < 0.0)
    o[:, bad] = 0.0
    d[:, bad] = 0.0
    d[2, bad] = 1.0 if from_sensor else -1.0
    wl[bad] = WAVELENGTH_D_NM
    return o, d, wl, bad


def trace_path(lens: Lens, rays: Rays, *, from_sensor: bool = True, stop_radius=None,
               aperture=None, catalog=None):
    """Hit points of a (small) ray set at every surface, in travel order, for drawings.

    Returns a list of (points (3, N), alive (N,)) after each surface; rays start where given.
    """
    placed = placed_surfaces(lens)
    nsurf = len(placed)
    order = list(range(nsurf - 1, -1, -1)) if from_sensor else list(range(nsurf))
    pairs = [(i + 1, i) for i in order] if from_sensor else [(i, i + 1) for i in order]
    kernel = Kernel(placed, order, pairs,
                     float(lens.stop_radius_mm if stop_radius is None else stop_radius), aperture)
    o, d, wl, bad = _prepare(rays, from_sensor)
    path = [(o.copy(), ~bad)]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        kernel.run(o[0], o[1], o[2], d[0], d[1], d[2], wl, _resolve_media(lens, catalog), path)
    return [(p, a & ~bad) for p, a in path], d


def _advance_to_safe_plane(lens: Lens, o, d, from_sensor: bool) -> None:
    """Move far-away origins along their rays to a plane just clear of the first surface met
    (_safe_plane_z; core.trace_compiled.prepare does the same per ray)."""
    z_safe = _safe_plane_z(lens, from_sensor)
    far = o[2] < z_safe if from_sensor else o[2] > z_safe
    if far.any():
        t = (z_safe - o[2, far]) / d[2, far]
        o[0, far] += t * d[0, far]
        o[1, far] += t * d[1, far]
        o[2, far] = z_safe


def _safe_plane_z(lens: Lens, from_sensor: bool, margin_mm: float = 1.0) -> float:
    """The plane far origins are moved to, margin_mm clear of the first surface's extreme point.

    Solving the intersection quadratic from a distant origin cancels catastrophically
    (B^2 and AC both grow as the distance squared); starting 1 mm from the surface's extreme
    point keeps full precision and changes no ray.
    """
    idx = len(lens.surfaces) - 1 if from_sensor else 0
    surf = lens.surfaces[idx]
    r = np.linspace(0.0, surf.semi_diameter_mm, 33)
    with np.errstate(invalid="ignore"):
        sg = sag(lens, idx, r)
    sg = sg[np.isfinite(sg)]
    z_v = float(lens.vertex_z[idx])
    if from_sensor:
        return z_v - max(0.0, float(sg.max(initial=0.0))) - margin_mm
    return z_v + max(0.0, float(-sg.min(initial=0.0))) + margin_mm


def _camera_path(n_surfaces: int, lo: int, hi: int, from_sensor: bool, ghost):
    """(order, media pairs, reflect flags) of the surfaces lo..hi-1 in travel order: the
    image's path, or a ghost's (core.ghost_path: from the sensor, or the light's own way)."""
    if ghost is not None:
        return (ghost_steps if from_sensor else ghost_steps_from_scene)(n_surfaces, ghost)
    if from_sensor:
        order = list(range(hi - 1, lo - 1, -1))
        return order, [(i + 1, i) for i in order], None   # after surface i is media[i + 1]
    order = list(range(lo, hi))
    return order, [(i, i + 1) for i in order], None


def trace(lens: Lens, rays: Rays, *, from_sensor: bool = True, stop_radius: float | None = None,
          aperture=None, sensor_z: float | None = 0.0, catalog=None, threads: int | None = None,
          chunk: int = CHUNK, surfaces: tuple[int, int] | None = None, ghost=None,
          coating=None, kernels: str | None = None) -> TraceResult:
    """Trace rays through the lens.

    from_sensor=True: rays start near the sensor travelling +z; the result is each ray leaving
    the front surface (origin on that surface). from_sensor=False: rays start in the scene
    travelling -z; the result is each ray arriving on the sensor plane z = sensor_z.
    stop_radius: the aperture-stop radius in mm (None: the design's full aperture);
    aperture: a shape from core.aperture with inside(x, y) in stop-normalised coordinates
    (None: circular).
    surfaces=(lo, hi): trace only prescription surfaces lo..hi-1 (a lens group, e.g. the part
    behind the stop); the result is on the last surface traced, and sensor_z=None skips the
    final propagation for scene rays.
    ghost: a core.ghost_path.Ghost: follow its path, reflected at its two surfaces, instead of
    the image's (from the sensor, or from the scene as the light goes); a ray that does not
    leave the front surface forwards (reach the sensor plane travelling -z) is invalid.
    coating: a core.coatings.Coating: the result's `weight` is each ray's product of
    the path's transmittances and reflectances (0 for invalid rays).
    kernels: "compiled" (core.trace_compiled, numba), "numpy" (the reference, trace_kernel) or
    "auto" (compiled where numba imports); None: the environment's NEUROLENS_KERNELS, else
    "auto" (core.jit). `threads` limits either; `chunk` is the numpy path's.
    """
    placed = placed_surfaces(lens)
    lo_s, hi_s = (0, len(placed)) if surfaces is None else surfaces
    if not 0 <= lo_s < hi_s <= len(placed):
        raise ValueError(f"surface range {surfaces} outside 0..{len(placed)}")
    if ghost is not None and surfaces is not None:
        raise ValueError("a ghost's path is traced through the whole lens")
    # the way a ghost's ray must leave: forwards from the front, or towards the sensor
    ghost_way = 0 if ghost is None else (1 if from_sensor else -1)
    order, pairs, reflect = _camera_path(len(placed), lo_s, hi_s, from_sensor, ghost)
    if stop_radius is None:
        stop_radius = lens.stop_radius_mm
    media = _resolve_media(lens, catalog)
    table = _compiled_table(placed, kernels)

    to_sensor = sensor_z if not from_sensor and hi_s == len(placed) else None
    if table is not None:
        from .trace_compiled import run
        o, d, wl = _copy_rays(rays)
        z_safe = _safe_plane_z(lens, from_sensor) if surfaces is None else math.nan
        status, died_at, valid, weight = run(
            table, order, pairs, reflect, media, o, d, wl, from_sensor=from_sensor,
            z_safe=z_safe, stop_radius=float(stop_radius), aperture=aperture, coating=coating,
            sensor_z=to_sensor, ghost_way=ghost_way, threads=threads)
        return TraceResult(Rays(o, d, wl), valid, status, died_at, weight)

    o, d, wl, bad = _prepare(rays, from_sensor)
    if surfaces is None:
        _advance_to_safe_plane(lens, o, d, from_sensor)
    kernel = Kernel(placed, order, pairs, float(stop_radius), aperture, reflect=reflect,
                    coating=coating)
    status, died_at, valid, weight = _run_numpy(kernel, media, o, d, wl, to_sensor,
                                                coating is not None, threads, chunk)
    return _finish(o, d, wl, bad, status, died_at, valid, weight, ghost_way)


def _compiled_table(placed, kernels):
    """The compiled trace's surface table, or None for the numpy reference (core.jit.mode, or a
    surface kind without a compiled twin)."""
    if jit.mode(kernels) != "compiled":
        return None
    from .trace_compiled import surface_table
    return surface_table(placed)


def _run_numpy(kernel, media, o, d, wl, sensor_z, weighted, threads, chunk):
    """The numpy reference over chunks of rays (in place); (status, died_at, alive, weight)."""
    n = o.shape[1]
    status = np.zeros(n, dtype=np.uint8)
    died_at = np.full(n, -1, dtype=np.int16)
    valid = np.zeros(n, dtype=bool)
    weight = np.ones(n) if weighted else None

    def work(lo: int) -> None:
        hi = min(lo + chunk, n)
        ox, oy, oz = o[0, lo:hi].copy(), o[1, lo:hi].copy(), o[2, lo:hi].copy()
        dx, dy, dz = d[0, lo:hi].copy(), d[1, lo:hi].copy(), d[2, lo:hi].copy()
        w = weight[lo:hi] if weight is not None else None      # a view: weighted in place
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            st, da, alive = kernel.run(ox, oy, oz, dx, dy, dz, wl[lo:hi], media, weight=w)
            if sensor_z is not None:
                # Propagate to the sensor plane.
                t = (sensor_z - oz) / dz
                alive &= np.isfinite(t)
                ox += t * dx
                oy += t * dy
                oz[:] = sensor_z
        o[0, lo:hi], o[1, lo:hi], o[2, lo:hi] = ox, oy, oz
        d[0, lo:hi], d[1, lo:hi], d[2, lo:hi] = dx, dy, dz
        status[lo:hi] = st
        died_at[lo:hi] = da
        valid[lo:hi] = alive

    starts = range(0, n, chunk)
    workers = threads or min(os.cpu_count() or 1, 8)
    if workers > 1 and n > chunk:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(work, starts))
    else:
        for lo in starts:
            work(lo)
    return status, died_at, valid, weight


def _finish(o, d, wl, bad, status, died_at, valid, weight, ghost_way: int) -> TraceResult:
    """Bad input rays flagged, non-finite results invalid, invalid rays zeroed
    (core.trace_compiled.finish: the same per ray). ghost_way: 1 (-1) a ghost's ray must
    leave travelling +z (-z), 0 the image's path."""
    status[bad] = RayStatus.BAD_INPUT
    died_at[bad] = -1
    valid &= ~bad
    if ghost_way:
        valid &= d[2] * ghost_way > 0.0    # a ghost's path may turn a ray back into the lens
    valid &= np.isfinite(o).all(axis=0) & np.isfinite(d).all(axis=0)
    status[~valid & (status == 0)] = RayStatus.MISSED_SURFACE
    o[:, ~valid] = 0.0
    d[:, ~valid] = 0.0
    wl = np.where(valid, wl, 0.0)
    if weight is not None:
        weight = np.where(valid, weight, 0.0)
    return TraceResult(Rays(o, d, wl), valid, status, died_at, weight)
