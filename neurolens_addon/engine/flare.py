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
Vogel's spiral, the same points for every candidate), the `count` brightest kept (where every
candidate is kept the pilot only splits the rays: PILOT_SPLIT_RAYS; a ghost none of its rays
reach is left out either way); the frame's rays (share x pixels x samples, what the camera-
side ghosts are given, the samples at most MAX_SAMPLES) are spread over lights and ghosts in
proportion to that light, never under a FLOOR of an even split, and drawn uniformly in the
box around the pilot's points whose rays landed (grown by SUPPORT_MARGIN of its spacings;
A_disc is then the box's area) for a light from nearly one direction (SUPPORT_SPREAD_DEG),
over the whole disc for others: most of a disc's rays miss a ghost's path; every light's
rays along a ghost are traced in one call. Lights are every lamp of the scene (the
MAX_LIGHTS brightest at the lens), in frame or not: a sun just outside the frame still
flares. In the engine small emissive meshes (SMALL_EMITTERS_SR) are one more light
(engine.emitters: a triangle by its power, a point uniform on it, L_i / p = E |cos t_l| /
(p_A r^2)), and so is an image world (engine.lights.World's importance sampling: an HDR's
sun gets the rays); the camera-side ghost samples then count neither an emitter they meet
first nor the environment they escape to (traces_emitters, traces_world), so that light is
counted once; Cycles' camera cannot leave them out, so there the camera- side ghosts keep
them.
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
#: the pilot's rays where every candidate is kept (it only splits the frame's rays)
PILOT_SPLIT_RAYS = 128
#: a light's rays along a ghost are drawn in the box around the pilot's points whose rays
#: landed, grown by this many of the pilot's spacings (most of the disc's rays miss a ghost's
#: path: 86 % of the double Gauss's for the night street's lamps)
SUPPORT_MARGIN = 1.5
#: ... for a light whose directions at the lens lie within this angle of their mean (degrees):
#: a shift of the light's direction moves a ghost's footprint on the disc by about the
#: front-to-stop distance times the angle, under the margin; the others over the whole disc
SUPPORT_SPREAD_DEG = 1.0
PILOT_SEED = 7331       # the pilot's random numbers (not the frame's seed: module docstring)
MAX_LIGHTS = 16
#: a frame's flare rays are those of at most this many samples: light tracing puts every ray
#: on the film, drawn where the pilot's rays landed (SUPPORT_MARGIN); 32 samples' worth so
#: drawn are less noisy than 64's over the whole disc were (the point lamp: 0.175 against
#: 0.208 relative RMS, docs/bench/flare.md)
MAX_SAMPLES = 32
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
        from .camera_rays import lens_to_world
        return lens_to_world(o_lens, self.matrix, self.camera.sensor_z_mm, self.mm_per_unit)

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
        # whether the light comes from nearly one direction (a lamp, a small sun): where its
        # rays land then hardly depends on which point of the light a ray leaves, and the
        # pilot's landing points bound them (FlareLayer._support); an environment's or a
        # large mesh's rays land from everywhere
        lit = wi[(cos > 0.0) & (li.sum(axis=1) > 0.0)]
        mean = lit.sum(axis=0)
        spread = (math.degrees(math.acos(min(1.0, float(np.min(lit @ mean))
                                             / max(float(np.linalg.norm(mean)), 1e-300))))
                  if lit.shape[0] else 180.0)
        self.compact = spread <= SUPPORT_SPREAD_DEG

    def launch(self, counts, dispersion: bool, pilot: bool = False,
               boxes=None) -> list["Launch"]:
        """The light's rays towards the lens (those that travel towards it) through
        sum(counts) points of the disc, before the trace, in groups of counts[i] points (one
        ghost's estimate each, drawn in one go): flux factor = (n . w_i) A / counts[i] (A the
        disc's area, or with `boxes` the area of group i's box (x0, x1, y0, y1) on the disc's
        plane, its points uniform in it), times L_i/p, the path's coating weight w_g and the
        shadow test to come. With dispersion each point sends three rays, one per channel
        (lambda ~ s_c), so the flare has no colour noise of its own. A pilot's points are
        evenly spread over the disc (Vogel's spiral), not drawn: it compares ghosts of nearly
        equal light, every ghost through the same points."""
        cam, view = self.view.camera, self.view
        rng = self.pilot_rng if pilot else self.rng
        counts = np.asarray(counts, dtype=np.int64)
        n = int(counts.sum())
        group = np.repeat(np.arange(counts.size), counts)
        box = None if boxes is None else np.asarray(boxes, dtype=np.float64)
        if pilot:
            k = np.arange(n) + 0.5
            r = self.radius * np.sqrt(k / n)
            phi = k * GOLDEN_ANGLE
            x, y = r * np.cos(phi), r * np.sin(phi)
        elif box is not None:
            b = box[group]
            x = b[:, 0] + (b[:, 1] - b[:, 0]) * rng.random(n)
            y = b[:, 2] + (b[:, 3] - b[:, 2]) * rng.random(n)
        else:
            r = self.radius * np.sqrt(rng.random(n))
            phi = 2.0 * np.pi * rng.random(n)
            x, y = r * np.cos(phi), r * np.sin(phi)
        if box is not None:
            sizes = (box[:, 1] - box[:, 0]) * (box[:, 3] - box[:, 2])
        else:
            sizes = np.full(counts.size, math.pi * self.radius ** 2)
        o = np.stack([x, y, np.full(n, cam.lens.front_vertex_z)])
        world = view.to_world(o)
        wi, dist, li = _sample_light(self.light, world, rng.random(n), rng.random(n))
        cos_o = wi @ view.axis
        if dispersion:
            u = rng.random(n)
            response = sensor_response()
            lam = np.stack([response.sample_channel(u, c) for c in range(3)], axis=1)
        else:
            lam = np.full((n, 1), WAVELENGTH_D_NM)
        d = view.direction_to_lens(-wi)                  # the light's travel, towards -z
        go = np.flatnonzero((cos_o > 0) & (d[2] < 0))
        area = (sizes / np.maximum(counts, 1))[group[go]]
        d = d[:, go]
        rays = Launch(start=o[:, go] - 50.0 * d,        # in front of any front surface
                      direction=d, wavelength=lam[go], flux=cos_o[go] * area, li=li[go],
                      disc=o[:2, go].T, shadow_origin=world[go], shadow_direction=wi[go],
                      shadow_distance=dist[go])
        # the points in order: each group's a slice
        cut = np.searchsorted(go, np.cumsum(counts)[:-1])
        return [rays.part(a, b) for a, b in zip(np.r_[0, cut], np.r_[cut, go.size])]


@dataclass(frozen=True)
class Launch:
    """Rays of a light towards the lens (LightFlare.launch), per disc point: start and
    direction in lens space (mm, (3, n)), wavelengths (n, k: with dispersion one ray per
    channel, k = 3; else the d line for all three, k = 1), flux factor (n,), the light's
    L_i / p (n, 3), the point on the disc's plane (n, 2; lens space, mm) and the shadow ray
    from the point to the light (world)."""

    start: np.ndarray
    direction: np.ndarray
    wavelength: np.ndarray
    flux: np.ndarray
    li: np.ndarray
    disc: np.ndarray
    shadow_origin: np.ndarray
    shadow_direction: np.ndarray
    shadow_distance: np.ndarray

    def part(self, a: int, b: int) -> "Launch":
        """Points a..b-1 (views)."""
        return Launch(**{name: (v[:, a:b] if name in ("start", "direction") else v[a:b])
                         for name, v in vars(self).items()})

    @staticmethod
    def joined(launches: list["Launch"]) -> tuple["Launch", np.ndarray]:
        """(one Launch of all their points, each point's index in `launches`): the lights'
        rays along one ghost traced in one call."""
        owner = np.repeat(np.arange(len(launches)), [x.flux.size for x in launches])
        fields = {name: np.concatenate([getattr(x, name) for x in launches],
                                       axis=1 if name in ("start", "direction") else 0)
                  for name in Launch.__dataclass_fields__}
        return Launch(**fields), owner


class FlareLayer:
    """The frame's flare from its lights (module docstring): `render()` -> (W H, 3)."""

    def __init__(self, view: FlareView, lights, caster, *, rays: int, seed: int = 0,
                 dispersion: bool = True, support: bool = True):
        self.view = view
        self.caster = caster
        #: draw a light's rays along a ghost only where its pilot's rays landed (_support);
        #: False: over the whole disc (the reference the support is checked against)
        self.support = bool(support)
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
        # pilot: each light's light on the film along each candidate, shadows tested; where
        # every candidate is kept it only splits the rays, and a coarse estimate does
        n_pilot = PILOT_RAYS if len(candidates) > count else PILOT_SPLIT_RAYS
        pilots = [f.launch([n_pilot], self.dispersion, pilot=True)[0] for f in self.lights]
        energy = np.zeros((len(self.lights), len(candidates)))
        support = {}
        for j, g in enumerate(candidates):
            _pix, _ch, flux, owner, (reached, xy) = self._landing(pilots, g)
            total = flux if flux.ndim == 1 else flux.sum(axis=1)
            energy[:, j] = np.bincount(owner, weights=total, minlength=len(self.lights))
            for i in np.unique(reached):
                if self.support and self.lights[i].compact:
                    support[i, j] = self._support(self.lights[i], xy[reached == i], n_pilot)
        chosen = []
        for i, f in enumerate(self.lights):
            order = np.argsort(energy[i])[::-1][:count]
            picked = [(j, energy[i, j]) for j in order if energy[i, j] > 0.0]
            if picked:
                chosen.append((i, f, picked))
        if not chosen:
            return image
        light_e = np.array([sum(e for _j, e in p) for _i, _f, p in chosen])
        light_n = _spread(self.total_rays, light_e)
        scale = (self.plan.intensity / (max(self.plan.t0, 1e-12) * cam.centre_irradiance)
                 / cam.lens_film.pixel_area_mm2)
        # the lights' rays along each ghost, traced together
        along = {}
        for (i, f, picked), n_light in zip(chosen, light_n):
            ghost_n = _spread(n_light, np.array([e for _j, e in picked]))
            boxes = ([support[i, j] for j, _e in picked] if (i, picked[0][0]) in support
                     else None)
            for (j, _e), launch in zip(picked, f.launch(ghost_n, self.dispersion,
                                                       boxes=boxes)):
                along.setdefault(j, []).append(launch)
        for j, launches in along.items():
            pix, ch, flux, _owner, _reached = self._landing(launches, candidates[j])
            _splat(image, pix, ch, flux * scale)
        return image

    @staticmethod
    def _support(f: LightFlare, xy: np.ndarray, n_pilot: int) -> tuple:
        """The box (x0, x1, y0, y1) on the disc's plane a light's rays along a ghost are drawn
        in: around the pilot's disc points whose rays landed (shadows aside: a partly hidden
        light's shadow moves with the point of it a ray leaves), grown by SUPPORT_MARGIN times
        the pilot's spacing (its points' own share of the disc), within the disc's square."""
        grow = SUPPORT_MARGIN * f.radius * math.sqrt(math.pi / n_pilot)
        r = f.radius
        return (max(-r, float(xy[:, 0].min()) - grow), min(r, float(xy[:, 0].max()) + grow),
                max(-r, float(xy[:, 1].min()) - grow), min(r, float(xy[:, 1].max()) + grow))

    def _landing(self, launches: list[Launch], ghost):
        """(pixel, channel (-1: all three), flux ((M,), or (M, 3) for channel -1), launch
        index) of the launched rays that reach the film along `ghost` (core.trace from the
        scene along the ghost's path, its coating weight) with nothing between the lens and
        the light (a shadow ray a disc point), and (launch index, point on the disc's plane
        (K, 2)) of those that reach the film before the shadow test. The image
        point of a sensor point (x, y) is (-x, -y) on the lens's film (the readout flips the
        inverted image: camera_rays)."""
        from ..core.trace import trace
        cam = self.view.camera
        pts, owner = Launch.joined(launches)
        k = pts.wavelength.shape[1]
        res = trace(cam.lens, Rays(np.repeat(pts.start, k, axis=1),
                                   np.repeat(pts.direction, k, axis=1),
                                   pts.wavelength.ravel()),
                    from_sensor=False, ghost=ghost, coating=cam.coating,
                    stop_radius=cam.stop_radius_mm, aperture=cam.aperture,
                    sensor_z=cam.sensor_z_mm)
        ok = np.flatnonzero(res.valid)
        pix = cam.lens_film.pixels_of(-res.rays.o[0, ok], -res.rays.o[1, ok])
        on = pix >= 0
        ok, pix = ok[on], pix[on]
        reached = (owner[ok // k], pts.disc[ok // k])
        if ok.size:
            # one shadow ray a disc point, whatever number of its rays landed
            point, inverse = np.unique(ok // k, return_inverse=True)
            lit = ~self.caster.occluded(pts.shadow_origin[point], pts.shadow_direction[point],
                                        pts.shadow_distance[point] * (1 - 1e-6))
            ok, pix = ok[lit[inverse]], pix[lit[inverse]]
        point = ok // k
        w = res.weight[ok] * pts.flux[point]
        if k == 3:
            channel = ok % 3
            flux = w * pts.li[point, channel]
        else:
            channel = np.full(ok.size, -1)
            flux = w[:, None] * pts.li[point]
        return pix, channel, flux, owner[point], reached


def _sample_light(light, p: np.ndarray, u1: np.ndarray, u2: np.ndarray):
    """(wi, distance, L_i / p) of light.sample, through its compiled twin
    (engine.light_kernels) for a Blender lamp where the kernels run: a flare samples its
    lights at every disc point, hundreds of thousands a frame."""
    from ..core import jit
    from .lights import Light
    if isinstance(light, Light) and jit.mode() == "compiled":
        from .light_kernels import run_sample
        wi, dist, li, _pdf = run_sample(light.row, p, u1, u2)
    else:
        wi, dist, li, _pdf = light.sample(p, u1, u2)
    return wi, dist, li


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
