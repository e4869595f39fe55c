"""Glass: a rough dielectric interface that reflects or refracts (Walter et al. 2007,
"Microfacet Models for Refraction through Rough Surfaces").

With n the normal on the side of the outgoing direction wo, eta = n_t / n_i the ratio of the
refractive indices across the surface in the direction of travel (ior entering, 1 / ior
leaving) and alpha = max(roughness^2, ALPHA_MIN):
  1. a microfacet normal m from D(m) (n.m) (GGX, tan^2 theta_m = alpha^2 u / (1 - u));
  2. the exact unpolarised Fresnel reflectance of the interface m,
         c = wo.m,  g^2 = eta^2 - 1 + c^2   (g^2 < 0: total internal reflection, F = 1)
         F = 1/2 ((g - c) / (g + c))^2 (1 + ((c (g + c) - 1) / (c (g - c) + 1))^2);
  3. reflection wi = 2 c m - wo with probability F, else refraction
         wi = (c / eta - sqrt(1 - (1 - c^2) / eta^2)) m - wo / eta;
  4. the weight of either, f |n.wi| / p = |wo.m| G(wo, wi) / (|wo.n| |m.n|)  (Walter eq. 41),
     G = G1(wo) G1(wi) (Smith, bsdf.smith_g1).
At alpha = ALPHA_MIN (roughness below 0.032) this is smooth glass, m = n and weight 1. The lobe is only
sampled, never evaluated for light samples: paths through glass see lights by meeting them.
"""

from __future__ import annotations

import numpy as np

from .bsdf import ALPHA_MIN, _alpha, basis, smith_g1
from .vec import dot, norm


def fresnel(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Unpolarised reflectance of a dielectric interface for |cos| of the incident angle and
    eta = n_t / n_i (1 under total internal reflection)."""
    c = np.abs(cos_i)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - c) / np.maximum(g + c, 1e-12)
    b = (c * (g + c) - 1.0) / np.where(np.abs(c * (g - c) + 1.0) > 1e-12,
                                      c * (g - c) + 1.0, 1e-12)
    return np.where(g2 > 0.0, np.clip(0.5 * a * a * (1.0 + b * b), 0.0, 1.0), 1.0)


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
    g = np.where(alpha <= ALPHA_MIN, 1.0,
                 smith_g1(cos_o, alpha) * smith_g1(np.abs(cos_i), alpha))
    weight = np.abs(c) * g / np.maximum(np.abs(cos_o) * cos_m, 1e-12)
    ok = (c > 0) & np.where(refract, cos_i < 0, cos_i > 0)
    return wi, np.where(ok, weight, 0.0), refract, ok
