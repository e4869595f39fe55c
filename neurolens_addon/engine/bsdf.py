"""The surface model: Cycles' Principled BSDF without coat, sheen and subsurface: a Lambert
diffuse layer under a dielectric GGX specular layer, mixed with a metallic GGX lobe.

With base colour b, metallic m, roughness r, unit normal n facing the outgoing direction wo
(towards the viewer), incoming direction wi (towards the light), h = (wo + wi) / |wo + wi|,
mu_o = n.wo and the GGX terms of microfacet.py (D, the height-correlated G2, the dielectric
Fresnel F, the multiple-scattering scale c and the layer albedo A):
    f(wo, wi) = (1 - m) (1 - A(mu_o)) b / pi                                   (diffuse)
              + D(h) G2(wo, wi) / (4 (n.wo) (n.wi))
                x [(1 - m) c_d(mu_o) F(wo.h, eta) + m c_m(mu_o) F_s(wo.h)]     (specular, metal)
    eta   the IOR whose normal reflectance is F0_d = ((ior - 1) / (ior + 1))^2 2 s (Principled's
          IOR and Specular IOR Level s; 0.04 at the defaults 1.5 and 0.5; shader_nodes.py):
          Cycles' generalized Schlick with the real Fresnel curve, which is F(c, eta) itself
    F_s   Schlick's F0 + (1 - F0)(1 - c)^5 with F0 = b: Cycles' F82-tint metal at a white tint
    c_d, c_m  1 + F_ms (1 - E) / E of each lobe's mean reflectance (multiple scattering within
          the lobe, Multiscatter GGX, `multiple` = 1; 1 for plain GGX, `multiple` = 0)
    A     what the specular layer reflects in all from wo (the diffuse gets the rest, as Cycles
          layers its Principled lobes; without it the engine's direct light from lamps was
          11.5 % above Cycles' on the demo scene, with it 3.5 %)
Sampling (one-sample mixture): with probability P_s = 0.2 + 0.8 m (0 where there is no
glossy lobe, m = 0 and F0_d = 0: a Diffuse BSDF, whose paths would otherwise spend a fifth of
their bounces on a lobe of zero) sample h from D(h)(n.h)
(tan^2 theta_h = alpha^2 u / (1 - u)), wi = reflect(-wo, h), p_s(wi) = D (n.h) / (4 wo.h);
else a cosine-weighted wi, p_d(wi) = (n.wi) / pi. The throughput of the bounce is
    f(wo, wi) (n.wi) / (P_s p_s(wi) + (1 - P_s) p_d(wi)),
unbiased for the whole f whichever lobe produced wi. All functions take (N, 3) arrays; f0 is
F0_d per row (None: 0.04), `multiple` per row (None: 1). Transmission is dielectric.py's lobe.
Not modelled: coat, sheen, subsurface, anisotropy, the specular tint, Oren-Nayar diffuse
roughness.
"""

from __future__ import annotations

import numpy as np

from . import microfacet as mf
from .microfacet import ALPHA_MIN, ggx_d  # noqa: F401  (the lobe's terms, for its callers)
from .vec import dot, norm

F0_DIELECTRIC = 0.04


def basis(n: np.ndarray):
    """Orthonormal tangents (t, b) for unit normals n (Duff et al. 2017, branchless)."""
    s = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    bb = n[:, 0] * n[:, 1] * a
    t = np.stack([1.0 + s * n[:, 0] ** 2 * a, s * bb, -s * n[:, 0]], axis=1)
    b = np.stack([bb, s + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t, b


def _alpha(roughness):
    return mf.alpha(roughness)


def _f0(f0, n):
    return np.full(n, F0_DIELECTRIC) if f0 is None else np.asarray(f0, dtype=np.float64)


def _multiple(multiple, n):
    return np.ones(n) if multiple is None else np.asarray(multiple, dtype=np.float64)


def evaluate(base, metallic, roughness, n, wo, wi, f0=None, multiple=None):
    """f(wo, wi) (n.wi) for (N, 3) arrays (0 where wi or wo is below the surface), (N, 3)."""
    diffuse, glossy = evaluate_parts(base, metallic, roughness, n, wo, wi, f0, multiple)
    return diffuse + glossy


def evaluate_parts(base, metallic, roughness, n, wo, wi, f0=None, multiple=None):
    """`evaluate` split by lobe: (diffuse f (n.wi), glossy f (n.wi)), each (N, 3)."""
    k = n.shape[0]
    f0d = _f0(f0, k)
    ms = _multiple(multiple, k)
    cos_o = dot(n, wo)
    cos_i = dot(n, wi)
    ok = (cos_o > 0) & (cos_i > 0)
    m = metallic[:, None]
    mu_o = np.clip(cos_o, 0.0, 1.0)
    e, e_avg, c_d, layer = _dielectric_layer(roughness, mu_o, f0d, ms)
    diffuse = (1.0 - m) * base / np.pi * (1.0 - layer)[:, None]
    h = wo + wi
    h /= np.maximum(norm(h)[:, None], 1e-12)
    alpha = _alpha(roughness)
    cos_h = np.clip(dot(n, h), 0.0, 1.0)
    voh = np.clip(dot(wo, h), 0.0, 1.0)
    fres = (1.0 - m) * (c_d * mf.fresnel(voh, mf.eta_from_f0(f0d)))[:, None]
    if (metallic > 0).any():                  # the metal lobe (most surfaces have none)
        c_m = 1.0 + ms[:, None] * (mf.multiscatter(e[:, None], e_avg[:, None],
                                                   mf.schlick_f_avg(base)) - 1.0)
        fres = fres + m * c_m * mf.schlick(voh, base)
    single = (ggx_d(cos_h, alpha) * mf.smith_g2(cos_o, np.maximum(cos_i, 1e-8), alpha)
              / (4.0 * np.maximum(cos_o, 1e-8) * np.maximum(cos_i, 1e-8)))
    spec = single[:, None] * fres
    w = np.where(ok, np.maximum(cos_i, 0.0), 0.0)[:, None]
    return diffuse * w, spec * w


def specular_albedo(roughness, cos_o, f0=F0_DIELECTRIC, multiple=1.0):
    """A(mu_o): the share of light the dielectric specular layer (F0) reflects from the
    direction mu_o = n.wo (microfacet.layer_albedo): the diffuse layer below receives 1 - A of
    it, as Cycles' Principled BSDF layers its lobes (energy conserving: the diffuse does not
    add to what the specular layer reflects)."""
    return _dielectric_layer(roughness, np.clip(cos_o, 0.0, 1.0), f0, multiple)[3]


def _dielectric_layer(roughness, mu_o, f0, multiple):
    """(E, E_avg, c_d, A) at mu_o: the plain lobe's albedos, the dielectric lobe's
    multiple-scattering scale (1 where `multiple` is 0: plain GGX) and the layer's albedo.
    Both lobes scale by their multiple scattering seen from the viewer, as in Cycles (the
    compensation depends on wo only)."""
    e, e_avg = mf.single_albedo(roughness, mu_o)
    c = 1.0 + multiple * (mf.multiscatter(e, e_avg, mf.dielectric_f_avg(f0)) - 1.0)
    return e, e_avg, c, mf.layer_albedo(e, mf.dielectric_albedo(roughness, mu_o, f0), c,
                                        multiple)


def spec_probability(metallic, f0=None):
    m = np.clip(metallic, 0.0, 1.0)
    p = 0.2 + 0.8 * m
    return p if f0 is None else np.where((m > 0) | (np.asarray(f0) > 0), p, 0.0)


def pdf(metallic, roughness, n, wo, wi, f0=None):
    """Density (per solid angle) of `sample` producing wi."""
    glossy, diffuse = pdf_parts(metallic, roughness, n, wo, wi, f0)
    return glossy + diffuse


def pdf_parts(metallic, roughness, n, wo, wi, f0=None):
    """`pdf` split by lobe: (P_s p_s(wi), (1 - P_s) p_d(wi)), the glossy and diffuse shares."""
    alpha = _alpha(roughness)
    cos_i = dot(n, wi)
    h = wo + wi
    h /= np.maximum(norm(h)[:, None], 1e-12)
    cos_h = np.clip(dot(n, h), 0.0, 1.0)
    voh = np.maximum(dot(wo, h), 1e-8)
    p_spec = ggx_d(cos_h, alpha) * cos_h / (4.0 * voh)
    p_diff = np.maximum(cos_i, 0.0) / np.pi
    ps = spec_probability(metallic, f0)
    return ps * p_spec, (1.0 - ps) * p_diff


def sample(base, metallic, roughness, n, wo, u1, u2, u3, f0=None, multiple=None):
    """(wi (N, 3), throughput (N, 3), ok (N,)): a direction from the mixture and its weight
    f (n.wi) / pdf; ok is False where wi fell below the surface (the path ends)."""
    wi, thr, ok, _, _ = sample_lobe(base, metallic, roughness, n, wo, u1, u2, u3, f0, multiple)
    return wi, thr, ok


def sample_lobe(base, metallic, roughness, n, wo, u1, u2, u3, f0=None, multiple=None):
    """`sample`, and also the density of wi (N,) and whether the GGX lobe produced it (N,)
    (a glossy bounce, else a diffuse one)."""
    wi, spec = sample_direction(metallic, roughness, n, wo, u1, u2, u3, f0)
    f = evaluate(base, metallic, roughness, n, wo, wi, f0, multiple)
    p = pdf(metallic, roughness, n, wo, wi, f0)
    ok = (dot(n, wi) > 0) & (p > 0)
    thr = np.where(ok[:, None], f / np.where(p > 0, p, 1.0)[:, None], 0.0)
    return wi, thr, ok, np.where(ok, p, 0.0), spec


def sample_direction(metallic, roughness, n, wo, u1, u2, u3, f0=None):
    """(wi (N, 3), glossy (N,) bool): a direction from the lobe u3 chooses (the GGX lobe
    with probability P_s, else the cosine-weighted diffuse one), not yet weighed."""
    t, b = basis(n)
    alpha = _alpha(roughness)
    spec = u3 < spec_probability(metallic, f0)
    phi = 2.0 * np.pi * u2
    # cosine-weighted hemisphere
    r = np.sqrt(u1)
    z_d = np.sqrt(np.maximum(0.0, 1.0 - u1))
    # GGX half vector
    tan2 = alpha * alpha * u1 / np.maximum(1.0 - u1, 1e-12)
    cos_h = 1.0 / np.sqrt(1.0 + tan2)
    sin_h = np.sqrt(np.maximum(0.0, 1.0 - cos_h * cos_h))
    lx = np.where(spec, sin_h, r) * np.cos(phi)
    ly = np.where(spec, sin_h, r) * np.sin(phi)
    lz = np.where(spec, cos_h, z_d)
    v = lx[:, None] * t + ly[:, None] * b + lz[:, None] * n
    h_dot = dot(wo, v)
    reflected = 2.0 * h_dot[:, None] * v - wo
    wi = np.where(spec[:, None], reflected, v)
    wi /= np.maximum(norm(wi)[:, None], 1e-12)
    return wi, spec
