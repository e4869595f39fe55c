"""Aperture mask images written for tests and benchmarks."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_disc_png(path: Path, side: int) -> None:
    """An RGBA PNG of side^2 pixels: an opaque white disc of radius 0.45 side on black, 8-bit
    (Pillow), without a float copy of the image."""
    from PIL import Image
    y, x = np.ogrid[:side, :side]
    c = (side - 1) / 2.0
    disc = ((x - c) ** 2 + (y - c) ** 2 <= (0.45 * side) ** 2).astype(np.uint8) * 255
    rgba = np.empty((side, side, 4), np.uint8)
    rgba[..., :3] = disc[..., None]
    rgba[..., 3] = 255
    Image.fromarray(rgba, "RGBA").save(path)
