"""The shape of a rendered light: its spread about its centroid (the anamorphic bokeh tests
and the lens_effects benchmark)."""

from __future__ import annotations

import math

import numpy as np


def spread_px(img: np.ndarray) -> tuple[float, float]:
    """(sigma x, sigma y) in pixels of a luminance image's light about its centroid."""
    ii, jj = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    w = img / img.sum()
    cy, cx = (w * ii).sum(), (w * jj).sum()
    return math.sqrt((w * (jj - cx) ** 2).sum()), math.sqrt((w * (ii - cy) ** 2).sum())
