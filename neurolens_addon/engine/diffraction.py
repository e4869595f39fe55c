"""The frame's diffraction: the Combined pass convolved with the set-up's kernel.

core.diffraction gives, per channel, the stop's Fraunhofer pattern on the film's pixel grid
(LensSetup.diffraction_kernel); the finished frame's Combined colour (after denoising, so the
starbursts come out as smooth as the optics make them) is convolved with it, alpha and every
other pass kept. The noisy colour, when kept, stays as rendered.
"""

from __future__ import annotations

import numpy as np


def diffracted_frame(film, kernel, passes: dict | None = None) -> dict:
    """The frame's passes (the film's readout, or `passes` from the denoiser) with Combined
    convolved with `kernel` (core.diffraction.DiffractionKernel)."""
    from ..core.diffraction import convolve
    from .plan import Tile
    if passes is None:
        passes = film.readout(Tile(0, 0, film.width, film.height))
    h, w = film.height, film.width
    comb = passes["Combined"]
    out = comb.copy()
    rgb = convolve(comb[:, :3].reshape(h, w, 3), kernel)
    out[:, :3] = rgb.reshape(-1, 3).astype(comb.dtype)
    return dict(passes, Combined=out)
