"""A bundle's light paths: wavefront path tracing with next-event estimation and multiple
importance sampling.

For a camera sample of weight W (camera_rays) and world ray (o, d), every path vertex x_k
(k = 0 the first hit) adds
    T_k Le(x_k) w_b                                              (emission met by the path)
  + sum over light strategies  T_k f(wo, wi) (n.wi) Li / p_l  w_l  V(x_k, wi)   (light samples)
with T_0 = W. Each lobe j of the opaque surface (bsdf.py: diffuse, glossy) is its own bounce
strategy: it is chosen with probability P_j and samples wi with density p_j, and the bounce
carries T_{k+1} = T_k f_j (n.wi) / (P_j p_j) (glass: dielectric.sample's weight). The light
strategies, one sample each per vertex: every Blender light (lights.Light) that diffuse or
glossy rays see, the emissive triangles (emitters.py) and the world (lights.World). A light
sample's f is split by lobe and each part weighed against that lobe by the power heuristic,
    w_l,j = p_l^2 / (p_l^2 + (P_j p_j)^2),   and a bounce ray of lobe j takes
    w_b = (P_j p_j)^2 / ((P_j p_j)^2 + p_l^2)
where it meets an emissive surface (emitters.area_density), a light with size (Light.hit) or
escapes to the world (World.pdf), all densities per solid angle. A lobe that cannot bounce
(its kind's limit, or the path's last vertex) is no strategy: its part of a light sample
counts whole. Camera rays, rays after a glass bounce (never light-sampled) or through an
alpha surface (shadow rays stop there), and light samples of lights without size take
weight 1.

A surface (materials.SurfacePoint) is: with probability 1 - alpha, nothing (the ray goes on,
a transparent bounce); else a glass lobe of share t (dielectric.py, refracted light tinted by
the base colour, and reflected light too for a Glass BSDF) and the opaque Principled lobes
(bsdf.py) of share 1 - t, chosen at random for the bounce; light samples evaluate the opaque
lobes (times 1 - t) only.
Bounces stop at the scene's Light Paths limits (settings.py): the total, and per kind diffuse
(the diffuse lobe), glossy (the GGX lobe, glass reflection), transmission (refraction) and
transparent (alpha). After min_light_bounces bounces a path survives Russian roulette with
probability q = min(1, sqrt(max_c T_c / max_c W_c)) and its throughput is divided by q.

Faces are two-sided: the face normal is flipped to face the incoming ray and the shading
normal (smooth meshes, materials.py) follows it, falling back to the face normal where it
would face away; a bounce leaves EPSILON (1 + |x|_inf) scene units off the surface, on the
side it goes to. Clamping, as Cycles' Light Paths > Clamping: a contribution c (RGB) is scaled
to c min(1, K / (|c_r| + |c_g| + |c_b|)) with K the direct limit for light that lights the
first hit (its light samples, and what its bounce ray meets) or that a camera ray meets, else
the indirect limit (0: no clamp); a camera sample of three single-channel rays (dispersion)
clamps each ray at K / 3. Per camera sample it also keeps the first hit's depth along the camera's
view axis, its world normal and base colour (the passes and the denoiser's guides).
Uniform numbers come from camera_rays.hash_u01(seed, pixel, sample, dimension), so a sample is
reproducible whatever the bundle it is in.
Where numba runs (core.jit), the per-row arithmetic of these stages runs as compiled kernels,
one pass over the rows each: the misses, surface and light-sample stages whole
(stage_kernels.py), the bounce and the sums (shading_kernels.py);
the numpy expressions here are their reference and the path without numba, and the same random
numbers give the same image.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import bsdf, dielectric, shading_kernels, stage_kernels, vec
from . import microfacet as mf
from .camera_rays import hash_u01
from .emitters import Emitters
from .settings import RenderSettings

EPSILON = 1e-4
#: first hash dimension of the path's uniforms (camera_rays uses 0..5); each path step uses
#: DIMS_PER_STEP of them: 0-2 the bounce, 3 the lobe, 4 alpha, 5 roulette, 6-7 the world,
#: 8-9 the emissive meshes, 10 + 2 i the light i
DIM_PATH = 16
DIMS_PER_STEP = 1 << 12


def clamped(contribution: np.ndarray, limit) -> np.ndarray:
    """(N, 3) contributions scaled so that |r| + |g| + |b| <= limit; `limit` a number or one
    per row (0: that row unchanged)."""
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), contribution.shape[:1])
    if not (limit > 0).any():
        return contribution
    total = np.abs(contribution).sum(axis=1)
    scale = np.where(limit > 0, np.minimum(1.0, limit / np.maximum(total, 1e-300)), 1.0)
    return contribution * scale[:, None]


def power_heuristic(p_this: np.ndarray, p_other: np.ndarray) -> np.ndarray:
    """p_this^2 / (p_this^2 + p_other^2): 1 where p_other is 0 or p_this infinite (a delta
    light), 0 where p_this is 0 (and p_other is not)."""
    a, b = np.square(p_this), np.square(p_other)
    with np.errstate(invalid="ignore", over="ignore"):
        w = a / np.maximum(a + b, 1e-300)
    # a delta (infinite) density wins outright; a strategy that cannot produce wi, never
    return np.where((b > 0) & ~np.isinf(a), w, 1.0)


@dataclass
class ShadeResult:
    rgb: np.ndarray       # (N, 3) W L per camera sample (0 for invalid ones)
    hit: np.ndarray       # (N,) bool first hit
    depth: np.ndarray     # (N,) view-axis depth of the first hit
    normal: np.ndarray    # (N, 3) world normal of the first hit
    albedo: np.ndarray    # (N, 3) base colour of the first hit (the denoiser's guide)
    data: np.ndarray | None = None   # (N, D) the data passes' sums (data_passes), or None


@dataclass
class Paths:
    """The live paths of a bundle: per path its camera sample, ray, throughput and history."""

    idx: np.ndarray        # (M,) camera sample of each path
    o: np.ndarray          # (M, 3) ray origin
    d: np.ndarray          # (M, 3) unit ray direction
    thr: np.ndarray        # (M, 3) throughput T
    w0: np.ndarray         # (M,) max_c W_c: the camera weight (Russian roulette's scale)
    pdf: np.ndarray        # (M,) p_b of d, 0: no multiple importance sampling on what d meets
    depth: np.ndarray      # (M,) bounces so far (transparent ones not counted)
    kinds: np.ndarray      # (M, 4) bounces so far: diffuse, glossy, transmission, transparent

    def take(self, sel) -> "Paths":
        if shading_kernels.active():        # the gathers in one pass
            return Paths(*stage_kernels.run_take_paths(sel, *self.fields()))
        return Paths(*(getattr(self, f)[sel] for f in self.__dataclass_fields__))

    def fields(self) -> tuple:
        return tuple(getattr(self, f) for f in self.__dataclass_fields__)


class Shader:
    def __init__(self, caster, materials, lights, world, *, emitters: Emitters | None = None,
                 settings: RenderSettings | None = None, camera_position=None,
                 view_axis=None, transparent: bool = False, flare_traces_emitters: bool = False,
                 flare_traces_world: bool = False, data=None):
        s = settings or RenderSettings()
        self.caster = caster
        self.materials = materials
        self.lights = list(lights)
        self.world = world
        self.emitters = emitters if emitters else None
        # the flare layer brings the emissive meshes' and an environment's ghosts
        # (engine.flare.traces_emitters, traces_world): a ghost camera ray then counts neither
        # an emitter it meets first nor the environment it escapes to (nor twice)
        self.flare_traces_emitters = bool(flare_traces_emitters)
        self.flare_traces_world = bool(flare_traces_world)
        self.bounces = int(s.bounces)
        self.limits = np.array([s.diffuse_bounces, s.glossy_bounces, s.transmission_bounces,
                                s.transparent_bounces])
        self.min_light_bounces = int(s.min_light_bounces)
        self.seed = int(s.seed)
        self.camera_position = np.asarray(camera_position if camera_position is not None
                                          else (0, 0, 0), dtype=np.float64)
        self.view_axis = np.asarray(view_axis if view_axis is not None else (0, 0, -1),
                                    dtype=np.float64)
        self.transparent = bool(transparent)
        self.clamp = (float(s.clamp_direct), float(s.clamp_indirect))
        self.sample_world = world is not None and not world.is_black
        #: the data passes' values at first hits (data_passes.FirstHitData), or None
        self.data = data

    @cached_property
    def _hit_table(self):
        """The lights with size that bounce rays see, flat for the compiled misses stage."""
        return stage_kernels.light_table([light for light in self.lights
                                          if light.visible and not light.is_delta])[0]

    @cached_property
    def _light_table(self):
        """The lights each diffuse or glossy ray sees, flat for the compiled light stage."""
        return stage_kernels.light_table([light for light in self.lights if light.visible])

    def _u(self, pixel, sample, dim):
        return hash_u01(self.seed, pixel, sample, dim)

    def shade(self, cam) -> ShadeResult:
        """Radiance of every camera sample of a bundle (camera_rays.CameraSamples)."""
        n = cam.pixel.size
        out = ShadeResult(np.zeros((n, 3)), np.zeros(n, dtype=bool), np.zeros(n),
                          np.zeros((n, 3)), np.zeros((n, 3)))
        if self.data is not None:           # the image samples that pass the lens (UV's A)
            out.data = np.zeros((n, self.data.layout.width))
            out.data[cam.index, -2] = 1.0
            if cam.ghost is not None:
                out.data[cam.ghost, -2] = 0.0
        idx = cam.index
        w = cam.weight[idx]
        m = idx.size
        # a camera ray has no direction density (0); -1 marks a ghost ray whose first
        # emitter the flare layer brings (its surface stage adds no emission for it)
        pdf = np.zeros(m)
        if (self.flare_traces_emitters or self.flare_traces_world) and cam.ghost is not None:
            pdf[cam.ghost[idx]] = -1.0
        paths = Paths(idx, cam.origin, cam.direction, w, vec.absmax3(w), pdf,
                      np.zeros(m, np.int64), np.zeros((m, 4), np.int64))
        # every step either ends paths or counts a (transparent) bounce; this bounds the loop
        for step in range(self.bounces + int(self.limits[3]) + 1):
            if paths.idx.size == 0:
                break
            paths = self._step(paths, cam, out, step)
        return out

    # -- one wavefront step: cast, gather what the rays meet, light samples, next bounce

    def _step(self, paths: Paths, cam, out: ShadeResult, step: int) -> Paths:
        first = step == 0
        h = self.caster.closest(paths.o, paths.d)
        share = cam.share
        # the clamps of this bundle's sums: each ray carries its share of a sample
        limit_direct, limit_indirect = self.clamp[0] * share, self.clamp[1] * share
        compiled = shading_kernels.active()

        def add(samples, contribution, direct):
            """Add contributions to camera samples, clamped as direct where `direct`."""
            if compiled:
                shading_kernels.run_accumulate(out.rgb, samples, contribution, direct,
                                               limit_direct, limit_indirect)
                return
            c = clamped(contribution, np.where(direct, limit_direct, limit_indirect))
            for ch in range(3):               # bincount: a scatter-add far faster than add.at
                out.rgb[:, ch] += np.bincount(samples, c[:, ch], minlength=out.rgb.shape[0])

        # as in Cycles, light met by a ray counts as lighting the vertex the ray left: direct
        # for camera rays and for the bounce rays of the first hit
        met_direct = paths.depth <= 1
        flat_world = self.world.texture is None
        if compiled:                       # the same stage fused, a pass over the rays
            t_hit = stage_kernels.run_misses(
                paths, h, self._hit_table, self.world.colour if flat_world else None,
                self.sample_world, self.transparent, limit_direct, limit_indirect, out.rgb)
            if not flat_world:
                self._escapes(paths, np.isinf(t_hit), met_direct, add)
        else:
            t_hit = np.full(paths.idx.size, np.inf)
            t_hit[h.ray] = vec.norm(h.location - paths.o[h.ray])
            self._light_hits(paths, t_hit, met_direct, add)
            self._escapes(paths, np.isinf(t_hit), met_direct, add)
        if h.ray.size == 0:
            return paths.take(np.zeros(0, np.int64))

        # the surfaces hit
        p = paths.take(h.ray)
        j = p.idx
        direct = p.depth == 0
        if first:
            out.hit[j] = True
            out.depth[j] = np.einsum("ij,j->i", h.location - self.camera_position,
                                     self.view_axis)   # (matmul would wake BLAS threads)
            out.normal[j] = h.normal / np.maximum(vec.norm(h.normal)[:, None], 1e-12)
        sp = self.materials.lookup(h, self.caster.objects)
        if first:
            out.albedo[j] = np.clip(sp.base, 0.0, 1.0)
            if self.data is not None:       # after lookup: the objects' tables are built
                values = self.data.values(h, self.caster.objects, self.materials.object_table,
                                          getattr(self.caster, "instances", ()))
                if cam.ghost is not None:   # a ghost's first hit is not the image's
                    values[cam.ghost[j]] = 0.0
                out.data[j] = values
        px, sm = cam.pixel[j], cam.sample[j]
        dim = DIM_PATH + DIMS_PER_STEP * step
        alpha_dim = dim + 4
        if compiled:                       # the same stage fused, a pass over the hits
            ng, nf, eps, front, through, keep = stage_kernels.run_surface(
                p, h, sp, t_hit[h.ray], px, sm, self.seed, alpha_dim, self.limits[3],
                self.emitters.total if self.emitters is not None else -1.0,
                limit_direct, limit_indirect, out.rgb)
            eps = eps[:, None]
            wo = -p.d
        else:
            ng, nf, wo, eps, front, through, keep = self._surface(p, h, sp, t_hit, px, sm,
                                                                  alpha_dim, met_direct, add)
        passed = p.take(through)
        passed.o = h.location[through] - ng[through] * eps[through]
        passed.pdf = np.minimum(passed.pdf, 0.0)      # no MIS past it; a ghost's mark kept
        passed.kinds[:, 3] += 1

        # what stays: light samples and the next bounce
        keep = np.flatnonzero(keep)
        loc = h.location
        if keep.size < p.idx.size:          # (an opaque scene keeps every row: no copies)
            p, sp = p.take(keep), _take_surface(sp, keep)
            nf, ng, wo, eps, px, sm = (nf[keep], ng[keep], wo[keep], eps[keep], px[keep],
                                       sm[keep])
            loc, direct, front = loc[keep], direct[keep], front[keep]
        sp_k = sp
        pos = loc + ng * eps
        last = p.depth >= self.bounces
        opaque = 1.0 - sp_k.transmission
        # what the lobes share for every direction at a vertex, once for its light samples and
        # its bounce (the compiled path)
        terms = (shading_kernels.run_layer_terms(sp_k.roughness, nf, wo, sp_k.f0,
                                                 sp_k.multiscatter, mf.tables())
                 if compiled else None)
        self._light_samples(p, sp_k, nf, ng, wo, pos, eps, px, sm, dim, opaque, last, add,
                            direct, terms, (out.rgb, limit_direct, limit_indirect))
        nxt = self._bounce(p, sp_k, nf, ng, wo, loc, eps, px, sm, dim, opaque, ~last, front,
                           terms)
        return _concat(passed, nxt) if passed.idx.size else nxt

    def _light_hits(self, paths, t_hit, met_direct, add):
        """Lights with size met before the surface by bounce rays (lights do not block rays),
        weighed against the light's sampling where the ray has a density (numpy;
        stage_kernels.misses the same fused)."""
        mis = paths.pdf > 0
        bounce = np.flatnonzero(paths.depth != 0)
        if not bounce.size:
            return
        miss = np.isinf(t_hit)
        for light in self.lights:
            tl, rad, pl = light.hit(paths.o[bounce], paths.d[bounce], miss[bounce])
            met = tl < t_hit[bounce]
            if not met.any():
                continue
            sel = bounce[met]
            wgt = np.where(mis[sel], power_heuristic(paths.pdf[sel], pl[met]), 1.0)
            add(paths.idx[sel], paths.thr[sel] * rad[met] * wgt[:, None], met_direct[sel])

    def _escapes(self, paths, miss, met_direct, add):
        """The world's light for the rays that escape (camera rays too unless the film is
        transparent), weighed against the world's sampling where the ray has a density."""
        seen = (paths.depth != 0) | (not self.transparent)
        if self.flare_traces_world:          # a ghost camera ray's environment: the flare's
            seen &= paths.pdf >= 0
        esc = np.flatnonzero(miss & seen)
        if not esc.size:
            return
        li = self.world.radiance(paths.d[esc])
        wgt = np.ones(esc.size)
        if self.sample_world:
            mw = paths.pdf[esc] > 0
            if mw.any():
                wgt[mw] = power_heuristic(paths.pdf[esc[mw]], self.world.pdf(paths.d[esc[mw]]))
        add(paths.idx[esc], paths.thr[esc] * li * wgt[:, None], met_direct[esc])

    def _surface(self, p, h, sp, t_hit, px, sm, alpha_dim, met_direct, add):
        """The surface stage in numpy (stage_kernels.surface the same fused): (ng, nf, wo, eps,
        front, through, keep) of the hits; emission added, p.thr scaled by the opacity past
        the transparent limit."""
        nrm = h.normal / np.maximum(vec.norm(h.normal)[:, None], 1e-12)
        wo = -p.d
        side = np.where(vec.dot(nrm, wo) < 0, -1.0, 1.0)[:, None]
        ng = nrm * side                                   # face normal towards the viewer
        nf = sp.normal * side                             # shading normal, same side
        nf = np.where((vec.dot(nf, wo) > 0)[:, None], nf, ng)
        eps = EPSILON * (1.0 + vec.absmax3(h.location)[:, None])
        # emission met by the path (not by a ghost ray whose emitters the flare layer brings)
        emits = np.flatnonzero((vec.absmax3(sp.emission) > 0) & (p.pdf >= 0))
        if emits.size:
            wgt = np.ones(emits.size)
            mw = p.pdf[emits] > 0
            if mw.any() and self.emitters is not None:
                e = emits[mw]
                cos_l = np.abs(vec.dot(nrm[e], p.d[e]))
                pl = (self.emitters.area_density(sp.emission[e]) * t_hit[h.ray[e]] ** 2
                      / np.maximum(cos_l, 1e-12))
                wgt[mw] = power_heuristic(p.pdf[e], pl)
            add(p.idx[emits], p.thr[emits] * sp.emission[emits] * wgt[:, None],
                met_direct[h.ray][emits])
        # alpha: the ray passes straight on with probability 1 - alpha
        may_pass = p.kinds[:, 3] < self.limits[3]
        through = (self._u(px, sm, alpha_dim) >= sp.alpha) & may_pass
        # past the transparent limit a partly transparent surface is shaded at its opacity
        # (what passing through would have brought is not counted)
        p.thr = np.where((~may_pass)[:, None], p.thr * sp.alpha[:, None], p.thr)
        keep = ~through & (sp.alpha > 0)
        return ng, nf, wo, eps, side[:, 0] > 0, through, keep

    def _light_samples(self, p, sp, nf, ng, wo, pos, eps, px, sm, dim, opaque, last, add,
                       direct, terms=None, sums=None):
        """One sample of every light strategy at each surface point, shadow-tested; weight 1
        at a path's last vertex (`last`), where no bounce ray competes. The compiled path adds
        into sums = (the bundle's rgb, direct clamp, indirect clamp) itself."""
        if not (opaque > 0).any():
            return
        # a light hidden from diffuse and glossy rays lights no surface (as in Cycles)
        strategies = [(light, dim + 10 + 2 * i) for i, light in enumerate(self.lights)
                      if light.visible]
        if self.emitters is not None:
            strategies.append((self.emitters, dim + 8))
        if self.sample_world:
            strategies.append((self.world, dim + 6))
        if shading_kernels.active():
            self._light_samples_compiled(p, sp, nf, ng, wo, pos, eps, px, sm, opaque, last,
                                         sums, direct, terms, strategies)
            return
        for light, d0 in strategies:
            u1, u2 = self._u(px, sm, d0), self._u(px, sm, d0 + 1)
            if light is self.world:
                wi, li, pl = self.world.sample(px.size, u1, u2)
                dist = np.full(px.size, np.inf)
                shadow = True
            else:
                wi, dist, li, pl = light.sample(pos, u1, u2)
                shadow = getattr(light, "shadow", True)
            live, contrib, wi, dist = self._light_contribution(
                p, sp, nf, ng, wo, wi, li, pl, dist, opaque, last)
            if live is None:
                continue
            reach = np.where(np.isinf(dist), np.inf, dist - 2.0 * eps[live, 0])
            if shadow:
                clear = ~self.caster.occluded(pos[live], wi, reach)
                live, contrib = live[clear], contrib[clear]
            add(p.idx[live], contrib, direct[live])

    def _light_samples_compiled(self, p, sp, nf, ng, wo, pos, eps, px, sm, opaque, last, sums,
                                direct, terms, strategies):
        """`_light_samples` through stage_kernels.light_samples: every strategy's samples in
        one pass, their shadow rays in one Embree cast."""
        on = ~last
        world_sample = None
        if self.sample_world and self.world.texture is None:
            world_sample = self.world.colour              # sampled in the kernel
        elif self.sample_world:
            d0 = strategies[-1][1]
            u = shading_kernels.run_hash_u01_dims(self.seed, px, sm, [d0, d0 + 1])
            world_sample = self.world.sample(px.size, u[0], u[1])
        row, contrib, wi, reach, tested, origin = stage_kernels.run_light_samples(
            self.seed, [d0 for _light, d0 in strategies], px, sm, self._light_table,
            self.emitters, world_sample, p.thr, sp, nf, ng, wo, opaque,
            on & (p.kinds[:, 1] < self.limits[1]), on & (p.kinds[:, 0] < self.limits[0]),
            terms, pos, eps)
        if row.size == 0:
            return
        if tested.all():                  # (every light casts shadows: no gathers)
            clear = ~self.caster.occluded(origin, wi, reach)
        else:
            clear = np.ones(row.size, dtype=bool)
            t = np.flatnonzero(tested)
            if t.size:
                clear[t] = ~self.caster.occluded(origin[t], wi[t], reach[t])
        shading_kernels.run_accumulate_rows(sums[0], p.idx, row, clear, contrib, direct,
                                            sums[1], sums[2])

    def _light_contribution(self, p, sp, nf, ng, wo, wi, li, pl, dist, opaque, last):
        """(rows, contribution, wi, dist) of the surface points a light sample lights (numpy;
        shading_kernels.light_contribution the same fused), rows None where none is lit."""
        # the surface is evaluated only where the light arrives from above it
        live = np.flatnonzero((vec.absmax3(li) > 0) & (vec.dot(ng, wi) > 0) & (opaque > 0))
        if live.size == 0:
            return None, None, None, None
        wi, li, pl, dist = wi[live], li[live], pl[live], dist[live]
        fd, fg = bsdf.evaluate_parts(sp.base[live], sp.metallic[live], sp.roughness[live],
                                     nf[live], wo[live], wi, sp.f0[live],
                                     sp.multiscatter[live])
        # each lobe is its own bounce strategy: weigh the light sample against the lobe's
        # density, or take it whole where that lobe ends the path (or is a delta light)
        pg, pd = self._lobe_pdfs(p, sp, nf, wo, wi, live, opaque, last)
        finite = np.isfinite(pl)
        wd = np.where(finite, power_heuristic(pl, pd), 1.0)[:, None]
        wg = np.where(finite, power_heuristic(pl, pg), 1.0)[:, None]
        contrib = p.thr[live] * (fd * wd + fg * wg) * (li * opaque[live, None])
        nz = vec.absmax3(contrib) > 0
        if not nz.all():
            live, contrib, wi, dist = live[nz], contrib[nz], wi[nz], dist[nz]
        return live, contrib, wi, dist

    def _lobe_pdfs(self, p, sp, nf, wo, wi, rows, opaque, last):
        """(glossy, diffuse) densities with which the bounce of surface points `rows` makes
        wi through each lobe (lobe choice included); 0 for a lobe whose bounce limit ends the
        path there, or at the path's last vertex: no bounce competes with the light sample."""
        glossy, diffuse = bsdf.pdf_parts(sp.metallic[rows], sp.roughness[rows], nf[rows],
                                         wo[rows], wi, sp.f0[rows])
        k = p.kinds[rows]
        on = ~last[rows]
        glossy = np.where(on & (k[:, 1] < self.limits[1]), glossy, 0.0)
        diffuse = np.where(on & (k[:, 0] < self.limits[0]), diffuse, 0.0)
        return opaque[rows] * glossy, opaque[rows] * diffuse

    def _bounce(self, p, sp, nf, ng, wo, loc, eps, px, sm, dim, opaque, go, front,
                terms=None) -> Paths:
        """The next ray of each path that goes on (`go`): a lobe chosen by its share, sampled,
        the kind's bounce limit and Russian roulette applied. `front`: the ray came from the
        side the face normal points to (outside a closed mesh: glass is entered)."""
        k = p.idx.size
        if shading_kernels.active():        # the same arithmetic fused, a pass over the rows
            u = shading_kernels.run_hash_u01_dims(self.seed, px, sm, [dim + i for i in
                                                                      (0, 1, 2, 3, 5)])
            origin, wi, t, pdf, kinds, ok = shading_kernels.run_bounce(
                p.thr, p.w0, p.depth, p.kinds, sp, nf, ng, wo, loc, eps, front, go, u[:4],
                u[4], self.limits, self.min_light_bounces, mf.tables(), terms)
            return Paths(*stage_kernels.run_take_paths(ok, p.idx, origin, wi, t, p.w0, pdf,
                                                       p.depth, kinds, depth_add=1))
        u = [self._u(px, sm, dim + i) for i in range(4)]
        glass = u[3] < sp.transmission
        u_lobe = np.where(glass, 0.0, (u[3] - sp.transmission) / np.maximum(opaque, 1e-12))
        # the opaque lobes: a direction from the chosen lobe, weighed as that lobe's own
        # strategy, f_j (n.wi) / (P_j p_j) (the light samples weigh against the same density)
        wi, spec = bsdf.sample_direction(sp.metallic, sp.roughness, nf, wo, u[0], u[1], u_lobe,
                                         sp.f0)
        fd, fg = bsdf.evaluate_parts(sp.base, sp.metallic, sp.roughness, nf, wo, wi, sp.f0,
                                     sp.multiscatter)
        pg, pd = bsdf.pdf_parts(sp.metallic, sp.roughness, nf, wo, wi, sp.f0)
        lobe_pdf = np.where(spec, pg, pd)
        ok = (vec.dot(nf, wi) > 0) & (lobe_pdf > 0) & (vec.dot(ng, wi) > 0)
        thr = np.where(spec[:, None], fg, fd) / np.where(lobe_pdf > 0, lobe_pdf, 1.0)[:, None]
        kind = np.where(spec, 1, 0)
        pdf = opaque * lobe_pdf
        origin = loc + ng * eps
        gi = np.flatnonzero(glass)
        if gi.size:
            eta = np.where(front[gi], sp.ior[gi], 1.0 / sp.ior[gi])
            gwi, gw, refr, gok = dielectric.sample(nf[gi], wo[gi], eta, sp.roughness[gi],
                                                   u[0][gi], u[1][gi], u[2][gi])
            t = sp.tint_reflection[gi, None]
            tint = np.where(refr[:, None], sp.base[gi], t * sp.base[gi] + (1.0 - t))
            wi[gi], thr[gi] = gwi, tint * gw[:, None]
            ok[gi] = gok & np.where(refr, vec.dot(ng[gi], gwi) < 0, vec.dot(ng[gi], gwi) > 0)
            pdf[gi] = 0.0
            kind[gi] = np.where(refr, 2, 1)
            origin[gi] = loc[gi] + np.where(refr[:, None], -ng[gi], ng[gi]) * eps[gi]
        kinds = p.kinds.copy()
        kinds[np.arange(k), kind] += 1
        ok &= go & (kinds[np.arange(k), kind] <= self.limits[kind])
        t = p.thr * thr
        # Russian roulette after min_light_bounces bounces
        q = np.ones(k)
        rr = (p.depth + 1) > max(self.min_light_bounces, 1)
        if rr.any():
            q[rr] = np.minimum(1.0, np.sqrt(vec.absmax3(t[rr])
                                            / np.maximum(p.w0[rr], 1e-300)))
            ok &= self._u(px, sm, dim + 5) < q
        t = t / np.maximum(q, 1e-12)[:, None]
        ok &= vec.absmax3(t) > 0
        sel = np.flatnonzero(ok)
        return Paths(p.idx[sel], origin[sel], wi[sel], t[sel], p.w0[sel], pdf[sel],
                     p.depth[sel] + 1, kinds[sel])


def _take_surface(sp, sel):
    return type(sp)(*(getattr(sp, f)[sel] for f in sp.__dataclass_fields__))


def _concat(a: Paths, b: Paths) -> Paths:
    return Paths(*(np.concatenate([getattr(a, f), getattr(b, f)])
                   for f in Paths.__dataclass_fields__))
