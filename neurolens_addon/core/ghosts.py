"""Ghosts: light reflected twice inside the lens, at two surfaces, before it reaches the sensor.

The ghost (a, b), a < b, is reflected back at surface b and forward again at surface a; its
path, as a camera traces it backwards, is core.ghost_path's, followed by core.trace
(trace(..., ghost=Ghost(a, b))), crossing the stop once or three times, each time clipped by
its shape (the aperture shows in the ghost). Only surfaces between different media reflect (a
stop or a flat in air does not).

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

from .ghost_path import Ghost
from .lru import cache
from .prescription import Lens
from .pupil import disc_rays
from .trace import trace


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


def _uniform_camera_rays(lens: Lens, film_radius_mm: float, n: int, seed: int,
                         sensor_z: float, dispersion: bool):
    """Camera rays from film points uniform over the film's disc towards core.pupil.rear_disc,
    with their irradiance weights (core.pupil.disc_rays)."""
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
    image = max(float((c * path_weight(lens, rays, None, **kw)).sum()), 1e-300)
    return [float((c * path_weight(lens, rays, g, **kw)).sum()) / image for g in ghosts]


def path_weight(lens: Lens, rays, ghost: Ghost | None, *, coating, **kw) -> np.ndarray:
    """Each camera ray's weight along a ghost's path (None: the image's): the product of the
    coating's transmittances and reflectances, 0 where the ray does not pass (core.trace)."""
    res = trace(lens, rays, ghost=ghost, coating=coating, **kw)
    return res.weight if res.weight is not None else res.valid.astype(np.float64)


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


_RANKED = cache(16)


def ranked_ghosts(lens: Lens, coating, *, film_radius_mm: float, stop_radius: float,
                  aperture, sensor_z: float = 0.0, n: int = 6000):
    """rank_ghosts, cached by value (a few seconds a lens; the frames of an animation that
    keep lens, stop, aperture and coating share it)."""
    from .aperture import aperture_key
    key = (lens.content_hash(), repr(coating), round(float(film_radius_mm), 6),
           round(float(stop_radius), 9), aperture_key(aperture), round(float(sensor_z), 6), n)
    hit = _RANKED.get_lru(key)
    if hit is None:
        hit = _RANKED.put(key, rank_ghosts(lens, coating, film_radius_mm=film_radius_mm,
                                           stop_radius=stop_radius, aperture=aperture, n=n,
                                           sensor_z=sensor_z))
    return hit


def centre_transmittance(lens: Lens, coating, *, stop_radius=None, aperture=None,
                         sensor_z: float = 0.0) -> float:
    """T_0: the image path's mean transmittance (the coating's) for light reaching the film
    centre, irradiance-weighted (core.pupil.centre_irradiance with and without the coating):
    the image's own share of the light, against which a ghost's light is measured."""
    from .pupil import cached_centre_irradiance
    kw = dict(sensor_z=sensor_z, stop_radius=lens.stop_radius_mm if stop_radius is None
              else stop_radius, aperture=aperture)
    return (cached_centre_irradiance(lens, coating=coating, **kw)
            / cached_centre_irradiance(lens, **kw))


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
