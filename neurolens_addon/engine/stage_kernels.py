"""Three stages of a wavefront step compiled whole (numba): the misses, surface and light-sample
stages of shading.Shader._step, one pass over the bundle's rays or hits each, so that between
Embree's casts the step runs in kernels that release the GIL rather than in numpy expressions
that hold it between operations.

The misses stage, per ray: its distance to the hit (inf: it escapes), then every light with size
that a bounce ray meets before its surface, light by light, and for a flat world the rays that
escape (camera rays too unless the film is transparent), each weighed against the light's or
the world's sampling where the ray has a density, added to the bundle's sums.
The surface stage, per hit (shading.py's docstring states the equations; this restates none):
the face normal made unit and turned towards the viewer, the shading normal on the same side,
the offset EPSILON (1 + |x|_inf), the emission the path meets with its MIS weight against the
emissive meshes' sampling, added to the bundle's sums, and the alpha choice (pass through, or
stay and be shaded at the surface's opacity past the transparent limit).
The light-sample stage: for every light strategy in shading's order (the Blender lights each
diffuse or glossy ray sees, the emissive meshes, the world), one sample per surface point
(light_kernels), its contribution weighed against both lobes (shading_kernels), and the
shadow rays of the samples that light something, written compacted, strategy by strategy in
row order, as the numpy stage concatenates them; the caller casts them in one Embree call and
adds the clear ones.
The numpy stages in shading.py are the reference (tests/engine/test_shading_kernels.py);
differences are rounding only.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import jit
from . import light_kernels
from .light_kernels import emitters_sample_one, hit_one, sample_one
from .shading_kernels import _power, add_one, contribution_one, hash_one, salts

_njit = jit.njit(cache=True, nogil=True)
_LUM_R, _LUM_G, _LUM_B = light_kernels._LUM_R, light_kernels._LUM_G, light_kernels._LUM_B
EPSILON = 1e-4                                       # shading.EPSILON (tested equal)
_COL = light_kernels._COL                            # a light row's colour column


@_njit
def misses(o, d, thr, pdf, depth, samples, ray, location, rows, colour, world_flat,
           world_mis, transparent, limit_direct, limit_indirect, rgb, t_hit):
    """The misses stage (module docstring): t_hit (N,) of every ray (inf: it escapes; ray and
    location: the hits), then for every light with size (rows) the bounce rays that meet it
    before their surface, light by light in row order, then, for a flat world (world_flat),
    the rays that escape (camera rays too unless the film is transparent), added into
    rgb[samples[r]] with the MIS weight against the light's or the world's sampling where
    the ray has a density (world_mis: the world is sampled)."""
    for r in range(o.shape[0]):
        t_hit[r] = math.inf
    for i in range(ray.shape[0]):
        r = ray[i]
        vx, vy, vz = location[i, 0] - o[r, 0], location[i, 1] - o[r, 1], location[i, 2] - o[r, 2]
        t_hit[r] = math.sqrt(vx * vx + vy * vy + vz * vz)
    for s in range(rows.shape[0]):
        L = rows[s]
        for r in range(o.shape[0]):
            if depth[r] == 0:
                continue
            t, scale, dens = hit_one(L, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2],
                                     math.isinf(t_hit[r]))
            if not t < t_hit[r]:
                continue
            w = _power(pdf[r], dens) if pdf[r] > 0.0 else 1.0
            add_one(rgb, samples[r], thr[r, 0] * (L[_COL] * scale) * w,
                    thr[r, 1] * (L[_COL + 1] * scale) * w, thr[r, 2] * (L[_COL + 2] * scale) * w,
                    limit_direct if depth[r] <= 1 else limit_indirect)
    if not world_flat:
        return
    p_world = 1.0 / (4.0 * math.pi)
    for r in range(o.shape[0]):
        if not math.isinf(t_hit[r]) or (depth[r] == 0 and transparent):
            continue
        w = _power(pdf[r], p_world) if (world_mis and pdf[r] > 0.0) else 1.0
        add_one(rgb, samples[r], thr[r, 0] * colour[0] * w, thr[r, 1] * colour[1] * w,
                thr[r, 2] * colour[2] * w, limit_direct if depth[r] <= 1 else limit_indirect)


@_njit
def surface(d, thr, pdf, depth, kinds, samples, pixel, sample, loc, normal, t_hit,
            shading_normal, emission, alpha, salt, dim1, transparent_limit, emit_total,
            limit_direct, limit_indirect, rgb, ng, nf, eps, front, through, keep):
    """The surface stage (module docstring) of hits r: ng, nf (K, 3), eps, front, through and
    keep (K,) written; thr scaled by the opacity where the transparent limit is reached;
    emission added into rgb[samples[r]]; emit_total < 0: no emissive meshes are sampled (no
    MIS on emission)."""
    for r in range(d.shape[0]):
        nx, ny, nz = normal[r, 0], normal[r, 1], normal[r, 2]
        ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        wx, wy, wz = -d[r, 0], -d[r, 1], -d[r, 2]
        side = -1.0 if nx * wx + ny * wy + nz * wz < 0.0 else 1.0
        gx, gy, gz = nx * side, ny * side, nz * side
        sx, sy, sz = (shading_normal[r, 0] * side, shading_normal[r, 1] * side,
                      shading_normal[r, 2] * side)
        if not sx * wx + sy * wy + sz * wz > 0.0:
            sx, sy, sz = gx, gy, gz
        ng[r, 0], ng[r, 1], ng[r, 2] = gx, gy, gz
        nf[r, 0], nf[r, 1], nf[r, 2] = sx, sy, sz
        eps[r] = EPSILON * (1.0 + max(abs(loc[r, 0]), abs(loc[r, 1]), abs(loc[r, 2])))
        front[r] = side > 0.0
        e0, e1, e2 = emission[r, 0], emission[r, 1], emission[r, 2]
        # pdf < 0: a ghost camera ray whose emitters the flare layer brings (engine.flare)
        if max(abs(e0), abs(e1), abs(e2)) > 0.0 and pdf[r] >= 0.0:
            w = 1.0
            if pdf[r] > 0.0 and emit_total >= 0.0:
                cos_l = abs(nx * d[r, 0] + ny * d[r, 1] + nz * d[r, 2])
                p_area = max(e0 * _LUM_R + e1 * _LUM_G + e2 * _LUM_B, 0.0) / max(emit_total,
                                                                                1e-300)
                w = _power(pdf[r], p_area * t_hit[r] ** 2 / max(cos_l, 1e-12))
            add_one(rgb, samples[r], thr[r, 0] * e0 * w, thr[r, 1] * e1 * w,
                    thr[r, 2] * e2 * w, limit_direct if depth[r] <= 1 else limit_indirect)
        may_pass = kinds[r, 3] < transparent_limit
        a = alpha[r]
        through[r] = may_pass and hash_one(salt, dim1, pixel[r], sample[r]) >= a
        if not may_pass:
            for c in range(3):
                thr[r, c] = thr[r, c] * a
        keep[r] = (not through[r]) and a > 0.0


@_njit
def light_samples(salt, dim1, pixel, sample, rows, shadow, cdf, corners, emission, emit_total,
                  has_emitters, world_colour, world_wi, world_li, world_pdf, has_world, thr,
                  base, metallic, roughness, nf, ng, wo, f0, multiple, opaque, glossy_on,
                  diffuse_on, terms, pos, eps, out_row, out_contrib, out_wi, out_reach,
                  out_tested, out_origin):
    """The light-sample stage (module docstring): strategy s draws its two uniforms with
    (salt, dim1)[2 s] and [2 s + 1]; lights are rows (L, light_kernels.ROW) with their
    shadow flags, then the emissive meshes (has_emitters), then the world (has_world: 0 not
    sampled, 1 a flat world_colour, sampled uniformly over the sphere as lights.World, 2 its
    samples given per point). The samples that light a point go to out_* (surface row,
    contribution, wi, shadow ray length, whether it is shadow-tested, the shadow ray's origin
    pos[r]); their count is returned."""
    wi, dist = np.empty((1, 3)), np.empty(1)
    li, pdf = np.empty((1, 3)), np.empty(1)
    nl = rows.shape[0]
    strategies = nl + (1 if has_emitters else 0) + (1 if has_world > 0 else 0)
    n = 0
    none = np.zeros(light_kernels.ROW)
    for s in range(strategies):
        # the light's row taken once a strategy (a view made per row costs its reference count)
        L = rows[s] if s < nl else none
        for r in range(nf.shape[0]):
            if not opaque[r] > 0.0:
                continue
            u1 = hash_one(salt[2 * s], dim1[2 * s], pixel[r], sample[r])
            u2 = hash_one(salt[2 * s + 1], dim1[2 * s + 1], pixel[r], sample[r])
            tested = True
            if s < nl:
                sample_one(L, pos[r, 0], pos[r, 1], pos[r, 2], u1, u2, wi, dist, li,
                           pdf, 0)
                tested = shadow[s]
            elif s == nl and has_emitters:
                emitters_sample_one(cdf, corners, emission, emit_total, pos[r, 0], pos[r, 1],
                                    pos[r, 2], u1, u2, wi, dist, li, pdf, 0)
            elif has_world == 1:                           # a flat world: the sphere
                z = 1.0 - 2.0 * u1
                rad = math.sqrt(max(0.0, 1.0 - z * z))
                phi = 2.0 * math.pi * u2
                wi[0, 0], wi[0, 1], wi[0, 2] = rad * math.cos(phi), rad * math.sin(phi), z
                for c in range(3):
                    li[0, c] = world_colour[c] * (4.0 * math.pi)
                pdf[0] = 1.0 / (4.0 * math.pi)
                dist[0] = math.inf
            else:                                          # the world's samples, given
                for c in range(3):
                    wi[0, c] = world_wi[r, c]
                    li[0, c] = world_li[r, c]
                pdf[0] = world_pdf[r]
                dist[0] = math.inf
            if contribution_one(thr, base, metallic, roughness, nf, ng, wo, f0, multiple,
                                opaque, glossy_on, diffuse_on, terms, r, wi[0, 0], wi[0, 1],
                                wi[0, 2], li[0, 0], li[0, 1], li[0, 2], pdf[0], out_contrib,
                                n):
                out_row[n] = r
                for c in range(3):
                    out_wi[n, c] = wi[0, c]
                    out_origin[n, c] = pos[r, c]
                out_reach[n] = math.inf if math.isinf(dist[0]) else dist[0] - 2.0 * eps[r]
                out_tested[n] = tested
                n += 1
    return n


@_njit
def take_paths(sel, idx, o, d, thr, w0, pdf, depth, kinds, depth_add, out_idx, out_o, out_d,
               out_thr, out_w0, out_pdf, out_depth, out_kinds):
    """Rows sel of a wavefront's path state (shading.Paths' fields, in its order) into the out_
    arrays, depth raised by depth_add: the gathers of a compaction in one pass."""
    for j in range(sel.shape[0]):
        r = sel[j]
        out_idx[j] = idx[r]
        for c in range(3):
            out_o[j, c] = o[r, c]
            out_d[j, c] = d[r, c]
            out_thr[j, c] = thr[r, c]
        out_w0[j] = w0[r]
        out_pdf[j] = pdf[r]
        out_depth[j] = depth[r] + depth_add
        for c in range(4):
            out_kinds[j, c] = kinds[r, c]


# ---------------------------------------------------------------- array wrappers

def _f(a):
    return np.ascontiguousarray(a, dtype=np.float64)


def _i(a):
    return np.ascontiguousarray(a, dtype=np.int64)


def run_take_paths(sel, idx, o, d, thr, w0, pdf, depth, kinds, depth_add=0):
    """`take_paths` of the rows sel (int indices, or a bool mask): the fields' new arrays."""
    sel = np.flatnonzero(sel) if sel.dtype == np.bool_ else _i(sel)
    k = sel.shape[0]
    out = (np.empty(k, np.int64), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3)),
           np.empty(k), np.empty(k), np.empty(k, np.int64), np.empty((k, 4), np.int64))
    take_paths(sel, _i(idx), _f(o), _f(d), _f(thr), _f(w0), _f(pdf), _i(depth), _i(kinds),
               int(depth_add), *out)
    return out


def run_surface(p, hits, sp, t_hit, pixel, sample, seed, dim, transparent_limit, emit_total,
                limit_direct, limit_indirect, rgb):
    """`surface` of the hits (scene_cast.Hits) of paths p (shading.Paths, its thr changed in
    place) with their materials sp (materials.SurfacePoint); dim: the alpha choice's hash
    dimension; (ng, nf, eps, front, through, keep). rgb: the bundle's sums (C-contiguous
    float64, changed in place)."""
    k = p.idx.shape[0]
    p.thr = _f(p.thr)                     # (written in place: contiguous float64 first)
    ng, nf, eps = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
    front, through, keep = (np.empty(k, np.bool_) for _ in range(3))
    salt, dim1 = salts(seed, dim)
    surface(_f(p.d), p.thr, _f(p.pdf), _i(p.depth), _i(p.kinds), _i(p.idx), _i(pixel),
            _i(sample), _f(hits.location), _f(hits.normal), _f(t_hit), _f(sp.normal),
            _f(sp.emission), _f(sp.alpha), salt, dim1, int(transparent_limit),
            float(emit_total), float(limit_direct), float(limit_indirect), rgb, ng, nf, eps,
            front, through, keep)
    return ng, nf, eps, front, through, keep


def run_misses(paths, hits, rows, world_colour, world_mis, transparent, limit_direct,
               limit_indirect, rgb):
    """`misses` of the rays of paths (shading.Paths) and their hits (scene_cast.Hits); rows:
    light_table's of the lights with size; world_colour: the flat world's colour, None for
    a textured one (whose escapes the caller adds); t_hit (N,)."""
    k = paths.idx.shape[0]
    t_hit = np.empty(k)
    flat = world_colour is not None
    misses(_f(paths.o), _f(paths.d), _f(paths.thr), _f(paths.pdf), _i(paths.depth),
           _i(paths.idx), _i(hits.ray), _f(hits.location), rows,
           _f(world_colour if flat else np.zeros(3)), flat, bool(world_mis), bool(transparent),
           float(limit_direct), float(limit_indirect), rgb, t_hit)
    return t_hit


def light_table(lights):
    """(rows (L, ROW), shadow flags (L,)) of lights (lights.Light)."""
    rows = np.array([light.row for light in lights]).reshape(len(lights), light_kernels.ROW)
    shadow = np.array([bool(getattr(light, "shadow", True)) for light in lights], np.bool_)
    return np.ascontiguousarray(rows, np.float64), shadow


def run_light_samples(seed, dims, pixel, sample, table, emitters, world_sample, thr, sp, nf,
                      ng, wo, opaque, glossy_on, diffuse_on, terms, pos, eps):
    """`light_samples`: dims the first hash dimension of each strategy (lights, emitters,
    world); table: light_table's; emitters: emitters.Emitters or None; world_sample: the
    world's (wi, Li / p, p) per point, a flat world's colour (3,) (sampled in the kernel), or
    None (the world is not sampled). (row, contribution, wi, reach, tested, origin) of the
    samples that light something."""
    k = nf.shape[0]
    pairs = [salts(seed, d + j) for d in dims for j in (0, 1)]
    salt = np.array([a for a, _ in pairs], np.uint64)
    dim1 = np.array([b for _, b in pairs], np.uint64)
    if emitters is not None:
        cdf, corners = _f(emitters.cdf), _f(emitters.corners)
        emission, total = _f(emitters.emission), float(emitters.total)
    else:
        cdf, corners, emission, total = np.zeros(2), np.zeros((1, 3, 3)), np.zeros((1, 3)), 0.0
    world_colour = np.zeros(3)
    world_wi, world_li, world_pdf = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    has_world = 0
    if isinstance(world_sample, tuple):
        world_wi, world_li, world_pdf = (_f(x) for x in world_sample)
        has_world = 2
    elif world_sample is not None:
        world_colour, has_world = _f(world_sample), 1
    cap = k * len(dims)
    row, contrib, wi = np.empty(cap, np.int64), np.empty((cap, 3)), np.empty((cap, 3))
    reach, tested, origin = np.empty(cap), np.empty(cap, np.bool_), np.empty((cap, 3))
    n = light_samples(salt, dim1, _i(pixel), _i(sample), table[0], table[1], cdf, corners,
                      emission, total, emitters is not None, world_colour, world_wi, world_li,
                      world_pdf, has_world, _f(thr), _f(sp.base), _f(sp.metallic),
                      _f(sp.roughness), _f(nf), _f(ng), _f(wo), _f(sp.f0),
                      _f(sp.multiscatter), _f(opaque),
                      np.ascontiguousarray(glossy_on, np.bool_),
                      np.ascontiguousarray(diffuse_on, np.bool_), terms, _f(pos),
                      _f(np.reshape(eps, (k,))), row, contrib, wi, reach, tested, origin)
    return row[:n], contrib[:n], wi[:n], reach[:n], tested[:n], origin[:n]
