"""A bundle's light paths: first hits, direct lighting with shadow rays, diffuse bounces.

For a camera sample with weight W (camera_rays) and world ray (o, d), the estimate is the
path-traced radiance with next-event estimation on the lights:
    L = sum_{k=0..B} T_k [ Le(x_k) + sum_lights f(wo_k, wi) (n.wi) Li V(x_k, light) ]
        + T_{k} L_world(d_k) where the path escapes,
    T_0 = W,  T_{k+1} = T_k f(wo_k, wi_k) (n.wi_k) / p(wi_k)               (bsdf.sample)
with B the number of bounces, Le the surface's emission (both faces), Li / V a light sample and
its shadow ray (lights.py), and the world seen by escaping rays only (with a transparent film,
not by camera rays). Emissive meshes are found by rays, not sampled, so nothing is counted
twice. The face normal is flipped to face the incoming ray (two-sided surfaces) and the
shading normal (smooth meshes, materials.py) follows it, falling back to the face normal where
it would face away; secondary rays start EPSILON (1 + |x|_inf) scene units off the surface
along the face normal.
Clamping, as Cycles' Light Paths > Clamping: a contribution c (RGB) that reaches the camera
directly (the first hit's emission and light samples, the world seen by a camera ray) or
through one or more bounces is scaled to c min(1, K / (|c_r| + |c_g| + |c_b|)) with K the
direct or indirect limit (0: no clamp). It trades a little energy for fewer fireflies. A
camera sample of three single-channel rays (dispersion, camera_rays) clamps each ray at K / 3,
so a grey contribution is held at K per sample, as Cycles holds it.
Per camera sample it also keeps the first hit's depth along the camera's view axis and its
world-space normal (film.py averages them).
Uniform numbers come from camera_rays.hash_u01(seed, pixel, sample, dimension), so a sample
is reproducible whatever the bundle it is in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import bsdf
from .camera_rays import hash_u01

EPSILON = 1e-4
#: first hash dimension of the path's uniforms (camera_rays uses 0..5)
DIM_PATH = 16


def clamped(contribution: np.ndarray, limit: float) -> np.ndarray:
    """(N, 3) contributions scaled so that |r| + |g| + |b| <= limit (limit 0: unchanged)."""
    if not limit > 0.0:
        return contribution
    total = np.abs(contribution).sum(axis=1, keepdims=True)
    return contribution * np.minimum(1.0, limit / np.maximum(total, 1e-300))


@dataclass
class ShadeResult:
    rgb: np.ndarray       # (N, 3) W L per camera sample (0 for invalid ones)
    hit: np.ndarray       # (N,) bool first hit
    depth: np.ndarray     # (N,) view-axis depth of the first hit
    normal: np.ndarray    # (N, 3) world normal of the first hit
    albedo: np.ndarray    # (N, 3) base colour of the first hit (the denoiser's guide)


class Shader:
    def __init__(self, caster, materials, lights, world, *, bounces: int = 1, seed: int = 0,
                 camera_position=None, view_axis=None, transparent: bool = False,
                 clamp_direct: float = 0.0, clamp_indirect: float = 0.0):
        self.caster = caster
        self.materials = materials
        self.lights = lights
        self.world = world
        self.bounces = int(bounces)
        self.seed = int(seed)
        self.camera_position = np.asarray(camera_position if camera_position is not None
                                          else (0, 0, 0), dtype=np.float64)
        self.view_axis = np.asarray(view_axis if view_axis is not None else (0, 0, -1),
                                    dtype=np.float64)
        self.transparent = bool(transparent)
        self.clamp = (float(clamp_direct), float(clamp_indirect))

    def _u(self, pixel, sample, dim):
        return hash_u01(self.seed, pixel, sample, dim)

    def shade(self, cam) -> ShadeResult:
        """Radiance of every camera sample of a bundle (camera_rays.CameraSamples)."""
        n = cam.pixel.size
        rgb = np.zeros((n, 3))
        hit = np.zeros(n, dtype=bool)
        albedo = np.zeros((n, 3))
        depth = np.zeros(n)
        normal = np.zeros((n, 3))
        idx = cam.index
        o, d = cam.origin, cam.direction
        thr = cam.weight[idx]
        sample = cam.sample
        for k in range(self.bounces + 1):
            if idx.size == 0:
                break
            limit = self.clamp[0 if k == 0 else 1] * cam.share
            h = self.caster.closest(o, d)
            miss = np.ones(idx.size, dtype=bool)
            miss[h.ray] = False
            if miss.any() and (k > 0 or not self.transparent):
                rgb[idx[miss]] += clamped(thr[miss] * self.world.radiance(d[miss]), limit)
            if h.ray.size == 0:
                break
            j = idx[h.ray]
            t = thr[h.ray]
            wo = -d[h.ray]
            nrm = h.normal / np.maximum(np.linalg.norm(h.normal, axis=1, keepdims=True), 1e-12)
            if k == 0:
                hit[j] = True
                depth[j] = (h.location - self.camera_position) @ self.view_axis
                normal[j] = nrm
            sp = self.materials.lookup(h, self.caster.objects)
            base, metal, rough = sp.base, sp.metallic, sp.roughness
            if k == 0:
                albedo[j] = np.clip(base, 0.0, 1.0)
            side = np.where(bsdf.dot(nrm, wo) < 0, -1.0, 1.0)[:, None]
            ng = nrm * side                                   # face normal towards the viewer
            nf = sp.normal * side                             # shading normal, same side
            nf = np.where((bsdf.dot(nf, wo) > 0)[:, None], nf, ng)
            rgb[j] += clamped(t * sp.emission, limit)
            eps = EPSILON * (1.0 + np.abs(h.location).max(axis=1, keepdims=True))
            p = h.location + ng * eps
            px, sm = cam.pixel[j], sample[j]
            dim = DIM_PATH + 8 * k
            for li, light in enumerate(self.lights):
                u1 = self._u(px, sm, dim + 100 + 2 * li)
                u2 = self._u(px, sm, dim + 101 + 2 * li)
                wi, dist, li_rad = light.sample(p, u1, u2)
                contrib = t * bsdf.evaluate(base, metal, rough, nf, wo, wi) * li_rad
                live = np.flatnonzero((np.abs(contrib).max(axis=1) > 0)
                                      & (bsdf.dot(ng, wi) > 0))
                if live.size == 0:
                    continue
                if light.shadow:
                    blocked = self.caster.occluded(p[live], wi[live],
                                                   dist[live] - 2.0 * eps[live, 0])
                    live = live[~blocked]
                rgb[j[live]] += clamped(contrib[live], limit)
            if k == self.bounces:
                break
            wi, w, ok = bsdf.sample(base, metal, rough, nf, wo, self._u(px, sm, dim),
                                    self._u(px, sm, dim + 1), self._u(px, sm, dim + 2))
            t = t * w
            keep = ok & (bsdf.dot(ng, wi) > 0) & (np.abs(t).max(axis=1) > 0)
            idx, o, d, thr = j[keep], p[keep], wi[keep], t[keep]
        return ShadeResult(rgb, hit, depth, normal, albedo)
