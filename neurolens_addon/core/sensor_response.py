"""Non-negative RGB channel responses: how one wavelength per camera ray becomes colour.

A dispersive lens bends each wavelength its own way, so a camera ray carries one wavelength and
its colour comes from averaging rays. The linear Rec.709 colour-matching functions
k_c rgb_bar_c (core.spectrum) are negative over parts of the spectrum (spectral colours lie
outside the Rec.709 gamut), and a ray weighted by them can make a pixel negative. We weight by
non-negative *channel responses* s_c instead, built so that colour and lateral colour stay as
the colour-matching functions give them:

Construction (c = R, G, B; knots lambda_j on the CIE 5 nm grid within [lo, hi], plus lo and hi;
s_c linear between knots)
    clipped  q_c(lambda_j) = max(k_c rgb_bar_c(lambda_j), 0)
    tilted   s_c(lambda_j) = q_c(lambda_j) exp(t_c (lambda_j - 580 nm) / 100 nm) / Z_c
    Z_c makes integral_lo^hi s_c = 1, so a flat spectrum gives RGB (1, 1, 1): white stays white.
    t_c is the exponential tilt (found by bisection; the mean of a tilted density grows with t)
    that gives s_c the first moment of the signed curve,
        integral lambda s_c = integral lambda k_c rgb_bar_c / integral k_c rgb_bar_c,
    because a lens's lateral colour is, to first order, linear in wavelength: channel c's image
    of a point lands at the image height of its mean wavelength. Clipping alone would pull red
    from 635 to 602 nm and blue from 437 to 452 nm and weaken lateral colour by about a quarter.
    All integrals are exact for piecewise-linear functions.

Two ways to draw wavelengths (u uniform in [0, 1))
    per channel  lambda ~ s_c (exact inverse CDF of the piecewise-linear density); the ray counts
                 towards channel c only, with weight exactly 1: three rays (R, G, B) sharing
                 every other random number make one sample whose colour weights sum to
                 (1, 1, 1) exactly (the engine).
    sensor       lambda ~ p = (s_R + s_G + s_B) / 3; weight w = s(lambda) / p(lambda)
                 = 3 s(lambda) / sum_c s_c(lambda): non-negative, w_R + w_G + w_B = 3 for every
                 ray, E[w] = (1, 1, 1) (the Cycles camera, one ray per sample).
    Inverse CDF on a segment [x0, x0 + h] with end values a, b and mass r below the target:
        a t + (b - a) t^2 / (2 h) = r   =>   t = 2 r / (a + sqrt(a^2 + 2 (b - a) r / h)),
    a form that stays exact when a = 0 or a = b.

Pure numpy, float64, vectorised; never NaN (u is clamped into [0, 1), NaN u reads as 0).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .spectrum import (
    CIE_MIN_NM,
    DEFAULT_HI_NM,
    DEFAULT_LO_NM,
    check_wavelength_range,
    cie_table,
    cmf_rgb,
    rgb_normalisation,
)

#: centre and scale of the exponential tilt (nm): any values give the same responses
TILT_CENTRE_NM = 580.0
TILT_SCALE_NM = 100.0
CHANNELS = ("R", "G", "B")


def _integral(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Exact integral of the piecewise-linear y(x) (y: (M,) or (M, C))."""
    h = np.diff(x).reshape((-1,) + (1,) * (y.ndim - 1))
    return np.sum(0.5 * h * (y[1:] + y[:-1]), axis=0)


def _first_moment(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Exact integral of x y(x) for piecewise-linear y."""
    shape = (-1,) + (1,) * (y.ndim - 1)
    x0, x1 = x[:-1].reshape(shape), x[1:].reshape(shape)
    return np.sum((x1 - x0) * (y[:-1] * (2 * x0 + x1) + y[1:] * (x0 + 2 * x1)) / 6.0, axis=0)


def _cdf(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cumulative integral of the piecewise-linear density y at the knots, normalised to 1."""
    c = np.concatenate([[0.0], np.cumsum(0.5 * np.diff(x) * (y[1:] + y[:-1]))])
    return c / c[-1]


def cdf_scale(knots: np.ndarray, density: np.ndarray, cdf: np.ndarray):
    """cdf units per density-integral unit of a piecewise-linear density (density and cdf
    (M,) or (M, C) columns: one scale per column)."""
    return cdf[-1] / _integral(knots, density)


def sample_linear_density(u, knots: np.ndarray, density: np.ndarray,
                          cdf: np.ndarray) -> np.ndarray:
    """Inverse CDF of a piecewise-linear density (values `density` at `knots`, normalised `cdf`)."""
    u = np.clip(np.nan_to_num(np.asarray(u, dtype=np.float64), nan=0.0),
                0.0, np.nextafter(1.0, 0.0))
    j = np.clip(np.searchsorted(cdf, u, side="right") - 1, 0, len(knots) - 2)
    h = knots[j + 1] - knots[j]
    scale = cdf_scale(knots, density, cdf)
    a, b = density[j] * scale, density[j + 1] * scale
    r = u - cdf[j]
    root = np.sqrt(np.maximum(a * a + 2.0 * (b - a) * r / h, 0.0))
    den = a + root
    t = np.where(den > 0, 2.0 * r / np.where(den > 0, den, 1.0), 0.0)
    return knots[j] + np.clip(t, 0.0, h)


@dataclass(frozen=True)
class SensorResponse:
    """The three channel responses on [lo, hi] and what sampling them needs."""

    knots: np.ndarray          # (M,) nm
    values: np.ndarray         # (M, 3) s_c at the knots; integral of each column is 1
    tilts: np.ndarray          # (3,) t_c
    channel_cdfs: np.ndarray   # (M, 3) normalised cumulative integrals of s_c
    sensor_density: np.ndarray  # (M,) p = sum_c s_c / 3
    sensor_cdf: np.ndarray     # (M,)

    def at(self, wavelength_nm) -> np.ndarray:
        """s(lambda), shape (..., 3); 0 outside [lo, hi] and for non-finite input."""
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        flat = lam.reshape(-1)
        ok = np.isfinite(flat) & (flat >= self.knots[0]) & (flat <= self.knots[-1])
        safe = np.where(ok, flat, self.knots[0])
        out = np.stack([np.interp(safe, self.knots, self.values[:, c]) for c in range(3)], -1)
        out[~ok] = 0.0
        return out.reshape(lam.shape + (3,))

    def means_nm(self) -> np.ndarray:
        """First moment of each response (nm)."""
        return _first_moment(self.knots, self.values)

    def sample_channel(self, u, channel: int) -> np.ndarray:
        """Wavelengths drawn from s_channel (weight exactly 1 in that channel)."""
        return sample_linear_density(u, self.knots, self.values[:, channel],
                                     self.channel_cdfs[:, channel])

    def sample_sensor(self, u) -> tuple[np.ndarray, np.ndarray]:
        """(lambda, weight (N, 3)) drawn from p = sum_c s_c / 3, weight 3 s / sum_c s_c."""
        lam = sample_linear_density(u, self.knots, self.sensor_density, self.sensor_cdf)
        s = self.at(lam)
        total = s.sum(axis=-1, keepdims=True)
        return lam, np.where(total > 0, 3.0 * s / np.where(total > 0, total, 1.0), 1.0)


def signed_means_nm(lo: float = DEFAULT_LO_NM, hi: float = DEFAULT_HI_NM) -> np.ndarray:
    """First moments of the signed colour-matching functions k_c rgb_bar_c on [lo, hi] (nm)."""
    knots = response_knots(lo, hi)
    signed = cmf_rgb(knots) * rgb_normalisation(lo, hi)
    return _first_moment(knots, signed) / _integral(knots, signed)


def response_knots(lo: float = DEFAULT_LO_NM, hi: float = DEFAULT_HI_NM) -> np.ndarray:
    """The CIE grid points inside [lo, hi], with lo and hi."""
    lo, hi = check_wavelength_range(lo, hi)
    wl, _ = cie_table()
    return np.unique(np.concatenate([[max(lo, CIE_MIN_NM), hi], wl[(wl > lo) & (wl < hi)]]))


def _tilted(knots: np.ndarray, clipped: np.ndarray, t: float) -> np.ndarray:
    y = clipped * np.exp(t * (knots - TILT_CENTRE_NM) / TILT_SCALE_NM)
    return y / _integral(knots, y)


def _tilt_for_mean(knots: np.ndarray, clipped: np.ndarray, target: float) -> float:
    lo, hi = -40.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _first_moment(knots, _tilted(knots, clipped, mid)) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=8)
def sensor_response(lo: float = DEFAULT_LO_NM, hi: float = DEFAULT_HI_NM) -> SensorResponse:
    """The responses for the sampled range [lo, hi] (module docstring), built once."""
    knots = response_knots(lo, hi)
    clipped = np.maximum(cmf_rgb(knots) * rgb_normalisation(lo, hi), 0.0)
    targets = signed_means_nm(lo, hi)
    tilts = np.array([_tilt_for_mean(knots, clipped[:, c], targets[c]) for c in range(3)])
    values = np.stack([_tilted(knots, clipped[:, c], tilts[c]) for c in range(3)], axis=1)
    cdfs = np.stack([_cdf(knots, values[:, c]) for c in range(3)], axis=1)
    density = values.sum(axis=1) / 3.0
    arrays = (knots, values, tilts, cdfs, density, _cdf(knots, density))
    for a in arrays:
        a.setflags(write=False)
    return SensorResponse(*arrays)
