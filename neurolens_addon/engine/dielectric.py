"""Glass: a rough dielectric interface that reflects or refracts (Walter et al. 2007,
"Microfacet Models for Refraction through Rough Surfaces").

With n the normal on the side of the outgoing direction wo, eta = n_t / n_i the ratio of the
refractive indices across the surface in the direction of travel (ior entering, 1 / ior
leaving) and alpha = max(roughness^2, ALPHA_MIN):
  1. a microfacet normal m from D(m) (n.m) (GGX, tan^2 theta_m = alpha^2 u / (1 - u));
  2. the exact unpolarised Fresnel reflectance F(c, eta) of the interface m, c = wo.m
     (microfacet.fresnel; total internal reflection: F = 1);
  3. reflection wi = 2 c m - wo with probability F, else refraction
         wi = (c / eta - sqrt(1 - (1 - c^2) / eta^2)) m - wo / eta;
  4. the weight of either, f |n.wi| / p = |wo.m| G2(wo, wi) / (|wo.n| |m.n|)  (Walter eq. 41),
     G2 = 1 / (1 + Lambda(wo) + Lambda(wi)), Smith's height-correlated masking-shadowing
     (microfacet.smith_g2, of |n.w|), as Cycles' glass.
At alpha = ALPHA_MIN (roughness below 0.032) this is smooth glass, m = n and weight 1. The lobe
is only sampled, never evaluated for light samples: paths through glass see lights by meeting
them. Not modelled: Cycles' multiple-scattering compensation of rough glass.
"""

from __future__ import annotations

import numpy as np

from .bsdf import basis
from .microfacet import ALPHA_MIN, alpha as _alpha, fresnel, smith_g2
from .vec import dot, norm

__all__ = ["fresnel", "sample"]


def sample(n, wo, eta, roughness, u1, u2, u3):
    """(wi (N, 3), weight (N,), refracted (N,) bool, ok (N,) bool) of one bounce off glass."""
    alpha = _alpha(roughness)
    t, b = basis(n)
    # the smoothest glass is exactly smooth: GGX's long tail would scatter a few rays widely
    tan2 = np.where(alpha <= ALPHA_MIN, 0.0, alpha * alpha * u1 / np.maximum(1.0 - u1, 1e-12))
    cos_m = 1.0 / np.sqrt(1.0 + tan2)
    sin_m = np.sqrt(np.maximum(0.0, 1.0 - cos_m * cos_m))
    phi = 2.0 * np.pi * u2
    m = ((sin_m * np.cos(phi))[:, None] * t + (sin_m * np.sin(phi))[:, None] * b
         + cos_m[:, None] * n)
    c = dot(wo, m)
    f = fresnel(c, eta)
    refract = u3 >= f
    inv = 1.0 / eta
    k = np.maximum(1.0 - (1.0 - c * c) * inv * inv, 0.0)
    wt = (c * inv - np.sqrt(k))[:, None] * m - inv[:, None] * wo
    wr = 2.0 * c[:, None] * m - wo
    wi = np.where(refract[:, None], wt, wr)
    wi /= np.maximum(norm(wi)[:, None], 1e-12)
    cos_o, cos_i = dot(n, wo), dot(n, wi)
    g = np.where(alpha <= ALPHA_MIN, 1.0, smith_g2(np.abs(cos_o), np.abs(cos_i), alpha))
    weight = np.abs(c) * g / np.maximum(np.abs(cos_o) * cos_m, 1e-12)
    ok = (c > 0) & np.where(refract, cos_i < 0, cos_i > 0)
    return wi, np.where(ok, weight, 0.0), refract, ok
