"""Training rays from the exact spectral trace, stratified by Latin hypercube sampling.

Sensor-side rays are drawn from a Latin hypercube over (film point, sensor position, aim point,
wavelength): the film point is uniform over the film disc, the sensor plane uniform over the
focus range [z_closest, z_infinity], the aim point uniform over a disc on the rear-pupil
sampler's plane (core.pupil) 1.15 x as wide as every passing ray it found from the two ends of
the focus range (complete, and far less wasteful than aiming at the rear element: a cover glass
1 mm from the sensor would pass 1 % of such rays), the wavelength uniform over the range. Each ray is traced exactly through the rear
group to the stop plane (stage 1; kept when it reaches the stop inside its full-aperture radius)
and on through the front group to Pi_2 (stage 2; kept when it leaves the lens). Each stage's
samples are stored in its frame (core.irf.stage_frames):

Stage inputs  X = (r, u_r, u_t, w[, lambda])  and targets  Y = (x'_r, x'_t, u'_r, u'_t) in the
radial frame, X = (x, y, u, v, w[, lambda]) and Y = (x', y', u', v') in the cartesian frame of a
group with an anamorphic surface; all float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from neurolens_addon.core.field import (FULL_FRAME_HALF_DIAGONAL_MM, circle_radius_mm,
                                        design_film_radius_mm, sensor_profile)
from neurolens_addon.core.focus import closest_focus_mm, focus_sensor_z
from neurolens_addon.core.irf import irf_planes, propagate_to_z, stage_frames, stage_targets
from neurolens_addon.core.prescription import Lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace
from neurolens_addon.core.variable_gaps import tabulated_position
from neurolens_addon.neural.reference import stage_inputs

WAVELENGTH_RANGE_NM = (380.0, 780.0)
D_LINE_NM = 587.5618


def latin_hypercube(n: int, dims: int, rng: np.random.Generator) -> np.ndarray:
    """n points in [0, 1)^dims with exactly one point per 1/n stratum in every dimension."""
    u = (rng.random((dims, n)) + np.arange(n)[None, :]) / n
    for row in u:
        rng.shuffle(row)
    return u


@dataclass
class StageSamples:
    x: np.ndarray          # (N, d_in) inputs in the lens's frame
    y: np.ndarray          # (N, 4) targets in the same frame
    valid_in: np.ndarray   # (M, d_in without lambda) inputs of ALL rays offered to the stage
    passed: np.ndarray     # (M,) bool: which of them came through


@dataclass
class Domain:
    """What the scene may ask of the model: film disc, focus range, wavelengths."""

    film_radius_mm: float
    sensor_z_range: tuple[float, float]
    wavelength_range_nm: tuple[float, float]
    dispersion: bool
    film_radius_min_mm: float = 0.0          # > 0: a ring (a render region off the centre)
    stop_radius_mm: float | None = None      # None: the lens's full aperture

    def as_dict(self) -> dict:
        d = {"film_radius_mm": self.film_radius_mm,
             "sensor_z_range": list(self.sensor_z_range),
             "wavelength_range_nm": list(self.wavelength_range_nm),
             "dispersion": self.dispersion}
        if self.film_radius_min_mm > 0:
            d["film_radius_min_mm"] = self.film_radius_min_mm
        if self.stop_radius_mm is not None:
            d["stop_radius_mm"] = self.stop_radius_mm
        return d

    @staticmethod
    def from_region(region) -> "Domain":
        """The trainer's domain for a core.scene_needs.TrainingRegion."""
        return Domain(region.film_radius_mm, tuple(region.sensor_z_range),
                      tuple(region.wavelength_range_nm), region.dispersion,
                      region.film_radius_min_mm, region.stop_radius_mm)


#: film radius every default model covers: the full-frame half diagonal (36 x 24 mm, wider than
#: Blender's default 36 mm 16:9 camera) with 2 % for the pixel filter's reach
DEFAULT_FILM_RADIUS_MM = 1.02 * FULL_FRAME_HALF_DIAGONAL_MM
#: the extension stops where film points see the scene this far off axis: past it the stage
#: fits diverge (the fisheye trained out to its 15.6 mm image circle, 78-90 degrees, missed
#: by 100 % where it fits its stated 156 degree field to 0.1 %)
EXTENSION_MAX_FIELD_DEG = 75.0
#: sensor positions a model of a lens with its groups at a close tabulated position covers
#: around the design plane and the exact residual focus
GROUP_SENSOR_PAD_MM = 0.02


def extended_film_radius_mm(lens: Lens, sensor_z: float) -> float:
    """How far the film extends past the stated field: towards DEFAULT_FILM_RADIUS_MM while
    light reaches it (the image circle) and film points look less than
    EXTENSION_MAX_FIELD_DEG off axis (core.field.sensor_profile)."""
    radii, angles, illumination = sensor_profile(lens, sensor_z)
    reach = circle_radius_mm(radii, angles, illumination)
    steep = np.flatnonzero(angles > EXTENSION_MAX_FIELD_DEG)
    if steep.size:
        reach = min(reach, float(radii[max(steep[0] - 1, 0)]))
    return min(DEFAULT_FILM_RADIUS_MM, reach)


def default_domain(lens: Lens, dispersion: bool = True) -> Domain:
    """The whole lens: focus from infinity to the closest focus, the visible range, and the film
    out to the image height of the lens's stated field, extended towards a full-frame camera's
    corners (extended_film_radius_mm): a lens still passes light beyond its stated field, and
    automatic model choice only uses a model that covers the rendered film
    (camera.model_choice). A lens whose focusing groups stand at a close tabulated position
    (a model per position, scripts/train_presets.py) is used only focused there: its sensor
    range spans the design plane and the exact residual focus at stops from full to 1/8."""
    z_inf = focus_sensor_z(lens, math.inf)
    z_near = focus_sensor_z(lens, closest_focus_mm(lens))
    k = tabulated_position(lens, lens.focus_gaps)
    if k:
        # focusing groups at a tabulated close distance: the camera uses this lens only
        # focused there, the sensor by the design plane (the paraxial image is on it) or at
        # the exact residual focus, which changes with the stop: sensors over both, padded
        d = lens.focus_gaps.positions[k]
        zs = [0.0] + [focus_sensor_z(lens, d, stop_radius=lens.stop_radius_mm * f)
                      for f in (1.0, 0.7, 0.5, 0.35, 0.25, 0.125)]
        z_near, z_inf = min(zs) - GROUP_SENSOR_PAD_MM, max(zs) + GROUP_SENSOR_PAD_MM
    wl = WAVELENGTH_RANGE_NM if dispersion else (D_LINE_NM, D_LINE_NM)
    film = max(design_film_radius_mm(lens), extended_film_radius_mm(lens, z_inf))
    return Domain(film, (min(z_near, z_inf), max(z_near, z_inf)), wl, dispersion)


def aim_disc(lens: Lens, domain: Domain) -> tuple[float, float]:
    """(plane z, radius) of the disc training rays aim at: the rear-pupil sampler's plane, wide
    enough for what passes from both ends of the focus range."""
    if lens.anamorphic:     # the pupil sampler's grids rotate one band to every azimuth
        from neurolens_addon.core.pupil import rear_disc
        return rear_disc(lens)
    from neurolens_addon.core.pupil import RearPupilSampler
    z_lo, z_hi = domain.sensor_z_range
    radii, plane = [], None
    for z in (z_hi, z_lo):
        s = RearPupilSampler(lens, 1.03 * domain.film_radius_mm, sensor_z=z, bands=16, grid=32,
                             stop_radius=domain.stop_radius_mm)
        if plane is None:
            plane = s.plane_z
        elif s.plane_z != plane:
            continue
        radii.append(s.aim_radius())
    return plane, 1.15 * max(radii)


def sensor_rays(lens: Lens, domain: Domain, n: int, rng: np.random.Generator):
    """Latin-hypercube sensor rays (origins on their sensor plane) and their sensor z."""
    u = latin_hypercube(n, 6, rng)
    r_lo, r_hi = domain.film_radius_min_mm, domain.film_radius_mm * 1.03
    r = np.sqrt(r_lo * r_lo + (r_hi * r_hi - r_lo * r_lo) * u[0])       # uniform over the ring
    phi = 2.0 * np.pi * u[1]
    z_lo, z_hi = domain.sensor_z_range
    zs = z_lo + (z_hi - z_lo) * u[2]
    plane_z, radius = aim_disc(lens, domain)
    rear_r = radius * np.sqrt(u[3])
    rear_phi = 2.0 * np.pi * u[4]
    lo, hi = domain.wavelength_range_nm
    wl = lo + (hi - lo) * u[5]
    o = np.stack([r * np.cos(phi), r * np.sin(phi), zs])
    tgt = np.stack([rear_r * np.cos(rear_phi), rear_r * np.sin(rear_phi), np.full(n, plane_z)])
    d = tgt - o
    d /= np.linalg.norm(d, axis=0)
    return o, d, wl


def stage_samples(lens: Lens, domain: Domain, n: int, seed: int = 0):
    """Exact training samples for both stages from n Latin-hypercube sensor rays, each stage's
    in its frame (core.irf.stage_frames)."""
    rng = np.random.default_rng(seed)
    planes = irf_planes(lens)
    frame1, frame2 = stage_frames(lens)
    stop = lens.stop_index
    o, d, wl = sensor_rays(lens, domain, n, rng)
    o1 = propagate_to_z(o, d, planes.input_z)
    # Stage 1: rear group (surfaces stop..end, traversed from the sensor), ending on the stop;
    # traced from the sensor plane (Pi_1 only parametrises each ray's line).
    res1 = trace(lens, Rays(o, d, wl), surfaces=(stop, len(lens.surfaces)),
                 stop_radius=domain.stop_radius_mm)
    x1_all, rot1 = stage_inputs(o1.T, d.T, wl, domain.dispersion, frame1)
    v1 = res1.valid
    y1 = stage_targets(res1.rays.o, res1.rays.d, rot1)
    st1 = StageSamples(x1_all[v1], y1[v1], x1_all[:, :frame1.base + 1], v1)
    # Stage 2: from the stop plane through the front group, then to Pi_2.
    o2, d2, wl2 = res1.rays.o[:, v1], res1.rays.d[:, v1], wl[v1]
    if stop > 0:
        res2 = trace(lens, Rays(o2, d2, wl2), surfaces=(0, stop))
        v2, d_out = res2.valid, res2.rays.d
        out_o = propagate_to_z(res2.rays.o, d_out, planes.output_z)
    else:
        # The stop is the front surface: stage 2 is free space to Pi_2.
        v2, d_out = np.ones(o2.shape[1], dtype=bool), d2
        out_o = propagate_to_z(o2, d2, planes.output_z)
    x2_all, rot2 = stage_inputs(o2.T, d2.T, wl2, domain.dispersion, frame2)
    y2 = stage_targets(out_o, d_out, rot2)
    st2 = StageSamples(x2_all[v2], y2[v2], x2_all[:, :frame2.base + 1], v2)
    return planes, st1, st2
