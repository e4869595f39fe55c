"""The surface model: a Principled-like mix of Lambert diffuse and a GGX microfacet lobe.

With base colour b, metallic m, roughness r (alpha = max(r^2, ALPHA_MIN)), unit normal n facing
the outgoing direction wo, incoming direction wi and half vector h = (wo + wi) / |wo + wi|:
    f(wo, wi) = (1 - m) (1 - E(n.wo)) b / pi  +  D(h) G(wo, wi) F(wo.h) / (4 (n.wo) (n.wi))
    D(h)  = alpha^2 / (pi ((n.h)^2 (alpha^2 - 1) + 1)^2)                 (GGX / Trowbridge-Reitz)
    G     = G1(wo) G1(wi),  G1(w) = 2 (n.w) / ((n.w) + sqrt(alpha^2 + (1 - alpha^2)(n.w)^2))
    F(c)  = F0 + (1 - F0)(1 - c)^5,   F0 = (1 - m) F0_d + m b            (Schlick)
    F0_d  = ((ior - 1) / (ior + 1))^2 2 s, the dielectric reflectance of Principled's IOR and
          Specular IOR Level s (0.04 at the defaults 1.5 and 0.5; shader_nodes.py)
    E(mu) the directional albedo of the dielectric specular layer (specular_albedo): the
          diffuse layer gets what the specular one does not reflect, as in Cycles' Principled
          BSDF (without it the engine's direct light from lamps was 11.5 % above Cycles' on the
          demo scene, with it 3.5 %)
Sampling (one-sample mixture): with probability P_s = 0.2 + 0.8 m sample h from D(h)(n.h)
(tan^2 theta_h = alpha^2 u / (1 - u)), wi = reflect(-wo, h), p_s(wi) = D (n.h) / (4 wo.h);
else a cosine-weighted wi, p_d(wi) = (n.wi) / pi. The throughput of the bounce is
    f(wo, wi) (n.wi) / (P_s p_s(wi) + (1 - P_s) p_d(wi)),
unbiased for the whole f whichever lobe produced wi. All functions take (N, 3) arrays; f0 is
F0_d per row (None: 0.04). Transmission is dielectric.py's lobe. Not modelled: coat, sheen,
subsurface, anisotropy, the specular tint, multiple scattering within the GGX lobe.
"""

from __future__ import annotations

import numpy as np

from .vec import dot, norm

ALPHA_MIN = 1e-3
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
    return np.maximum(np.asarray(roughness, dtype=np.float64) ** 2, ALPHA_MIN)


def ggx_d(cos_h, alpha):
    a2 = alpha * alpha
    t = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (np.pi * t * t)


def smith_g1(cos_w, alpha):
    a2 = alpha * alpha
    c = np.maximum(cos_w, 1e-8)
    return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))


def _f0(f0, n):
    return np.full(n, F0_DIELECTRIC) if f0 is None else np.asarray(f0, dtype=np.float64)


def evaluate(base, metallic, roughness, n, wo, wi, f0=None):
    """f(wo, wi) (n.wi) for (N, 3) arrays (0 where wi or wo is below the surface), (N, 3)."""
    diffuse, glossy = evaluate_parts(base, metallic, roughness, n, wo, wi, f0)
    return diffuse + glossy


def evaluate_parts(base, metallic, roughness, n, wo, wi, f0=None):
    """`evaluate` split by lobe: (diffuse f (n.wi), glossy f (n.wi)), each (N, 3)."""
    f0d = _f0(f0, n.shape[0])
    cos_o = dot(n, wo)
    cos_i = dot(n, wi)
    ok = (cos_o > 0) & (cos_i > 0)
    m = metallic[:, None]
    diffuse = (1.0 - m) * base / np.pi * (1.0 - specular_albedo(roughness, cos_o, f0d))[:, None]
    h = wo + wi
    h /= np.maximum(norm(h)[:, None], 1e-12)
    alpha = _alpha(roughness)
    cos_h = np.clip(dot(n, h), 0.0, 1.0)
    voh = np.clip(dot(wo, h), 0.0, 1.0)
    f0c = (1.0 - m) * f0d[:, None] + m * base
    fres = f0c + (1.0 - f0c) * ((1.0 - voh) ** 5)[:, None]
    spec = (ggx_d(cos_h, alpha) * smith_g1(cos_o, alpha) * smith_g1(cos_i, alpha)
            / (4.0 * np.maximum(cos_o, 1e-8) * np.maximum(cos_i, 1e-8)))[:, None] * fres
    w = np.where(ok, np.maximum(cos_i, 0.0), 0.0)[:, None]
    return diffuse * w, spec * w


def specular_albedo(roughness, cos_o, f0=F0_DIELECTRIC):
    """E(mu_o): the share of light the dielectric specular layer (F0) reflects from the
    direction mu_o = n.wo, Karis' fit of the split-sum integral ("Physically Based Shading on
    Mobile", 2014): the diffuse layer below receives 1 - E of it, as Cycles' Principled BSDF
    layers its lobes (energy conserving: the diffuse does not add to what the coat reflects)."""
    r = np.asarray(roughness, dtype=np.float64)
    mu = np.clip(cos_o, 0.0, 1.0)
    rx, ry = -r + 1.0, -0.0275 * r + 0.0425
    rz, rw = -0.572 * r + 1.04, 0.022 * r - 0.04
    a004 = np.minimum(rx * rx, np.exp2(-9.28 * mu)) * rx + ry
    a, b = -1.04 * a004 + rz, 1.04 * a004 + rw
    return np.clip(f0 * a + b, 0.0, 1.0)


def spec_probability(metallic):
    return 0.2 + 0.8 * np.clip(metallic, 0.0, 1.0)


def pdf(metallic, roughness, n, wo, wi):
    """Density (per solid angle) of `sample` producing wi."""
    glossy, diffuse = pdf_parts(metallic, roughness, n, wo, wi)
    return glossy + diffuse


def pdf_parts(metallic, roughness, n, wo, wi):
    """`pdf` split by lobe: (P_s p_s(wi), (1 - P_s) p_d(wi)), the glossy and diffuse shares."""
    alpha = _alpha(roughness)
    cos_i = dot(n, wi)
    h = wo + wi
    h /= np.maximum(norm(h)[:, None], 1e-12)
    cos_h = np.clip(dot(n, h), 0.0, 1.0)
    voh = np.maximum(dot(wo, h), 1e-8)
    p_spec = ggx_d(cos_h, alpha) * cos_h / (4.0 * voh)
    p_diff = np.maximum(cos_i, 0.0) / np.pi
    ps = spec_probability(metallic)
    return ps * p_spec, (1.0 - ps) * p_diff


def sample(base, metallic, roughness, n, wo, u1, u2, u3, f0=None):
    """(wi (N, 3), throughput (N, 3), ok (N,)): a direction from the mixture and its weight
    f (n.wi) / pdf; ok is False where wi fell below the surface (the path ends)."""
    wi, thr, ok, _, _ = sample_lobe(base, metallic, roughness, n, wo, u1, u2, u3, f0)
    return wi, thr, ok


def sample_lobe(base, metallic, roughness, n, wo, u1, u2, u3, f0=None):
    """`sample`, and also the density of wi (N,) and whether the GGX lobe produced it (N,)
    (a glossy bounce, else a diffuse one)."""
    wi, spec = sample_direction(metallic, roughness, n, wo, u1, u2, u3)
    f = evaluate(base, metallic, roughness, n, wo, wi, f0)
    p = pdf(metallic, roughness, n, wo, wi)
    ok = (dot(n, wi) > 0) & (p > 0)
    thr = np.where(ok[:, None], f / np.where(p > 0, p, 1.0)[:, None], 0.0)
    return wi, thr, ok, np.where(ok, p, 0.0), spec


def sample_direction(metallic, roughness, n, wo, u1, u2, u3):
    """(wi (N, 3), glossy (N,) bool): a direction from the lobe u3 chooses (the GGX lobe
    with probability P_s, else the cosine-weighted diffuse one), not yet weighed."""
    t, b = basis(n)
    alpha = _alpha(roughness)
    spec = u3 < spec_probability(metallic)
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
