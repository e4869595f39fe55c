"""Flare from Blender's lights: each light's ghosts traced from the light through the lens to
the film (light tracing), splatted into the frame's flare layer.

Camera rays never meet a point, spot or sun lamp, so the camera-side ghost samples
(engine.camera_rays) cannot show their ghosts. Here the light's own rays are followed: for a
light and a ghost g = (a, b) of the lens (core.ghosts), light enters the front surface, is
reflected at b and at a, and reaches the sensor (core.trace from the scene along the ghost's
path, core.ghost_path.ghost_steps_from_scene). The camera estimator reads a ghost as
    C_c(pixel) = k / (T_0 g_0) * E_g,c(pixel)
(k the intensity, T_0 the image path's centre transmittance, g_0 the centre irradiance per unit
radiance, E_g,c the ghost's irradiance on the pixel from channel c's wavelengths), and by the
conservation of etendue the flux a pixel receives is the flux the ghost's rays bring through
the front of the lens:
    E_g,c(pixel) = 1 / A_pix * sum over rays landing in it of
                   (n . w_i) (L_i / p)_c * w_g * V * A_disc / N,
the N rays from points uniform over a disc of area A_disc on the front vertex's plane (normal n,
the lens axis), each towards a point of the light the light's own sampler picks
(engine.lights.Light.sample: (L_i / p) is I / r^2 for a point or spot, the sun's irradiance,
L cos(t_l) A / r^2 for an area light), w_g the path's coating transmittances and reflectances
at the ray's wavelength and angles, V the shadow ray from the disc point to the light, A_pix
the pixel's area on the sensor. With dispersion each disc point sends three rays, one per
channel at a wavelength drawn from its response (lambda ~ s_c), each counting towards its
channel; without, one ray at the d line counts towards all three. A light's ghosts are those it
puts the most light on the film with: CANDIDATES x count / sqrt(lights) (at least count) of the
lens's brightest for a uniform scene, PILOT_RAYS each (their own random numbers, the same for
every seed, so that every seed renders the same ghosts; the disc's points evenly spread,
Vogel's spiral), the `count` brightest kept; the
frame's rays (share x pixels x samples, what the camera-side ghosts are given, the samples at
most MAX_SAMPLES) are spread over lights and ghosts in proportion to that light, never under a
FLOOR of an even split. Lights are every lamp of the scene (the MAX_LIGHTS brightest at the
lens), in frame or not: a sun just outside the frame still flares. In the engine small
emissive meshes (SMALL_EMITTERS_SR) are one more light (engine.emitters: a triangle by its
power, a point uniform on it, L_i / p = E |cos t_l| / (p_A r^2)), and so is an image world
(engine.lights.World's importance sampling: an HDR's sun gets the rays); the camera-side
ghost samples then count neither an emitter they meet first nor the environment they escape
to (traces_emitters, traces_world), so that light is counted once; Cycles' camera cannot
leave them out, so there the camera-side ghosts keep them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.prescription import WAVELENGTH_D_NM
from ..core.rays import Rays
from ..core.sensor_response import sensor_response

CANDIDATES = 4          # one light's ghosts are chosen among CANDIDATES x count (n lights:
                        # CANDIDATES x count / sqrt(n), at least count)
PILOT_RAYS = 1024       # rays per candidate ghost and light measuring its light on the film:
                        # a lens's ghosts often carry nearly equal light (the 2x
                        # anamorphic's 3rd to 10th brightest for a lamp: 5.4-3.6 % each), and
                        # 192 drawn rays kept the wrong ones (a streak ghost left out)
PILOT_SEED = 7331       # the pilot's random numbers (not the frame's seed: module docstring)
MAX_LIGHTS = 16
#: a frame's flare rays are those of at most this many samples: light tracing puts every ray
#: on the film, and at 64 two seeds' flares already agree (docs/bench/flare.md)
MAX_SAMPLES = 64
#: the render pass of the flare layer (name, channels, channel ids)
FLARE_PASS = ("Flare", 3, "RGB")
FLOOR = 0.1             # the least share of an even split any light or ghost gets
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
DISC_MARGIN = 1.05      # the sampling disc's radius over what the front surface can take
AT_LENS = 64            # points of a light its irradiance at the lens is averaged over
#: emissive meshes subtending less than this (steradians, all together, at the camera) are
#: light-traced: a disc of about 2.3 degrees' radius (traces_emitters)
SMALL_EMITTERS_SR = 5e-3


@dataclass(frozen=True)
class FlareView:
    """Where the lens is: the derived camera and its placement (engine.camera_rays)."""

    camera: object            # camera.derived.DerivedCamera (lens, coating, film, ghost plan)
    matrix: np.ndarray        # 4x4 rigid camera matrix
    mm_per_unit: float

    def to_world(self, o_lens: np.ndarray) -> np.ndarray:
        """(3, N) lens-space points (mm) -> (N, 3) world points (engine.camera_rays)."""
        from .camera_rays import camera_to_world, lens_to_camera
        d = np.zeros_like(o_lens)
        d[2] = 1.0
        pc, dc = lens_to_camera(o_lens, d, self.camera.sensor_z_mm, self.mm_per_unit)
        return camera_to_world(pc, dc, self.matrix)[0]

    def direction_to_lens(self, d_world: np.ndarray) -> np.ndarray:
        """(N, 3) world directions -> (3, N) lens-space directions."""
        dc = d_world @ self.matrix[:3, :3]          # R^T d
        return np.stack([dc[:, 0], dc[:, 1], -dc[:, 2]])

    @property
    def axis(self) -> np.ndarray:
        """The lens axis towards the scene, in world space (the camera's -Z)."""
        return -self.matrix[:3, 2]


def _disc_radius(lens, tan_t: float) -> float:
    """Radius on the front vertex's plane that every ray entering the front surface at an
    angle with tangent tan_t crosses within (its rim lies |sag| off the plane)."""
    from ..core.trace import sag
    sd = float(lens.surfaces[0].semi_diameter_mm)
    rim = abs(float(np.asarray(sag(lens, 0, np.array([sd])))[0]))
    return DISC_MARGIN * (sd + rim * tan_t)


class LightFlare:
    """One light's rays through the lens along its ghosts, for one view."""

    def __init__(self, view: FlareView, light, seed: int, index: int = 0):
        self.view = view
        self.light = light
        self.rng = np.random.default_rng(seed)
        # the pilot's own numbers, the same whatever the frame's seed: which ghosts a light
        # gets must not change with the seed (two seeds would render different ghost sets)
        self.pilot_rng = np.random.default_rng(PILOT_SEED + index)
        cam = view.camera
        centre = view.to_world(np.array([[0.0], [0.0], [cam.lens.front_vertex_z]]))[0]
        # the irradiance at the lens, over AT_LENS stratified points of the light (a lamp's
        # are alike; an emissive mesh's triangles face every way)
        u = (np.arange(AT_LENS) + 0.5) / AT_LENS
        wi, _dist, li, _pdf = light.sample(np.repeat(centre[None, :], AT_LENS, axis=0), u,
                                           np.mod(u * AT_LENS * 0.6180339887498949, 1.0))
        cos = wi @ view.axis
        self.at_lens = float(np.mean(np.maximum(cos, 0.0) * li.sum(axis=1)))
        # the disc must take the steepest light that reaches the lens (an environment's or a
        # mesh's comes from many directions)
        facing = cos[cos > 0.0]
        cos_t = float(facing.min()) if facing.size else 1.0
        tan_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t)) / max(cos_t, 0.05)
        self.radius = _disc_radius(cam.lens, min(tan_t, 20.0))

    def rays(self, n: int, ghost, dispersion: bool, pilot: bool = False):
        """(x, y on the sensor, channel (-1: all three), flux factor, shadow rays (origin,
        direction, distance)) of the light's rays through n points of the disc along `ghost`
        that reach the sensor: flux factor = (n . w_i)(L_i/p) w_g A_disc / n, before the shadow
        test. With dispersion each point sends three rays, one per channel (lambda ~ s_c), so
        the flare has no colour noise of its own."""
        cam, view = self.view.camera, self.view
        rng = self.pilot_rng if pilot else self.rng
        if pilot:
            # a pilot compares ghosts of nearly equal light: its disc points evenly spread
            # (Vogel's spiral), not drawn, so that its estimates rank them
            k = np.arange(n) + 0.5
            r = self.radius * np.sqrt(k / n)
            phi = k * GOLDEN_ANGLE
        else:
            r = self.radius * np.sqrt(rng.random(n))
            phi = 2.0 * np.pi * rng.random(n)
        o = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, cam.lens.front_vertex_z)])
        world = view.to_world(o)
        wi, dist, li, _pdf = self.light.sample(world, rng.random(n), rng.random(n))
        cos_o = wi @ view.axis
        area = math.pi * self.radius ** 2 / n
        if dispersion:
            k = 3
            channel = np.tile(np.arange(3), n)
            u = np.repeat(rng.random(n), 3)
            response = sensor_response()
            lam = np.empty(3 * n)
            for c in range(3):
                lam[channel == c] = response.sample_channel(u[channel == c], c)
        else:
            k = 1
            channel = np.full(n, -1)
            lam = np.full(n, WAVELENGTH_D_NM)
        src = np.repeat(np.arange(n), k)                 # each ray's disc point
        d = view.direction_to_lens(-wi)                  # the light's travel, towards -z
        go = np.flatnonzero(((cos_o > 0) & (d[2] < 0))[src])
        from ..core.trace import trace
        start = o - 50.0 * d                             # in front of any front surface
        res = trace(cam.lens, Rays(start[:, src[go]], d[:, src[go]], lam[go]),
                    from_sensor=False, ghost=ghost, coating=cam.coating,
                    stop_radius=cam.stop_radius_mm, aperture=cam.aperture,
                    sensor_z=cam.sensor_z_mm)
        keep = go[res.valid]
        at = src[keep]
        w = res.weight[res.valid] * cos_o[at] * area
        flux = (w * li[at, channel[keep]] if dispersion else w[:, None] * li[at])
        return (res.rays.o[0, res.valid], res.rays.o[1, res.valid], channel[keep], flux,
                (world[at], wi[at], dist[at]))


class FlareLayer:
    """The frame's flare from its lights (module docstring): `render()` -> (W H, 3)."""

    def __init__(self, view: FlareView, lights, caster, *, rays: int, seed: int = 0,
                 dispersion: bool = True):
        self.view = view
        self.caster = caster
        self.total_rays = int(rays)
        self.dispersion = bool(dispersion)
        cam = view.camera
        self.plan = cam.ghost_plan
        flares = [LightFlare(view, light, seed * 7919 + i, i) for i, light in enumerate(lights)]
        flares = [f for f in flares if f.at_lens > 0.0]
        self.lights = sorted(flares, key=lambda f: -f.at_lens)[:MAX_LIGHTS]

    def candidates(self):
        """(the ghosts a light's are chosen among, how many each light keeps)."""
        cam = self.view.camera
        from ..core.ghosts import ranked_ghosts
        count = int(cam.setup.ghosts.count)
        ranked = ranked_ghosts(cam.lens, cam.coating, film_radius_mm=cam.film_radius_mm,
                               stop_radius=cam.stop_radius_mm, aperture=cam.aperture,
                               sensor_z=cam.sensor_z_mm)
        # the pilots cost lights x candidates traces: with many lights each weighs fewer
        k = max(count, round(CANDIDATES * count / math.sqrt(max(len(self.lights), 1))))
        return [g for g, e in ranked[:k] if e > 0.0], count

    def render(self) -> np.ndarray:
        cam = self.view.camera
        film = cam.film
        w_px, h_px = film.width_px, film.height_px
        image = np.zeros((w_px * h_px, 3))
        if self.plan is None or not self.lights or self.total_rays <= 0:
            return image
        candidates, count = self.candidates()
        # pilot: each light's light on the film along each candidate, shadows tested
        chosen = []
        for f in self.lights:
            energy = [float(np.sum(self._landing(f, PILOT_RAYS, g, pilot=True)[2]))
                      for g in candidates]
            order = np.argsort(energy)[::-1][:count]
            picked = [(candidates[i], energy[i]) for i in order if energy[i] > 0.0]
            if picked:
                chosen.append((f, picked))
        if not chosen:
            return image
        light_e = np.array([sum(e for _g, e in p) for _f, p in chosen])
        light_n = _spread(self.total_rays, light_e)
        scale = (self.plan.intensity / (max(self.plan.t0, 1e-12) * cam.centre_irradiance)
                 / cam.lens_film.pixel_area_mm2)
        for (f, picked), n_light in zip(chosen, light_n):
            ghost_n = _spread(n_light, np.array([e for _g, e in picked]))
            for (g, _e), n in zip(picked, ghost_n):
                pix, ch, flux = self._landing(f, int(n), g)
                _splat(image, pix, ch, flux * scale)
        return image

    def _landing(self, f: LightFlare, n: int, ghost, pilot: bool = False):
        """(pixel, channel, flux) of the light's rays (LightFlare.rays) that land on the film
        with nothing between the lens and the light (shadow rays). The image point of a sensor
        point (x, y) is (-x, -y) on the lens's film (the readout flips the inverted image:
        camera_rays)."""
        x, y, ch, flux, (so, sd, sdist) = f.rays(n, ghost, self.dispersion, pilot=pilot)
        pix = self.view.camera.lens_film.pixels_of(-x, -y)
        keep = np.flatnonzero(pix >= 0)
        if keep.size:
            keep = keep[~self.caster.occluded(so[keep], sd[keep], sdist[keep] * (1 - 1e-6))]
        return pix[keep], ch[keep], flux[keep]


def _spread(total: int, energy: np.ndarray) -> np.ndarray:
    """Integers summing to about `total`, in proportion to `energy`, none under FLOOR of an
    even split."""
    k = len(energy)
    share = energy / max(float(energy.sum()), 1e-300)
    share = np.maximum(share, FLOOR / k)
    share /= share.sum()
    return np.maximum(1, np.round(total * share)).astype(np.int64)


def _splat(image: np.ndarray, pix: np.ndarray, channel: np.ndarray, flux: np.ndarray) -> None:
    """Add each ray's flux to its pixel: to its channel, or (channel -1, flux (n, 3)) to all."""
    n = image.shape[0]
    if flux.ndim == 2:
        for c in range(3):
            image[:, c] += np.bincount(pix, weights=flux[:, c], minlength=n)
        return
    for c in range(3):
        sel = channel == c
        image[:, c] += np.bincount(pix[sel], weights=flux[sel], minlength=n)


def traces_emitters(cam, emitters, position) -> bool:
    """Whether the engine's flare layer traces the emissive meshes' ghosts from them (module
    docstring): a camera with ghosts at `position` (world) that sees emitters subtending less
    than SMALL_EMITTERS_SR together. Small bright ones are what camera-side ghost samples find
    by chance (speckle), and light tracing costs the same whatever their size; large ones the
    camera side finds often and cheaply. Its camera-side ghost samples then count no emitter
    they meet first (engine.shading), or that light would be counted twice; Cycles' camera
    cannot tell, so its flare layer leaves emitters out."""
    return (cam.ghost_plan is not None and bool(emitters)
            and emitters.solid_angle_at(np.asarray(position, float)) < SMALL_EMITTERS_SR)


def traces_world(cam, world) -> bool:
    """Whether the engine's flare layer traces an environment's ghosts from it (module
    docstring): an image world (an HDR's sun among its texels, where its importance sampling
    puts the rays) seen by a camera with ghosts; a flat colour's even glow is left to the
    camera-side ghost samples."""
    return (cam.ghost_plan is not None and world is not None and world.texture is not None
            and not world.is_black)


class WorldLight:
    """The environment as a light of the flare layer: its own importance sampling
    (engine.lights.World), from infinitely far."""

    def __init__(self, world):
        self.world = world

    def sample(self, p: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        """(wi, distance (inf), Li / p, p) towards the environment from points p (N, 3)."""
        wi, li, pdf = self.world.sample(p.shape[0], u1, u2)
        return wi, np.full(p.shape[0], np.inf), li, pdf


def flare_of_frame(cam, matrix, mm_per_unit: float, lights, caster, samples: int, seed: int,
                   dispersion: bool, emitters=None,
                   world=None) -> tuple[np.ndarray, FlareLayer] | None:
    """The flare layer ((W H, 3)) of a frame through the derived camera `cam` at the rigid
    camera `matrix`, with its FlareLayer; None when the set-up has no ghosts or the scene no
    lights. Its rays: the ghosts' share of the frame's camera samples (share x pixels x
    samples, the samples at most MAX_SAMPLES). Both renderers' flare (Cycles':
    blender.flare_compositor); the engine's also traces `emitters` (traces_emitters) and an
    image `world` (traces_world), each as one more light."""
    # (whether the emitters and the world are traced is decided once per frame, with the
    # camera side: engine.frame_setup)
    if emitters:
        lights = [*lights, emitters]
    if world is not None:
        lights = [*lights, WorldLight(world)]
    if cam.ghost_plan is None or not lights:
        return None
    f = cam.film
    rays = cam.ghost_plan.share * f.width_px * f.height_px * min(samples, MAX_SAMPLES)
    layer = FlareLayer(FlareView(cam, matrix, mm_per_unit), lights, caster, rays=int(rays),
                       seed=seed, dispersion=dispersion)
    return layer.render(), layer


def frame_flare(renderer, samples: int | None = None) -> tuple[np.ndarray, FlareLayer] | None:
    """flare_of_frame for a frame the engine renders (engine.renderer FrameRenderer), at its
    samples (`samples`: that many instead)."""
    gen, shader = renderer.generator, renderer.shader
    return flare_of_frame(gen.camera, gen.matrix, gen.mm_per_unit, shader.lights,
                          shader.caster,
                          renderer.settings.samples if samples is None else samples,
                          gen.seed, gen.dispersion,
                          emitters=shader.emitters if shader.flare_traces_emitters else None,
                          world=shader.world if shader.flare_traces_world else None)
