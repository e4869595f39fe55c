"""The GGX microfacet terms, as Cycles' Principled BSDF evaluates them (Blender 4 and 5, its
default distribution Multiscatter GGX); shared by the opaque lobes (bsdf.py) and glass
(dielectric.py).

With alpha = max(roughness^2, ALPHA_MIN), unit normal n and mu = n.w for a direction w:
    D(h)        = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)           (GGX / Trowbridge-Reitz)
    Lambda(w)   = (sqrt(1 + alpha^2 (1 - mu^2) / mu^2) - 1) / 2           (Smith, for GGX)
    G1(w)       = 1 / (1 + Lambda(w))
    G2(wo, wi)  = 1 / (1 + Lambda(wo) + Lambda(wi))
G2 is the height-correlated masking-shadowing term (Heitz 2014, "Understanding the Masking-
Shadowing Function"), Cycles' bsdf_G: a microfacet hidden from the light is likely hidden
from the viewer too, being low. The uncorrelated product G1(wo) G1(wi), which the engine used
before, counts it twice; they part where both Lambdas are large, at grazing light on a rough
surface (alpha 1, mu_o 0.24, mu_i 0.10: 0.076 against 0.145): a sunlit ground of roughness 1
under a sun 6 degrees high rendered 0.40x Cycles (docs/render-engine.md).
    F(c, eta)   = 1/2 ((g - c) / (g + c))^2 (1 + ((c (g + c) - 1) / (c (g - c) + 1))^2),
                g^2 = eta^2 - 1 + c^2: the exact unpolarised dielectric reflectance for
                c = wo.h and eta = n_t / n_i (g^2 < 0: total internal reflection, F = 1)
    F0 = ((eta - 1) / (eta + 1))^2,   eta = (1 + sqrt F0) / (1 - sqrt F0)   (normal incidence)

Directional albedo of the single-scattering lobe with reflectance F (F = 1: E):
    E_F(mu_o) = int D G2 F / (4 mu_o) (n.wi) dwi = mean over h ~ the visible normals of wo of
                F(wo.h) G2(wo, wi) / G1(wo),   wi = 2 (wo.h) h - wo  (0 where wi is below n)
computed on a deterministic grid of the visible-normal sampling of Heitz 2018 ("Sampling the
GGX Distribution of Visible Normals": polar disc coordinates, warped by wo; QUAD^2 points a
node for E, QUAD_F^2 for E_F) and tabulated on Cycles' nodes, read by multilinear
interpolation (within 0.009 of a 300^2-point quadrature for E, 0.0015 for E_F at z <= 0.6;
built once and kept in the user's cache folder, `tables_cache_path`, for later processes):
    E(r, mu)      32 x 32 nodes r, mu = i / 31 (clamped to >= 1e-4),  E_avg(r) = 2 int E mu dmu
    E_F(r, mu, z) the dielectric's, 16^3 nodes, z = F0^(1/4) in [1e-4, 0.99] (eta 1 .. ~400)
Multiple scattering (Kulla & Conty 2017, "Revisiting Physically Based Shading at Imageworks",
as Cycles' Multiscatter GGX): the single-scattering lobe is scaled by
    c(mu_o) = 1 + F_ms (1 - E(mu_o)) / E(mu_o),   F_ms = F_avg E_avg / (1 - F_avg (1 - E_avg))
with F_avg = 2 int F mu dmu the lobe's mean reflectance: (eta - 1) / (4.08567 + 1.00071 eta)
for the dielectric (Kulla and Conty's fit) and F0 + (1 - F0) / 21 for Schlick's
F0 + (1 - F0)(1 - c)^5 (exactly). A white lobe (F = 1) thereby reflects all the light at every
angle (c E = 1), where single scattering loses up to 69 % (alpha 1, normal incidence).
Layer albedo, what a dielectric specular layer reflects from wo, as Cycles' bsdf_albedo (the
diffuse layer below receives the rest, 1 - A):
    A(mu_o) = c(mu_o) E_F(mu_o)   with multiple scattering,   E_F(mu_o) / E(mu_o)   without
(Cycles' estimate assumes the plain lobe's albedo is 1).
"""

from __future__ import annotations

import hashlib
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

ALPHA_MIN = 1e-3
#: quadrature points per axis of the visible-normal grid of each node of E and of E_F (whose
#: values, the Fresnel's share of E, are ~0.04-0.2 for common IORs: the same relative error
#: is a fifth of the absolute one)
QUAD, QUAD_F = 48, 32


def alpha(roughness):
    return np.maximum(np.asarray(roughness, dtype=np.float64) ** 2, ALPHA_MIN)


def ggx_d(cos_h, alpha):
    a2 = alpha * alpha
    t = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * t * t)


def smith_lambda(cos_w, alpha):
    c2 = np.clip(np.asarray(cos_w, dtype=np.float64) ** 2, 1e-16, 1.0)
    return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 / c2 - 1.0)) - 1.0)


def smith_g1(cos_w, alpha):
    return 1.0 / (1.0 + smith_lambda(cos_w, alpha))


def smith_g2(cos_o, cos_i, alpha):
    """Height-correlated masking-shadowing of the directions with n.w = cos_o and cos_i."""
    return 1.0 / (1.0 + smith_lambda(cos_o, alpha) + smith_lambda(cos_i, alpha))


def fresnel(cos_i, eta):
    """Unpolarised reflectance of a dielectric interface for |cos| of the incident angle and
    eta = n_t / n_i (1 under total internal reflection)."""
    c = np.abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - c) / np.maximum(g + c, 1e-12)
    b = (c * (g + c) - 1.0) / np.where(np.abs(c * (g - c) + 1.0) > 1e-12,
                                      c * (g - c) + 1.0, 1e-12)
    return np.where(g2 > 0.0, np.clip(0.5 * a * a * (1.0 + b * b), 0.0, 1.0), 1.0)


def eta_from_f0(f0):
    """The relative IOR (>= 1) whose reflectance at normal incidence is F0 (< 1)."""
    s = np.sqrt(np.clip(np.asarray(f0, dtype=np.float64), 0.0, 0.9999))
    return (1.0 + s) / (1.0 - s)


def schlick(cos_i, f0):
    """Schlick's reflectance F0 + (1 - F0)(1 - c)^5 ((N,) cosines, (N, 3) F0)."""
    return f0 + (1.0 - f0) * ((1.0 - np.clip(cos_i, 0.0, 1.0)) ** 5)[:, None]


# -- the albedo tables


def _albedo_nodes(rough, mu, eta=None, n=QUAD):
    """E_F at every (rough, mu[, eta]) node: (R, M) for F = 1 (eta None), else (R, M, Z)."""
    u1 = (np.arange(n) + 0.5) / n
    r_disc = np.sqrt(u1)[:, None]
    phi = (2.0 * np.pi * (np.arange(n) + 0.5) / n)[None, :]
    t1, t2_disc = (r_disc * np.cos(phi)).ravel(), (r_disc * np.sin(phi)).ravel()
    out = []
    for r in rough:                                  # a node row at a time bounds the memory
        a = max(float(r) ** 2, 1e-8)
        m = np.asarray(mu, dtype=np.float64)[:, None]
        so = np.sqrt(1.0 - m * m)
        # wo = (so, 0, m) stretched by alpha; T1 = y, T2 = wo_s x T1
        sx, sz = a * so, m
        ln = np.hypot(sx, sz)
        sx, sz = sx / ln, sz / ln
        w = 0.5 * (1.0 + sz)
        t2 = (1.0 - w) * np.sqrt(np.maximum(1.0 - t1 * t1, 0.0)) + w * t2_disc
        tz = np.sqrt(np.maximum(1.0 - t1 * t1 - t2 * t2, 0.0))
        hx, hy, hz = a * (tz * sx - t2 * sz), a * t1, np.maximum(tz * sz + t2 * sx, 0.0)
        hn = np.sqrt(hx * hx + hy * hy + hz * hz)
        hx, hz = hx / hn, hz / hn
        oh = so * hx + m * hz
        mi = 2.0 * oh * hz - m
        lo = smith_lambda(m, a)
        g = np.where(mi > 0.0, (1.0 + lo) / (1.0 + lo + smith_lambda(np.maximum(mi, 1e-12), a)),
                     0.0)
        if eta is None:
            out.append(g.mean(axis=1))
        else:
            e = np.asarray(eta, dtype=np.float64)
            out.append(np.stack([(g * fresnel(oh, k)).mean(axis=1) for k in e], axis=1))
    return np.asarray(out)


def _nodes(count, low=1e-4, high=1.0):
    return np.clip(np.arange(count) / (count - 1), low, high)


#: the tables' shapes (E, E_avg, E_F)
_SHAPES = ((32, 32), (32,), (16, 16, 16))


def tables_cache_path() -> Path:
    """Where the tables are kept between processes: the user's kernel cache folder
    (core.jit), named by a digest of this file (a changed quadrature gets fresh tables)."""
    from ..core import jit
    digest = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]
    return jit.cache_dir() / f"ggx-albedo-{digest}.npz"


def _load_cached():
    """The tables from tables_cache_path(), or None where absent, unreadable or not tables of
    the right shapes and range (then they are computed again)."""
    try:
        with np.load(tables_cache_path(), allow_pickle=False) as f:
            tabs = tuple(np.array(f[k], dtype=np.float64) for k in ("e", "e_avg", "e_f"))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    ok = all(t.shape == shape and np.isfinite(t).all() and t.min() >= 0.0 and t.max() <= 1.0
             for t, shape in zip(tabs, _SHAPES))
    return tabs if ok else None


def _store(tabs) -> None:
    """Keep the tables for later processes (written whole or not at all); a folder that
    cannot be written only costs the next process the computation."""
    from ..core.atomic import atomic_path
    path = tables_cache_path()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path, verify=lambda tmp: None) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, e=tabs[0], e_avg=tabs[1], e_f=tabs[2])
    except OSError:
        pass


@lru_cache(maxsize=1)
def _tables():
    """(E (32, 32), E_avg (32,), E_F (16, 16, 16)): from the user's cache where an earlier
    process left them, else computed (module docstring) and left there."""
    cached = _load_cached()
    if cached is not None:
        return cached
    tabs = _compute_tables()
    _store(tabs)
    return tabs


def _compute_tables():
    e = _albedo_nodes(_nodes(32), _nodes(32))
    mu = _nodes(32)
    # E_avg = 2 int E mu dmu, trapezoids over the nodes
    f = 2.0 * e * mu[None, :]
    e_avg = ((f[:, 1:] + f[:, :-1]) * 0.5 * np.diff(mu)[None, :]).sum(axis=1)
    z = _nodes(16, 1e-4, 0.99)
    e_f = _albedo_nodes(_nodes(16), _nodes(16), eta_from_f0(z ** 4), QUAD_F)
    return np.clip(e, 1e-6, 1.0), np.clip(e_avg, 1e-6, 1.0), np.clip(e_f, 0.0, 1.0)


def tables():
    """(E, E_avg, E_F): the albedo tables (computed once), as the compiled kernels read them."""
    return _tables()


def _lerp(table, *coords):
    """Multilinear interpolation of a table over [0, 1]^k (node i at i / (size - 1))."""
    shape = table.shape
    strides = np.cumprod((1,) + shape[:0:-1])[::-1]             # row-major, in elements
    flat = np.zeros(np.shape(coords[0]), dtype=np.intp)
    weights = []
    for size, stride, c in zip(shape, strides, coords):
        x = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0) * (size - 1)
        i0 = np.minimum(x.astype(np.intp), size - 2)            # x >= 0: truncation is floor
        flat += i0 * stride
        weights.append(x - i0)
    # the 2^k corners at once (corner c has bit d set: the upper node along axis d), then
    # one axis at a time: pairs of corners differing in that axis' bit, lower first
    offsets = np.array([sum(((c >> d) & 1) * strides[d] for d in range(len(shape)))
                        for c in range(1 << len(shape))], dtype=np.intp)
    v = table.ravel().take(flat[None] + offsets.reshape((-1,) + (1,) * flat.ndim))
    for w in weights:
        v = v[0::2] + w * (v[1::2] - v[0::2])
    return v[0]


def single_albedo(roughness, cos_o):
    """(E(mu_o), E_avg): the share of light the plain lobe (F = 1) reflects from direction
    mu_o, and its mean over the hemisphere (cosine-weighted)."""
    tab = _tables()
    return _lerp(tab[0], roughness, cos_o), _lerp(tab[1], roughness)


def dielectric_albedo(roughness, cos_o, f0):
    """E_F(mu_o) of the lobe with the dielectric Fresnel of reflectance F0 at normal
    incidence."""
    # z = F0^(1/4) read as Cycles reads its table: node i at z = i / 15
    return _lerp(_tables()[2], roughness, cos_o,
                 np.sqrt(np.sqrt(np.clip(np.asarray(f0, dtype=np.float64), 0.0, 1.0))))


def dielectric_f_avg(f0):
    """F_avg of the dielectric Fresnel (Kulla and Conty's fit in eta)."""
    eta = eta_from_f0(f0)
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


def schlick_f_avg(f0):
    """F_avg of Schlick's Fresnel: 2 int (F0 + (1 - F0)(1 - mu)^5) mu dmu."""
    return f0 + (1.0 - f0) / 21.0


def multiscatter(e, e_avg, f_avg):
    """c(mu_o), the multiple-scattering scale of a lobe of mean reflectance f_avg, from its
    E(mu_o) and E_avg (single_albedo); arrays broadcast together."""
    f_ms = f_avg * e_avg / (1.0 - f_avg * (1.0 - e_avg))
    return 1.0 + f_ms * (1.0 - e) / e


def layer_albedo(e, e_f, c, multiple=1.0):
    """A(mu_o): what a dielectric specular layer reflects from mu_o in all, from its E, E_F
    and c, with multiple scattering where `multiple` is 1 (Multiscatter GGX), without where
    0."""
    with_ms, without = c * e_f, e_f / e
    return np.clip(without + np.asarray(multiple) * (with_ms - without), 0.0, 1.0)
