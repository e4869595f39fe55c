"""Ghosts: light reflected twice inside the lens, at two surfaces, before it reaches the sensor.

Surfaces are numbered 0 (front) to N - 1 (rear); medium k lies in front of surface k (medium 0
is the scene's air, medium N the air before the sensor). Light of the ghost (a, b), a < b, enters
at surface 0, is reflected back at surface b, forward again at surface a, and reaches the
sensor. A camera traces it backwards (sensor -> scene):
    surfaces N-1 .. a+1   refract                      (media k+1 -> k)
    surface a             reflect, staying in medium a+1
    surfaces a+1 .. b-1   refract, travelling -z       (media k -> k+1)
    surface b             reflect, staying in medium b
    surfaces b-1 .. 0     refract                      (media k+1 -> k)
crossing the stop once or three times, each time clipped by its shape (the aperture shows in
the ghost). Only surfaces between different media reflect (a stop or a flat in air does not).

Weight: with a coating (core.coatings) every refraction passes 1 - R and each of the two
reflections keeps R, at each ray's angle and wavelength (trace_kernel); the image path's own
weight is the product of its transmittances, so the light a ghost takes is light the image
loses (single reflections leave through the front and are lost, as in a real lens).

Energy of a ghost (ghost_energy): the mean weight of camera rays from film points spread over
the film towards the rear pupil's bound, relative to the image path's on the same rays: the
share of a uniformly bright scene's light that the ghost puts on the film. Ghosts are ranked by
it (rank_ghosts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .prescription import Lens
from .rays import Rays, RayStatus, TraceResult
from .trace import _prepare, _resolve_media
from .trace_kernel import Kernel, placed_surfaces


@dataclass(frozen=True)
class Ghost:
    """The ghost reflected at surfaces a < b (0-based, front to back)."""

    a: int
    b: int

    def __str__(self) -> str:
        return f"{self.a + 1}-{self.b + 1}"        # 1-based, as a prescription numbers them


def reflecting_surfaces(lens: Lens, catalog=None) -> list[int]:
    """Surfaces between different media (at the d line): the ones that can reflect."""
    from .glass import resolve_medium
    from .prescription import WAVELENGTH_D_NM
    media = [resolve_medium(m, catalog) for m in lens.media()]
    wl = np.array([WAVELENGTH_D_NM])
    n = [float(np.asarray(m.index(wl))[0]) for m in media]
    return [k for k in range(len(lens.surfaces)) if n[k] != n[k + 1]]


def all_ghosts(lens: Lens, catalog=None) -> list[Ghost]:
    """Every ordered pair of reflecting surfaces (a < b)."""
    s = reflecting_surfaces(lens, catalog)
    return [Ghost(a, b) for i, a in enumerate(s) for b in s[i + 1:]]


def ghost_steps(n_surfaces: int, ghost: Ghost):
    """(order, media pairs, reflect flags) of the camera-side path (module docstring)."""
    a, b = ghost.a, ghost.b
    if not 0 <= a < b < n_surfaces:
        raise ValueError(f"ghost {a}-{b}: surfaces must satisfy 0 <= a < b < {n_surfaces}")
    order, pairs, refl = [], [], []
    for k in range(n_surfaces - 1, a, -1):
        order.append(k), pairs.append((k + 1, k)), refl.append(False)
    order.append(a), pairs.append((a + 1, a)), refl.append(True)
    for k in range(a + 1, b):
        order.append(k), pairs.append((k, k + 1)), refl.append(False)
    order.append(b), pairs.append((b, b + 1)), refl.append(True)
    for k in range(b - 1, -1, -1):
        order.append(k), pairs.append((k + 1, k)), refl.append(False)
    return order, pairs, refl


def trace_ghost(lens: Lens, rays: Rays, ghost: Ghost | None, *, coating=None,
                stop_radius: float | None = None, aperture=None, catalog=None):
    """Camera rays (from the sensor, travelling +z) along a ghost's path (None: the image's
    own path), leaving the front surface: (TraceResult, weight), weight the product of the
    path's transmittances and reflectances (1 without a coating), 0 for invalid rays."""
    placed = placed_surfaces(lens)
    n = len(placed)
    if ghost is None:
        order = list(range(n - 1, -1, -1))
        pairs, refl = [(k + 1, k) for k in order], [False] * n
    else:
        order, pairs, refl = ghost_steps(n, ghost)
    kernel = Kernel(placed, order, pairs,
                    float(lens.stop_radius_mm if stop_radius is None else stop_radius),
                    aperture, reflect=refl, coating=coating)
    o, d, wl, bad = _prepare(rays, True)
    weight = np.ones(o.shape[1])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        status, died_at, alive = kernel.run(o[0], o[1], o[2], d[0], d[1], d[2], wl,
                                            _resolve_media(lens, catalog), weight=weight)
    status[bad] = RayStatus.BAD_INPUT
    valid = alive & ~bad & (d[2] > 0.0)
    valid &= np.isfinite(o).all(axis=0) & np.isfinite(d).all(axis=0)
    status[~valid & (status == 0)] = RayStatus.MISSED_SURFACE
    o[:, ~valid] = 0.0
    d[:, ~valid] = 0.0
    weight = np.where(valid, weight, 0.0)
    return TraceResult(Rays(o, d, np.where(valid, wl, 0.0)), valid, status, died_at), weight


def ghost_energy(lens: Lens, ghost: Ghost, coating, *, film_radius_mm: float,
                 stop_radius: float | None = None, aperture=None, n: int = 20000,
                 seed: int = 0, sensor_z: float = 0.0) -> float:
    """The share of a uniformly bright scene's light the ghost puts on the film, relative to
    the image path's (module docstring): same camera rays for both, aimed at a disc that
    holds the rear element."""
    from .prescription import WAVELENGTH_D_NM
    rng = np.random.default_rng(seed)
    r = film_radius_mm * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    rear = lens.surfaces[-1].semi_diameter_mm
    ra = rear * np.sqrt(rng.random(n))
    pa = 2 * np.pi * rng.random(n)
    z_rear = float(lens.rear_vertex_z)
    o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, sensor_z)])
    aim = np.stack([ra * np.cos(pa), ra * np.sin(pa), np.full(n, z_rear)])
    d = aim - o
    d /= np.linalg.norm(d, axis=0)
    wl = rng.uniform(450.0, 650.0, n) if coating is not None else np.full(n, WAVELENGTH_D_NM)
    rays = Rays(o, d, wl)
    _, w_img = trace_ghost(lens, rays, None, coating=coating, stop_radius=stop_radius,
                           aperture=aperture)
    _, w_ghost = trace_ghost(lens, rays, ghost, coating=coating, stop_radius=stop_radius,
                             aperture=aperture)
    # the cos^4 / distance^2 factors are the same ray by ray: the ratio of the sums
    return float(w_ghost.sum() / max(w_img.sum(), 1e-300))


def rank_ghosts(lens: Lens, coating, *, film_radius_mm: float, stop_radius=None,
                aperture=None, n: int = 20000) -> list[tuple[Ghost, float]]:
    """Every ghost with its energy (ghost_energy), brightest first."""
    out = [(g, ghost_energy(lens, g, coating, film_radius_mm=film_radius_mm,
                            stop_radius=stop_radius, aperture=aperture, n=n))
           for g in all_ghosts(lens)]
    return sorted(out, key=lambda p: -p[1])
