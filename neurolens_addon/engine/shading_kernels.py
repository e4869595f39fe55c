"""The shading's arithmetic compiled (numba): the surface model (bsdf.py with microfacet.py's
terms and tables), glass (dielectric.py) and the hash behind every uniform number
(camera_rays.hash_u01), one loop over rows each, with the numpy modules kept as the
reference they are tested against (tests/engine/test_shading_kernels.py).

Each kernel computes, row by row, exactly the expression its numpy twin writes over whole
arrays (the equations are in those modules' docstrings; this module restates none), in one
pass instead of one array pass per operation, and releases the GIL (`nogil`): the engine's
worker threads (renderer.py) shade their bundles on every core at once. The albedo tables
(microfacet._tables) are passed in, read by the same multilinear interpolation (axis 0 first,
as microfacet._lerp). Differences from the numpy reference: rounding only (a product
evaluated in another order, e.g. h normalised by a reciprocal), ~1e-15 relative.

Without numba (core.jit) the kernels are plain Python and `KERNELS` is False: the shading
then calls the numpy modules (a loop in Python would be slower still).
"""

from __future__ import annotations

import math

import numpy as np

from ..core import jit

_PI = math.pi
_ALPHA_MIN = 1e-3          # microfacet.ALPHA_MIN (tested equal)
_F0_CLIP = 0.9999          # microfacet.eta_from_f0's clip
_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)
_TO_UNIT = 1.0 / 9007199254740992.0

_njit = jit.njit(cache=True, nogil=True, fastmath=False)
_inline = jit.njit(cache=True, nogil=True, inline="always")


# ---------------------------------------------------------------- microfacet terms (scalars)

@_inline
def _alpha(r):
    return max(r * r, _ALPHA_MIN)


@_inline
def _ggx_d(cos_h, a):
    a2 = a * a
    t = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (_PI * t * t)


@_inline
def _lambda(cos_w, a):
    c2 = min(max(cos_w * cos_w, 1e-16), 1.0)
    return 0.5 * (math.sqrt(1.0 + a * a * (1.0 / c2 - 1.0)) - 1.0)


@_inline
def _g2(cos_o, cos_i, a):
    return 1.0 / (1.0 + _lambda(cos_o, a) + _lambda(cos_i, a))


@_inline
def _fresnel(cos_i, eta):
    c = abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    if not g2 > 0.0:
        return 1.0
    g = math.sqrt(g2)
    a = (g - c) / max(g + c, 1e-12)
    den = c * (g - c) + 1.0
    if not abs(den) > 1e-12:
        den = 1e-12
    b = (c * (g + c) - 1.0) / den
    return min(max(0.5 * a * a * (1.0 + b * b), 0.0), 1.0)


@_inline
def _eta_from_f0(f0):
    s = math.sqrt(min(max(f0, 0.0), _F0_CLIP))
    return (1.0 + s) / (1.0 - s)


@_inline
def _dielectric_f_avg(f0):
    eta = _eta_from_f0(f0)
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


@_inline
def _multiscatter(e, e_avg, f_avg):
    f_ms = f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg))
    return 1.0 + f_ms * (1.0 - e) / e


@_inline
def _node(c, size):
    """(lower node, weight) of coordinate c in [0, 1] on `size` nodes (microfacet._lerp)."""
    x = min(max(c, 0.0), 1.0) * (size - 1)
    i0 = min(int(x), size - 2)
    return i0, x - i0


@_inline
def _lerp1(tab, c0):
    i, w = _node(c0, tab.shape[0])
    return tab[i] + w * (tab[i + 1] - tab[i])


@_inline
def _lerp2(tab, c0, c1):
    i, w0 = _node(c0, tab.shape[0])
    j, w1 = _node(c1, tab.shape[1])
    lo = tab[i, j] + w0 * (tab[i + 1, j] - tab[i, j])
    hi = tab[i, j + 1] + w0 * (tab[i + 1, j + 1] - tab[i, j + 1])
    return lo + w1 * (hi - lo)


@_inline
def _lerp3(tab, c0, c1, c2):
    i, w0 = _node(c0, tab.shape[0])
    j, w1 = _node(c1, tab.shape[1])
    k, w2 = _node(c2, tab.shape[2])
    a0 = tab[i, j, k] + w0 * (tab[i + 1, j, k] - tab[i, j, k])
    a1 = tab[i, j + 1, k] + w0 * (tab[i + 1, j + 1, k] - tab[i, j + 1, k])
    a2 = tab[i, j, k + 1] + w0 * (tab[i + 1, j, k + 1] - tab[i, j, k + 1])
    a3 = tab[i, j + 1, k + 1] + w0 * (tab[i + 1, j + 1, k + 1] - tab[i, j + 1, k + 1])
    b0 = a0 + w1 * (a1 - a0)
    b1 = a2 + w1 * (a3 - a2)
    return b0 + w2 * (b1 - b0)


@_inline
def _spec_probability(metallic, f0):
    m = min(max(metallic, 0.0), 1.0)
    return 0.2 + 0.8 * m if (m > 0.0 or f0 > 0.0) else 0.0


@_inline
def basis_of(nx, ny, nz):
    """bsdf.basis for one normal: (t, b) as six numbers (light_kernels uses it too)."""
    s = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (s + nz)
    bb = nx * ny * a
    return (1.0 + s * nx * nx * a, s * bb, -s * nx), (bb, s + ny * ny * a, -ny)


# ---------------------------------------------------------------- the opaque lobes (bsdf.py)

@_inline
def _channel(b, m, ms, e, e_avg, tail, fres_d, layer, single, cos_i):
    """One colour channel of _evaluate_row: (diffuse, glossy), base colour b."""
    fres = fres_d
    if m > 0.0:
        c_m = 1.0 + ms * (_multiscatter(e, e_avg, b + (1.0 - b) / 21.0) - 1.0)
        fres = fres + m * c_m * (b + (1.0 - b) * tail)
    return (1.0 - m) * b / _PI * (1.0 - layer) * cos_i, single * fres * cos_i


@_inline
def _layer_terms(roughness, f0, multiple, e_tab, e_avg_tab, e_f_tab, r, cos_o):
    """What the lobes of row r share for every wi (they depend on wo alone): (E(mu_o), E_avg,
    the dielectric lobe's multiple-scattering scale c_d, the layer albedo A)."""
    rough, f0d, ms = roughness[r], f0[r], multiple[r]
    mu_o = min(max(cos_o, 0.0), 1.0)
    e = _lerp2(e_tab, rough, mu_o)
    e_avg = _lerp1(e_avg_tab, rough)
    c_d = 1.0 + ms * (_multiscatter(e, e_avg, _dielectric_f_avg(f0d)) - 1.0)
    e_f = _lerp3(e_f_tab, rough, mu_o, math.sqrt(math.sqrt(min(max(f0d, 0.0), 1.0))))
    without = e_f / e
    return e, e_avg, c_d, min(max(without + ms * (c_d * e_f - without), 0.0), 1.0)


@_njit
def layer_terms(roughness, n, wo, f0, multiple, e_tab, e_avg_tab, e_f_tab, terms):
    """_layer_terms of every row into terms (N, 4): computed once a path vertex, read by
    every light sample there and by its bounce."""
    for r in range(n.shape[0]):
        cos_o = n[r, 0] * wo[r, 0] + n[r, 1] * wo[r, 1] + n[r, 2] * wo[r, 2]
        terms[r, 0], terms[r, 1], terms[r, 2], terms[r, 3] = _layer_terms(
            roughness, f0, multiple, e_tab, e_avg_tab, e_f_tab, r, cos_o)


@_inline
def _evaluate_row(base, metallic, roughness, n, wo, f0, multiple, e_tab, e_avg_tab, e_f_tab,
                  r, wx, wy, wz):
    """bsdf.evaluate_parts of row r towards wi = (wx, wy, wz): (diffuse rgb, glossy rgb)."""
    cos_o = n[r, 0] * wo[r, 0] + n[r, 1] * wo[r, 1] + n[r, 2] * wo[r, 2]
    cos_i = n[r, 0] * wx + n[r, 1] * wy + n[r, 2] * wz
    if not (cos_o > 0.0 and cos_i > 0.0):
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    e, e_avg, c_d, layer = _layer_terms(roughness, f0, multiple, e_tab, e_avg_tab, e_f_tab, r,
                                        cos_o)
    return _evaluate_lobes(base, metallic, roughness, n, wo, f0, multiple, e, e_avg, c_d,
                           layer, r, cos_o, cos_i, wx, wy, wz)


@_inline
def _evaluate_lobes(base, metallic, roughness, n, wo, f0, multiple, e, e_avg, c_d, layer, r,
                    cos_o, cos_i, wx, wy, wz):
    """The lobes of row r towards wi once its _layer_terms are known (cos_o, cos_i > 0)."""
    a, cos_h, dot_oh = _half_vector(roughness, n, wo, r, wx, wy, wz)
    return _lobes_at(base, metallic, f0, multiple, e, e_avg, c_d, layer, r, cos_o, cos_i,
                     min(max(dot_oh, 0.0), 1.0), _ggx_d(cos_h, a), a)


@_inline
def _half_vector(roughness, n, wo, r, wx, wy, wz):
    """(alpha, n.h clamped to [0, 1], wo.h) of row r and wi, h the unit half vector."""
    hx, hy, hz = wo[r, 0] + wx, wo[r, 1] + wy, wo[r, 2] + wz
    ln = max(math.sqrt(hx * hx + hy * hy + hz * hz), 1e-12)
    hx, hy, hz = hx / ln, hy / ln, hz / ln
    cos_h = min(max(n[r, 0] * hx + n[r, 1] * hy + n[r, 2] * hz, 0.0), 1.0)
    return (_alpha(roughness[r]), cos_h,
            wo[r, 0] * hx + wo[r, 1] * hy + wo[r, 2] * hz)


@_inline
def _lobes_at(base, metallic, f0, multiple, e, e_avg, c_d, layer, r, cos_o, cos_i, voh, d,
              a):
    """_evaluate_lobes given wo.h clamped (voh) and the GGX density d at h."""
    m, f0d, ms = metallic[r], f0[r], multiple[r]
    fres_d = (1.0 - m) * (c_d * _fresnel(voh, _eta_from_f0(f0d)))
    single = (d * _g2(cos_o, max(cos_i, 1e-8), a)
              / (4.0 * max(cos_o, 1e-8) * max(cos_i, 1e-8)))
    tail = (1.0 - voh) ** 5
    d0, g0 = _channel(base[r, 0], m, ms, e, e_avg, tail, fres_d, layer, single, cos_i)
    d1, g1 = _channel(base[r, 1], m, ms, e, e_avg, tail, fres_d, layer, single, cos_i)
    d2, g2 = _channel(base[r, 2], m, ms, e, e_avg, tail, fres_d, layer, single, cos_i)
    return (d0, d1, d2), (g0, g1, g2)


@_inline
def _lobes_and_pdfs(base, metallic, roughness, n, wo, f0, multiple, terms, r, wx, wy, wz):
    """_evaluate_row (its _layer_terms read from `terms`) and _pdf_row of row r towards wi in
    one, the half vector and the GGX density computed once: (diffuse rgb, glossy rgb, glossy
    pdf, diffuse pdf)."""
    cos_o = n[r, 0] * wo[r, 0] + n[r, 1] * wo[r, 1] + n[r, 2] * wo[r, 2]
    cos_i = n[r, 0] * wx + n[r, 1] * wy + n[r, 2] * wz
    a, cos_h, dot_oh = _half_vector(roughness, n, wo, r, wx, wy, wz)
    d = _ggx_d(cos_h, a)
    ps = _spec_probability(metallic[r], f0[r])
    pg = ps * (d * cos_h / (4.0 * max(dot_oh, 1e-8)))
    pd = (1.0 - ps) * (max(cos_i, 0.0) / _PI)
    if not (cos_o > 0.0 and cos_i > 0.0):
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), pg, pd
    d3, g3 = _lobes_at(base, metallic, f0, multiple, terms[r, 0], terms[r, 1], terms[r, 2],
                       terms[r, 3], r, cos_o, cos_i, min(max(dot_oh, 0.0), 1.0), d, a)
    return d3, g3, pg, pd


@_inline
def _pdf_row(metallic, roughness, n, wo, f0, r, wx, wy, wz):
    """bsdf.pdf_parts of row r for wi = (wx, wy, wz): (glossy, diffuse)."""
    a, cos_h, dot_oh = _half_vector(roughness, n, wo, r, wx, wy, wz)
    cos_i = n[r, 0] * wx + n[r, 1] * wy + n[r, 2] * wz
    ps = _spec_probability(metallic[r], f0[r])
    return (ps * (_ggx_d(cos_h, a) * cos_h / (4.0 * max(dot_oh, 1e-8))),
            (1.0 - ps) * (max(cos_i, 0.0) / _PI))


@_inline
def _sample_row(metallic, roughness, n, wo, u1, u2, u3, f0, r):
    """bsdf.sample_direction of row r: (wx, wy, wz, glossy)."""
    return _sample_row_u(metallic, roughness, n, wo, u1[r], u2[r], u3[r], f0, r)


@_inline
def _sample_row_u(metallic, roughness, n, wo, u1, u2, u3, f0, r):
    """_sample_row with the row's three uniforms given."""
    nx, ny, nz = n[r, 0], n[r, 1], n[r, 2]
    t, b = basis_of(nx, ny, nz)
    a = _alpha(roughness[r])
    glossy = u3 < _spec_probability(metallic[r], f0[r])
    phi = 2.0 * _PI * u2
    if glossy:
        tan2 = a * a * u1 / max(1.0 - u1, 1e-12)
        lz = 1.0 / math.sqrt(1.0 + tan2)
        rad = math.sqrt(max(0.0, 1.0 - lz * lz))
    else:
        rad = math.sqrt(u1)
        lz = math.sqrt(max(0.0, 1.0 - u1))
    lx, ly = rad * math.cos(phi), rad * math.sin(phi)
    vx = lx * t[0] + ly * b[0] + lz * nx
    vy = lx * t[1] + ly * b[1] + lz * ny
    vz = lx * t[2] + ly * b[2] + lz * nz
    if glossy:
        hd = wo[r, 0] * vx + wo[r, 1] * vy + wo[r, 2] * vz
        vx, vy, vz = 2.0 * hd * vx - wo[r, 0], 2.0 * hd * vy - wo[r, 1], 2.0 * hd * vz - wo[r, 2]
    ln = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    return vx / ln, vy / ln, vz / ln, glossy


@_njit
def evaluate_parts(base, metallic, roughness, n, wo, wi, f0, multiple, e_tab, e_avg_tab,
                   e_f_tab, diffuse, glossy):
    """bsdf.evaluate_parts into `diffuse` and `glossy` (N, 3)."""
    for r in range(n.shape[0]):
        d3, g3 = _evaluate_row(base, metallic, roughness, n, wo, f0, multiple, e_tab,
                               e_avg_tab, e_f_tab, r, wi[r, 0], wi[r, 1], wi[r, 2])
        for c in range(3):
            diffuse[r, c] = d3[c]
            glossy[r, c] = g3[c]


@_njit
def pdf_parts(metallic, roughness, n, wo, wi, f0, glossy, diffuse):
    """bsdf.pdf_parts into `glossy` and `diffuse` (N,)."""
    for r in range(n.shape[0]):
        glossy[r], diffuse[r] = _pdf_row(metallic, roughness, n, wo, f0, r, wi[r, 0],
                                         wi[r, 1], wi[r, 2])


@_njit
def sample_direction(metallic, roughness, n, wo, u1, u2, u3, f0, wi, spec):
    """bsdf.sample_direction into `wi` (N, 3) and `spec` (N,) bool."""
    for r in range(n.shape[0]):
        wi[r, 0], wi[r, 1], wi[r, 2], spec[r] = _sample_row(metallic, roughness, n, wo, u1, u2,
                                                            u3, f0, r)


@_inline
def _power(p_this, p_other):
    """shading.power_heuristic for one pair."""
    a, b = p_this * p_this, p_other * p_other
    if not (b > 0.0 and not math.isinf(a)):
        return 1.0
    return a / max(a + b, 1e-300)


@_inline
def contribution_one(thr, base, metallic, roughness, nf, ng, wo, f0, multiple, opaque,
                     glossy_on, diffuse_on, terms, r, wx, wy, wz, l0, l1, l2, pl, contrib, k):
    """light_contribution of surface point r for a light sample (wi, Li / p, p) into row k of
    contrib; whether it is not zero."""
    lmax = max(abs(l0), abs(l1), abs(l2))
    if not (lmax > 0.0 and ng[r, 0] * wx + ng[r, 1] * wy + ng[r, 2] * wz > 0.0
            and opaque[r] > 0.0):
        for c in range(3):
            contrib[k, c] = 0.0
        return False
    d3, g3, pg, pd = _lobes_and_pdfs(base, metallic, roughness, nf, wo, f0, multiple, terms,
                                     r, wx, wy, wz)
    pg = opaque[r] * pg if glossy_on[r] else 0.0
    pd = opaque[r] * pd if diffuse_on[r] else 0.0
    wd, wg = 1.0, 1.0
    if not math.isinf(pl):
        wd, wg = _power(pl, pd), _power(pl, pg)
    big = 0.0
    li = (l0, l1, l2)
    for c in range(3):
        v = thr[r, c] * (d3[c] * wd + g3[c] * wg) * (li[c] * opaque[r])
        contrib[k, c] = v
        big = max(big, abs(v))
    return big > 0.0


@_njit
def light_contribution(thr, base, metallic, roughness, nf, ng, wo, wi, li, pl, f0, multiple,
                       opaque, glossy_on, diffuse_on, terms, contrib, keep):
    """One light sample at each surface point (shading.Shader._light_samples): where the light
    arrives (Li > 0) from above the face (ng.wi > 0) at an opaque share, the lobes times Li
    and the opaque share, each lobe weighed against its own bounce density (power heuristic;
    weight 1 for a delta light, or where that lobe cannot bounce: glossy_on / diffuse_on
    False) into contrib (N, 3); keep: the contribution is not zero (a shadow ray to cast)."""
    for r in range(nf.shape[0]):
        keep[r] = contribution_one(thr, base, metallic, roughness, nf, ng, wo, f0, multiple,
                                   opaque, glossy_on, diffuse_on, terms, r, wi[r, 0],
                                   wi[r, 1], wi[r, 2], li[r, 0], li[r, 1], li[r, 2], pl[r],
                                   contrib, r)


@_inline
def _dielectric_row(n, wo, eta, roughness, u1, u2, u3, r):
    """dielectric.sample of row r: (wx, wy, wz, weight, refracted, ok)."""
    nx, ny, nz = n[r, 0], n[r, 1], n[r, 2]
    a = _alpha(roughness[r])
    t, b = basis_of(nx, ny, nz)
    tan2 = 0.0 if a <= _ALPHA_MIN else a * a * u1[r] / max(1.0 - u1[r], 1e-12)
    cos_m = 1.0 / math.sqrt(1.0 + tan2)
    sin_m = math.sqrt(max(0.0, 1.0 - cos_m * cos_m))
    phi = 2.0 * _PI * u2[r]
    sx, sy = sin_m * math.cos(phi), sin_m * math.sin(phi)
    mx = sx * t[0] + sy * b[0] + cos_m * nx
    my = sx * t[1] + sy * b[1] + cos_m * ny
    mz = sx * t[2] + sy * b[2] + cos_m * nz
    ox, oy, oz = wo[r, 0], wo[r, 1], wo[r, 2]
    c = ox * mx + oy * my + oz * mz
    refract = u3[r] >= _fresnel(c, eta)
    if refract:
        inv = 1.0 / eta
        k = max(1.0 - (1.0 - c * c) * inv * inv, 0.0)
        s = c * inv - math.sqrt(k)
        vx, vy, vz = s * mx - inv * ox, s * my - inv * oy, s * mz - inv * oz
    else:
        vx, vy, vz = 2.0 * c * mx - ox, 2.0 * c * my - oy, 2.0 * c * mz - oz
    ln = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    vx, vy, vz = vx / ln, vy / ln, vz / ln
    cos_o = nx * ox + ny * oy + nz * oz
    cos_i = nx * vx + ny * vy + nz * vz
    g = 1.0 if a <= _ALPHA_MIN else _g2(abs(cos_o), abs(cos_i), a)
    good = c > 0.0 and ((cos_i < 0.0) if refract else (cos_i > 0.0))
    weight = abs(c) * g / max(abs(cos_o) * cos_m, 1e-12) if good else 0.0
    return vx, vy, vz, weight, refract, good


@_njit
def dielectric_sample(n, wo, eta, roughness, u1, u2, u3, wi, weight, refracted, ok):
    """dielectric.sample into `wi` (N, 3), `weight` (N,), `refracted` and `ok` (N,) bool."""
    for r in range(n.shape[0]):
        wi[r, 0], wi[r, 1], wi[r, 2], weight[r], refracted[r], ok[r] = _dielectric_row(
            n, wo, eta[r], roughness, u1, u2, u3, r)


@_njit
def bounce(thr, w0, depth, kinds, base, metallic, roughness, f0, multiple, transmission, ior,
           tint_reflection, nf, ng, wo, loc, eps, front, go, u0, u1, u2, u3, u_roulette,
           limits, min_light_bounces, terms, origin, wi, thr_out, pdf, kinds_out, ok):
    """shading.Shader._bounce row by row: glass with probability `transmission`, else the
    opaque lobes (a direction from the lobe u3 chooses, weighed f_j (n.wi) / (P_j p_j)); the
    kind's bounce count and limit, Russian
    roulette after min_light_bounces bounces; ok: the path goes on."""
    for r in range(nf.shape[0]):
        trans = transmission[r]
        opaque = 1.0 - trans
        for j in range(4):
            kinds_out[r, j] = kinds[r, j]
        if u3[r] < trans:                                  # glass
            eta = ior[r] if front[r] else 1.0 / ior[r]
            wx, wy, wz, gw, refr, good = _dielectric_row(nf, wo, eta, roughness, u0, u1, u2, r)
            tr = tint_reflection[r]
            for c in range(3):
                tint = base[r, c] if refr else tr * base[r, c] + (1.0 - tr)
                thr_out[r, c] = tint * gw
            side = ng[r, 0] * wx + ng[r, 1] * wy + ng[r, 2] * wz
            going = good and ((side < 0.0) if refr else (side > 0.0))
            p = 0.0
            kind = 2 if refr else 1
            sgn = -1.0 if refr else 1.0
        else:                                              # the opaque lobes
            u_lobe = (u3[r] - trans) / max(opaque, 1e-12)
            wx, wy, wz, spec = _sample_row_u(metallic, roughness, nf, wo, u0[r], u1[r], u_lobe,
                                             f0, r)
            d3, g3, pg, pd = _lobes_and_pdfs(base, metallic, roughness, nf, wo, f0, multiple,
                                             terms, r, wx, wy, wz)
            lobe = pg if spec else pd
            inv = 1.0 / lobe if lobe > 0.0 else 1.0
            for c in range(3):
                thr_out[r, c] = (g3[c] if spec else d3[c]) * inv
            going = (nf[r, 0] * wx + nf[r, 1] * wy + nf[r, 2] * wz > 0.0 and lobe > 0.0
                     and ng[r, 0] * wx + ng[r, 1] * wy + ng[r, 2] * wz > 0.0)
            p = opaque * lobe
            kind = 1 if spec else 0
            sgn = 1.0
        for c in range(3):
            origin[r, c] = loc[r, c] + sgn * ng[r, c] * eps[r]
        wi[r, 0], wi[r, 1], wi[r, 2] = wx, wy, wz
        pdf[r] = p
        kinds_out[r, kind] += 1
        going = going and go[r] and kinds_out[r, kind] <= limits[kind]
        big = 0.0
        for c in range(3):
            thr_out[r, c] = thr[r, c] * thr_out[r, c]
            big = max(big, abs(thr_out[r, c]))
        q = 1.0
        if depth[r] + 1 > max(min_light_bounces, 1):
            q = min(1.0, math.sqrt(big / max(w0[r], 1e-300)))
            going = going and u_roulette[r] < q
        inv_q = 1.0 / max(q, 1e-12)
        big = 0.0
        for c in range(3):
            thr_out[r, c] = thr_out[r, c] * inv_q
            big = max(big, abs(thr_out[r, c]))
        ok[r] = going and big > 0.0


# ---------------------------------------------------------------- the bundle's sums

@_njit
def accumulate_rows(rgb, idx, row, keep, contrib, direct, limit_direct, limit_indirect):
    """`accumulate` of the contributions i that are kept, each to the camera sample idx[r]
    of its surface row r = row[i], direct as direct[r]: the gathers of a sum in the pass."""
    for i in range(row.shape[0]):
        if keep[i]:
            r = row[i]
            add_one(rgb, idx[r], contrib[i, 0], contrib[i, 1], contrib[i, 2],
                    limit_direct if direct[r] else limit_indirect)


@_njit
def accumulate(rgb, samples, contrib, direct, limit_direct, limit_indirect):
    """rgb[samples[r]] += contrib[r], clamped as shading.clamped: scaled so that |r| + |g| +
    |b| <= the direct limit (direct[r]) or the indirect one, 0 meaning no clamp."""
    for r in range(samples.shape[0]):
        add_one(rgb, samples[r], contrib[r, 0], contrib[r, 1], contrib[r, 2],
                limit_direct if direct[r] else limit_indirect)


@_inline
def add_one(rgb, j, c0, c1, c2, limit):
    """rgb[j] += (c0, c1, c2) clamped to |r| + |g| + |b| <= limit (0: no clamp)."""
    scale = 1.0
    if limit > 0.0:
        scale = min(1.0, limit / max(abs(c0) + abs(c1) + abs(c2), 1e-300))
    rgb[j, 0] += c0 * scale
    rgb[j, 1] += c1 * scale
    rgb[j, 2] += c2 * scale


# ---------------------------------------------------------------- random numbers

@_inline
def _mix(x):
    x = x ^ (x >> np.uint64(30))
    x = x * _M2
    x = x ^ (x >> np.uint64(27))
    x = x * _M3
    return x ^ (x >> np.uint64(31))


@_inline
def hash_one(salt, dim1, pixel, sample):
    """camera_rays.hash_u01 of one (pixel, sample): salt = (seed 0x2545F491 + dim
    0x632BE5AB) mod 2^48 and dim1 = dim + 1, both uint64 (`salts`)."""
    x = _mix(np.uint64(pixel) * _M1 + salt)
    x = _mix(x ^ (np.uint64(sample) * _M2 + dim1))
    return np.float64(x >> np.uint64(11)) * _TO_UNIT


def salts(seed: int, dim: int):
    """(salt, dim1) of hash_one for a seed and dimension."""
    return (np.uint64((seed * 0x2545F491 + dim * 0x632BE5AB) & 0xFFFFFFFFFFFF),
            np.uint64(dim + 1))


@_njit
def hash_u01(salt, dim1, pixel, sample, out):
    """hash_one of every (pixel, sample) (N,) int64 into `out`."""
    for r in range(pixel.shape[0]):
        out[r] = hash_one(salt, dim1, pixel[r], sample[r])


# ---------------------------------------------------------------- array wrappers

def active() -> bool:
    """Whether the shading runs these kernels (core.jit.mode(): NEUROLENS_KERNELS, numba)."""
    return jit.mode() == "compiled"


def _f(a):
    return np.ascontiguousarray(a, dtype=np.float64)


def _rows(a, k, default):
    """(k,) float64 of a per-row value, a scalar or None (then `default`)."""
    if a is None:
        return np.full(k, float(default))
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), (k,)))


def run_evaluate_parts(base, metallic, roughness, n, wo, wi, f0, multiple, tables):
    k = n.shape[0]
    diffuse, glossy = np.empty((k, 3)), np.empty((k, 3))
    evaluate_parts(_f(base), _f(metallic), _f(roughness), _f(n), _f(wo), _f(wi),
                   _rows(f0, k, 0.04), _rows(multiple, k, 1.0), *tables, diffuse, glossy)
    return diffuse, glossy


def run_layer_terms(roughness, n, wo, f0, multiple, tables):
    """`layer_terms` of surface points (N, 4)."""
    k = n.shape[0]
    terms = np.empty((k, 4))
    layer_terms(_f(roughness), _f(n), _f(wo), _rows(f0, k, 0.04), _rows(multiple, k, 1.0),
                *tables, terms)
    return terms


def run_light_contribution(thr, base, metallic, roughness, nf, ng, wo, wi, li, pl, f0,
                           multiple, opaque, glossy_on, diffuse_on, tables, terms=None):
    """`light_contribution`; terms: the points' run_layer_terms (None: computed here)."""
    k = nf.shape[0]
    if terms is None:
        terms = run_layer_terms(roughness, nf, wo, f0, multiple, tables)
    contrib, keep = np.empty((k, 3)), np.empty(k, dtype=np.bool_)
    light_contribution(_f(thr), _f(base), _f(metallic), _f(roughness), _f(nf), _f(ng), _f(wo),
                       _f(wi), _f(li), _f(pl), _rows(f0, k, 0.04), _rows(multiple, k, 1.0),
                       _f(opaque), np.ascontiguousarray(glossy_on, dtype=np.bool_),
                       np.ascontiguousarray(diffuse_on, dtype=np.bool_), terms, contrib, keep)
    return contrib, keep


def run_bounce(thr, w0, depth, kinds, sp, nf, ng, wo, loc, eps, front, go, u, u_roulette,
               limits, min_light_bounces, tables, terms=None):
    """`bounce` over a bundle's surface points (sp: materials.SurfacePoint); (origin, wi,
    throughput, pdf, kinds, ok); terms: the points' run_layer_terms (None: computed here)."""
    k = nf.shape[0]
    if terms is None:
        terms = run_layer_terms(sp.roughness, nf, wo, sp.f0, sp.multiscatter, tables)
    origin, wi, thr_out = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
    pdf, kinds_out, ok = np.empty(k), np.empty((k, 4), np.int64), np.empty(k, np.bool_)
    bounce(_f(thr), _f(w0), np.ascontiguousarray(depth, np.int64),
           np.ascontiguousarray(kinds, np.int64), _f(sp.base), _f(sp.metallic),
           _f(sp.roughness), _rows(sp.f0, k, 0.04), _rows(sp.multiscatter, k, 1.0),
           _f(sp.transmission), _f(sp.ior), _f(sp.tint_reflection), _f(nf), _f(ng), _f(wo),
           _f(loc), _f(np.reshape(eps, (k,))), np.ascontiguousarray(front, np.bool_),
           np.ascontiguousarray(go, np.bool_), *(_f(x) for x in u), _f(u_roulette),
           np.ascontiguousarray(limits, np.int64), int(min_light_bounces), terms,
           origin, wi, thr_out, pdf, kinds_out, ok)
    return origin, wi, thr_out, pdf, kinds_out, ok


def run_pdf_parts(metallic, roughness, n, wo, wi, f0):
    k = n.shape[0]
    glossy, diffuse = np.empty(k), np.empty(k)
    # f0 None: bsdf.spec_probability without f0, the glossy lobe always present (f0 > 0)
    pdf_parts(_f(metallic), _f(roughness), _f(n), _f(wo), _f(wi), _rows(f0, k, 1.0), glossy,
              diffuse)
    return glossy, diffuse


def run_sample_direction(metallic, roughness, n, wo, u1, u2, u3, f0):
    k = n.shape[0]
    wi, spec = np.empty((k, 3)), np.empty(k, dtype=np.bool_)
    sample_direction(_f(metallic), _f(roughness), _f(n), _f(wo), _f(u1), _f(u2), _f(u3),
                     _rows(f0, k, 1.0), wi, spec)
    return wi, spec


def run_dielectric_sample(n, wo, eta, roughness, u1, u2, u3):
    k = n.shape[0]
    wi, weight = np.empty((k, 3)), np.empty(k)
    refracted, ok = np.empty(k, dtype=np.bool_), np.empty(k, dtype=np.bool_)
    dielectric_sample(_f(n), _f(wo), _rows(eta, k, 1.0), _f(roughness), _f(u1), _f(u2),
                      _f(u3), wi, weight, refracted, ok)
    return wi, weight, refracted, ok


def run_accumulate_rows(rgb, idx, row, keep, contrib, direct, limit_direct, limit_indirect):
    """`accumulate_rows` into rgb (C-contiguous float64, changed in place)."""
    accumulate_rows(rgb, np.ascontiguousarray(idx, np.int64), np.ascontiguousarray(row, np.int64),
                    np.ascontiguousarray(keep, np.bool_), _f(contrib),
                    np.ascontiguousarray(direct, np.bool_), float(limit_direct),
                    float(limit_indirect))


def run_accumulate(rgb, samples, contrib, direct, limit_direct, limit_indirect):
    """`accumulate` into rgb (C-contiguous float64, changed in place)."""
    k = samples.shape[0]
    accumulate(rgb, np.ascontiguousarray(samples, dtype=np.int64), _f(contrib),
               np.ascontiguousarray(np.broadcast_to(direct, (k,)), dtype=np.bool_),
               float(limit_direct), float(limit_indirect))


def run_hash_u01_dims(seed: int, pixel, sample, dims) -> np.ndarray:
    """(len(dims), N): hash_u01 of each dimension, in one call per dimension without the
    per-call conversions ((N,) int64 pixel and sample)."""
    pixel = np.ascontiguousarray(pixel, dtype=np.int64)
    sample = np.asarray(sample, dtype=np.int64)
    sample = np.ascontiguousarray(sample) if sample.shape == pixel.shape else \
        np.full(pixel.shape, sample)
    out = np.empty((len(dims), pixel.size))
    for i, dim in enumerate(dims):
        hash_u01(*salts(seed, dim), pixel, sample, out[i])
    return out


def run_hash_u01(seed: int, pixel, sample, dim: int) -> np.ndarray:
    pixel, sample = np.asarray(pixel, dtype=np.int64), np.asarray(sample, dtype=np.int64)
    shape = np.broadcast_shapes(pixel.shape, sample.shape)
    pixel, sample = (np.ascontiguousarray(a) if a.shape == shape else np.full(shape, a)
                     for a in (pixel, sample))
    out = np.empty(pixel.shape, dtype=np.float64)
    hash_u01(*salts(seed, dim), pixel.ravel(), sample.ravel(), out.reshape(-1))
    return out
