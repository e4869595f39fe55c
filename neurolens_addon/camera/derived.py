"""The derived camera: every optical value a renderer needs, computed once from a LensSetup.

As pbrt-v4's camera constructor does: camera.resolve decides (lens, model, f-number, focus,
aperture, film), and `DerivedCamera(setup)` derives what follows from those decisions, once.
The NeuroLens engine uses these values as they are; the Cycles camera (cycles.spec) copies them
and cycles/ only writes them into shader text. Nothing else derives them.

  lens               the lens as configured: its zoom gaps, focusing groups and the stop's
                     size at this zoom (core.variable_gaps.lens_at); its own f_number is its
                     design f-number there
  stop radius        R = R_0 N_0 / N on that lens (core.aperture.stop_radius_of)
  sensor z           the plane that focuses the set-up's distance at R (camera.focusing)
  lens film          the film the lens images onto: an anamorphic lens's is 1 / squeeze as
                     wide as the desqueezed frame (core.film.Film.on_lens); its radius bounds
                     every sampler and the ghosts' ranking
  aperture key       core.aperture.aperture_key
  centre irradiance  E_0 (core.pupil.centre_irradiance): every renderer divides its camera
                     weights by it, so the film centre reads the scene's radiance
  sampler            the engine's camera-ray sampler (core.pupil.camera_ray_sampler)
  shader aperture    the stop shape a Cycles shader embeds (core.aperture.shader_shape: a
                     large mask area-averaged down) and the E_0 of that shape
  slab pupil         the Cycles shader's sampler (core.pupil_slabs; None for an anamorphic
                     lens, whose shader aims over the rear disc)
  ghost plan         core.ghosts.GhostPlan of the brightest ghosts (None without ghosts)
  follow tables      a camera following Blender's animated focus and f-number (Cycles):
                     z_s and log E_0 over K focus points uniform in 1 / d and M f-numbers
                     uniform in log N, each point derived exactly as a still camera's, and
                     its slab pupil over every sensor plane of the range
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..core.aperture import aperture_key, shader_shape, stop_radius_of
from .lru import cache

#: focus points (uniform in 1 / distance) and f-numbers (uniform in log N) of follow tables
FOCUS_POINTS = 17
F_NUMBER_POINTS = 5
#: sensor planes a follow camera's slabs are traced from (the ends and the middle of its
#: range): the passing region moves smoothly with the sensor, and the slabs' half-cell margin
#: holds it
SLAB_PLANES = 3
#: the engine's pupil grids: bands about 1 mm of film radius wide (4..24), 48 x 48 cells each
ENGINE_GRID = 48


@dataclass(frozen=True)
class FollowTables:
    """What a camera that follows Blender's animated focus and f-number reads per frame."""

    t: np.ndarray               # (K,) 1 / d (1/mm), uniform
    f_numbers: np.ndarray       # (M,) uniform in log N
    stop_radii: np.ndarray      # (M,) R at each f-number: R N is the same for every N
    sensor_z: np.ndarray        # (K, M) the focusing sensor plane (mm)
    log_centre: np.ndarray      # (K, M) log E_0
    slab_planes: tuple          # sensor planes the slabs cover (the first is the table's own)


class DerivedCamera:
    """The optical values of one LensSetup (module docstring): LensSetup.derived."""

    def __init__(self, setup):
        self.setup = setup
        self.model = setup.model
        self.model_dir = setup.model_dir
        self.lens = setup.lens
        self.table = setup.entry.table       # a lens known only from a ray table
        self.design_f_number = float(self.lens.f_number)
        self.f_number = float(setup.f_number)
        self.stop_radius_mm = float(setup.stop_radius_mm)
        self.sensor_z_mm = float(setup.sensor_z_mm)
        self.film = setup.film
        self.squeeze = float(setup.squeeze)
        self.lens_film = self.film.on_lens(self.squeeze)
        self.film_radius_mm = float(self.lens_film.radius_mm)
        self.aperture = setup.aperture
        self.aperture_key = aperture_key(self.aperture)
        self.shader_aperture = shader_shape(self.aperture)
        self.dispersion = bool(setup.dispersion)
        self.coating = None
        if setup.ghosts is not None:
            from ..core.coatings import Coating
            self.coating = Coating(setup.ghosts.coating)

    # -- values that trace rays: computed on first use, cached by value in core

    @functools.cached_property
    def centre_irradiance(self) -> float:
        """E_0 at this sensor plane, stop and shape (core.pupil.centre_irradiance)."""
        if self.table:
            return self.lens.centre_irradiance
        from ..core.pupil import cached_centre_irradiance
        return cached_centre_irradiance(self.lens, sensor_z=self.sensor_z_mm,
                                        stop_radius=self.stop_radius_mm, aperture=self.aperture)

    @functools.cached_property
    def shader_centre_irradiance(self) -> float:
        """E_0 with the shape the Cycles shader clips with (the same value unless a large mask
        is reduced for it)."""
        if self.table:
            return self.lens.centre_irradiance
        from ..core.pupil import cached_centre_irradiance
        return cached_centre_irradiance(self.lens, sensor_z=self.sensor_z_mm,
                                        stop_radius=self.stop_radius_mm,
                                        aperture=self.shader_aperture)

    @functools.cached_property
    def slab_pupil(self):
        """The Cycles shader's sampler (core.pupil_slabs): at this sensor plane and stop, or
        for a following camera over its range at the widest stop; None for an anamorphic lens
        (its shader aims over the rear element's disc)."""
        if self.lens.anamorphic:
            return None
        from ..core.pupil_slabs import slab_pupil
        if self.table:
            return slab_pupil(self.lens, self.sensor_z_mm, self.film_radius_mm, math.inf,
                              passes=self.lens.passes, plane=self.lens.plane)
        tables = self.follow_tables
        if tables is None:
            return slab_pupil(self.lens, self.sensor_z_mm, self.film_radius_mm,
                              self.stop_radius_mm, self.shader_aperture)
        return slab_pupil(self.lens, tables.slab_planes[0], self.film_radius_mm,
                          float(tables.stop_radii[0]), self.shader_aperture,
                          also_sensor_z=tables.slab_planes[1:])

    @functools.cached_property
    def sampler(self):
        """The engine's camera-ray sampler (cached by value: its grids are costly)."""
        key = (self.lens.content_hash(), round(self.sensor_z_mm, 9),
               round(self.stop_radius_mm, 9), self.aperture_key, round(self.film_radius_mm, 6))
        s = _SAMPLERS.get_lru(key)
        if s is None:
            from ..core.pupil import camera_ray_sampler
            bands = int(min(24, max(4, math.ceil(self.film_radius_mm / 1.0))))
            if self.table:
                return _SAMPLERS.put(key, self.lens.sampler(self.film_radius_mm, bands=bands,
                                                            grid=ENGINE_GRID))
            s = camera_ray_sampler(self.lens, self.film_radius_mm, sensor_z=self.sensor_z_mm,
                                   stop_radius=self.stop_radius_mm, aperture=self.aperture,
                                   bands=bands, grid=ENGINE_GRID)
            _SAMPLERS.put(key, s)
        return s

    @functools.cached_property
    def ghost_set(self) -> tuple:
        """((Ghost, energy), ...): the `count` brightest ghosts at this lens, stop, shape and
        coating over the lens film (core.ghosts.ranked_ghosts), those that put any light on
        it; () without ghosts."""
        g = self.setup.ghosts
        if g is None:
            return ()
        from ..core.ghosts import ranked_ghosts
        ranked = ranked_ghosts(self.lens, self.coating, film_radius_mm=self.film_radius_mm,
                               stop_radius=self.stop_radius_mm, aperture=self.aperture,
                               sensor_z=self.sensor_z_mm)
        return tuple(p for p in ranked[:g.count] if p[1] > 0.0)

    @functools.cached_property
    def ghost_plan(self):
        """core.ghosts.GhostPlan of ghost_set for both renderers (None: no ghosts)."""
        if self.setup.ghosts is None:
            return None
        from ..core.ghosts import ghost_plan
        return ghost_plan(self.lens, self.ghost_set, self.setup.ghosts, self.coating,
                          stop_radius=self.stop_radius_mm, aperture=self.aperture,
                          sensor_z=self.sensor_z_mm)

    @functools.cached_property
    def follow_tables(self) -> FollowTables | None:
        """The tables of a camera that follows Blender's focus and f-number (follow_tables;
        None for a still camera)."""
        follow = self.setup.follow
        return None if follow is None else follow_tables(self.lens, follow,
                                                         self.shader_aperture)


_SAMPLERS = cache(4)       # the engine's pupil grids, by value
_FOLLOW = cache(8)         # follow tables, by value


def follow_tables(lens, follow, aperture) -> FollowTables:
    """The tables of a camera following Blender's focus and f-number over the range `follow`
    (camera.setup.FocusFollow) on a lens that focuses as a unit, for the stop shape `aperture`
    (the shader's): every point is the still camera's sensor plane and E_0 at its focus and
    f-number (cached by value)."""
    key = (lens.content_hash(), follow, aperture_key(aperture))
    hit = _FOLLOW.get_lru(key)
    if hit is not None:
        return hit
    from ..core.pupil import cached_centre_irradiance
    from .focusing import lens_sensor_z_mm
    near, far = follow.focus_mm
    t = np.linspace(1.0 / far if math.isfinite(far) else 0.0, 1.0 / near, FOCUS_POINTS)
    lo, hi = follow.f_numbers
    n = np.exp(np.linspace(math.log(lo), math.log(hi), F_NUMBER_POINTS))
    radii = np.array([stop_radius_of(lens, x) for x in n])
    z = np.array([[lens_sensor_z_mm(lens, 1.0 / x if x > 0 else math.inf, r) for r in radii]
                  for x in t])
    log_e = np.array([[math.log(cached_centre_irradiance(
        lens, sensor_z=float(z[k, m]), stop_radius=float(radii[m]), aperture=aperture))
        for m in range(len(n))] for k in range(len(t))])
    # the slabs are traced at the widest stop from planes spread over the whole range
    first = float(z[0, 0])
    planes = [float(p) for p in np.linspace(z.min(), z.max(), SLAB_PLANES) if p != first]
    return _FOLLOW.put(key, FollowTables(t, n, radii, z, log_e, (first, *planes)))
