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


def _uniform_camera_rays(lens: Lens, film_radius_mm: float, n: int, seed: int,
                         sensor_z: float, dispersion: bool):
    """Camera rays from film points uniform over the film's disc towards rear_disc, with
    their irradiance weights (disc_rays)."""
    from .prescription import WAVELENGTH_D_NM
    rng = np.random.default_rng(seed)
    r = film_radius_mm * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    wl = rng.uniform(450.0, 650.0, n) if dispersion else np.full(n, WAVELENGTH_D_NM)
    return disc_rays(lens, r * np.cos(phi), r * np.sin(phi), sensor_z, rng.random(n),
                     rng.random(n), wl)


def ghost_energies(lens: Lens, ghosts, coating, *, film_radius_mm: float,
                   stop_radius: float | None = None, aperture=None, n: int = 20000,
                   seed: int = 0, sensor_z: float = 0.0) -> list[float]:
    """Each ghost's share of a uniformly bright scene's light on the film, relative to the
    image path's (module docstring): the same camera rays for all, irradiance-weighted."""
    rays, c = _uniform_camera_rays(lens, film_radius_mm, n, seed, sensor_z, True)
    kw = dict(coating=coating, stop_radius=stop_radius, aperture=aperture)
    _, w_img = trace_ghost(lens, rays, None, **kw)
    image = max(float((c * w_img).sum()), 1e-300)
    return [float((c * trace_ghost(lens, rays, g, **kw)[1]).sum()) / image for g in ghosts]


def ghost_energy(lens: Lens, ghost: Ghost, coating, **kw) -> float:
    """ghost_energies of one ghost."""
    return ghost_energies(lens, [ghost], coating, **kw)[0]


def rank_ghosts(lens: Lens, coating, *, film_radius_mm: float, stop_radius=None,
                aperture=None, n: int = 20000, sensor_z: float = 0.0) -> list[tuple[Ghost, float]]:
    """Every ghost with its energy (ghost_energies), brightest first."""
    gs = all_ghosts(lens)
    e = ghost_energies(lens, gs, coating, film_radius_mm=film_radius_mm,
                       stop_radius=stop_radius, aperture=aperture, n=n, sensor_z=sensor_z)
    return sorted(zip(gs, e), key=lambda p: -p[1])


def rear_disc(lens: Lens) -> tuple[float, float]:
    """(z, radius) of a disc on the rear vertex's plane that every ray reaching the rear
    surface within its semi-diameter crosses from a sensor point behind it (the surface's
    sag at its rim added to its semi-diameter, with a margin)."""
    sd = lens.surfaces[-1].semi_diameter_mm
    rim = float(np.nan_to_num(np.abs(lens.surfaces[-1].shape.sag(0.0, sd, clamp=True))))
    return float(lens.rear_vertex_z), 1.05 * (sd + 2.0 * rim)


def disc_rays(lens: Lens, x, y, sensor_z: float, u1, u2, wavelength_nm):
    """Camera rays from sensor points (x, y) aimed uniformly over rear_disc (the ghosts'
    sampler: a ghost leaves through any part of the rear element) and their irradiance
    weights cos^4(theta) / (dz^2 p_A), p_A = 1 / (pi R^2) (core.pupil's estimator)."""
    z_p, rad = rear_disc(lens)
    r = rad * np.sqrt(np.asarray(u1, dtype=np.float64))
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    n = r.shape[0]
    dz = z_p - sensor_z
    d = np.stack([r * np.cos(phi) - x, r * np.sin(phi) - y, np.full(n, dz)])
    d /= np.linalg.norm(d, axis=0)
    o = np.stack([np.asarray(x, float), np.asarray(y, float), np.full(n, float(sensor_z))])
    weight = d[2] ** 4 / (dz * dz) * (np.pi * rad * rad)
    return Rays(o, d, np.asarray(wavelength_nm, dtype=np.float64) * np.ones(n)), weight


_RANKED: dict = {}


def ranked_ghosts(lens: Lens, coating, *, film_radius_mm: float, stop_radius: float,
                  aperture, aperture_key: tuple, sensor_z: float = 0.0, n: int = 6000):
    """rank_ghosts, cached by value (a few seconds a lens; the frames of an animation that
    keep lens, stop, aperture and coating share it)."""
    key = (lens.content_hash(), repr(coating), round(float(film_radius_mm), 6),
           round(float(stop_radius), 9), aperture_key, round(float(sensor_z), 6), n)
    hit = _RANKED.get(key)
    if hit is None:
        hit = rank_ghosts(lens, coating, film_radius_mm=film_radius_mm, stop_radius=stop_radius,
                          aperture=aperture, n=n, sensor_z=sensor_z)
        if len(_RANKED) >= 16:
            _RANKED.pop(next(iter(_RANKED)))
        _RANKED[key] = hit
    return hit


def centre_transmittance(lens: Lens, coating, *, stop_radius=None, aperture=None,
                         sensor_z: float = 0.0, n: int = 8192, seed: int = 7) -> float:
    """T_0: the image path's mean transmittance (the coating's) for light reaching the film
    centre, irradiance-weighted over rays aimed at rear_disc: the image's own share of the
    light, against which a ghost's light is measured."""
    from .prescription import WAVELENGTH_D_NM
    rng = np.random.default_rng(seed)
    zero = np.zeros(n)
    rays, c = disc_rays(lens, zero, zero, sensor_z, rng.random(n), rng.random(n),
                        np.full(n, WAVELENGTH_D_NM))
    res, w = trace_ghost(lens, rays, None, coating=coating, stop_radius=stop_radius,
                         aperture=aperture)
    c = np.where(res.valid, c, 0.0)
    return float((c * w).sum() / max(c.sum(), 1e-300))


@dataclass(frozen=True)
class GhostPlan:
    """What a renderer needs to spend a share of its camera samples on ghosts (the engine's
    and the Cycles camera's estimator, engine/camera_rays.py): the ghosts, the probability of
    each (proportional to its energy), the share of samples, the intensity multiplier, the
    coating, the image path's centre transmittance T_0 and the ghosts' summed energy."""

    ghosts: tuple
    probability: tuple
    share: float
    intensity: float
    coating: object
    t0: float
    energy: float

    @property
    def image_factor(self) -> float:
        """kappa / (1 - s), kappa = 1 / (1 + k sum E_g): the ghosts' light comes out of the
        image's."""
        return 1.0 / ((1.0 + self.intensity * self.energy) * (1.0 - self.share))

    @property
    def ghost_factor(self) -> float:
        """k / (s T_0): a ghost sample's weight beyond its path and sampling weights, divided
        by its ghost's probability."""
        return self.intensity / (self.share * max(self.t0, 1e-12))


def ghost_plan(lens: Lens, ghost_set, settings, coating, *, stop_radius, aperture,
               sensor_z: float) -> GhostPlan | None:
    """The plan for a set of (Ghost, energy) and ghost settings (None when the set is empty)."""
    if not ghost_set:
        return None
    e = np.array([en for _g, en in ghost_set])
    return GhostPlan(tuple(g for g, _e in ghost_set), tuple(float(v) for v in e / e.sum()),
                     float(settings.share), float(settings.intensity), coating,
                     centre_transmittance(lens, coating, stop_radius=stop_radius,
                                          aperture=aperture, sensor_z=sensor_z),
                     float(e.sum()))
