"""Counting the spikes of a rendered starburst (the engine's and Cycles' diffraction tests)."""

from __future__ import annotations

import numpy as np


def spike_count(img: np.ndarray, lo: float = 6.0, hi: float = 30.0) -> int:
    """Peaks of the light around the brightest pixel of a luminance image (rows top to bottom)
    over azimuth, lo to hi pixels out: 3 degree bins, mean per pixel, smoothed over three,
    standing above three times the median (peaks within 10 degrees count once)."""
    h, w = img.shape
    cy, cx = np.unravel_index(np.argmax(img), img.shape)
    ii, jj = np.mgrid[0:h, 0:w]
    r = np.hypot(ii - cy, jj - cx)
    ring = (r > lo) & (r < hi)
    ang = np.degrees(np.arctan2(-(ii - cy), jj - cx))[ring] % 360.0
    s, _ = np.histogram(ang, bins=120, range=(0, 360), weights=img[ring])
    n, _ = np.histogram(ang, bins=120, range=(0, 360))
    m = s / np.maximum(n, 1)
    ms = (np.roll(m, 1) + m + np.roll(m, -1)) / 3.0
    med = np.median(ms)
    peaks = [3 * i for i in range(120) if ms[i] >= ms[i - 1] and ms[i] > ms[(i + 1) % 120]
             and ms[i] > 3.0 * med]
    # a spike along a pixel row or column can split over neighbouring bins (few pixel centres
    # fall in them): peaks within 10 degrees are one spike
    merged = [a for k, a in enumerate(peaks) if k == 0 or a - peaks[k - 1] > 10]
    if len(merged) > 1 and merged[0] + 360 - peaks[-1] <= 10:
        merged = merged[1:]
    return len(merged)


def far_light(img: np.ndarray, beyond: float = 6.0) -> float:
    """The light more than `beyond` pixels from the brightest pixel."""
    h, w = img.shape
    cy, cx = np.unravel_index(np.argmax(img), img.shape)
    ii, jj = np.mgrid[0:h, 0:w]
    return float(img[np.hypot(ii - cy, jj - cx) > beyond].sum())
