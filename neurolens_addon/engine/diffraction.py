"""The frame's diffraction: the Combined pass convolved with the set-up's kernel.

core.diffraction gives, per channel, the stop's Fraunhofer pattern on the film's pixel grid
(LensSetup.diffraction_kernel); the finished frame's Combined colour (after denoising, so the
starbursts come out as smooth as the optics make them) is convolved with it, alpha and every
other pass kept. The noisy colour, when kept, stays as rendered. The convolution runs a strip
of rows at a time (core.diffraction.convolve), so beyond the Combined pass itself its work
arrays do not grow with the frame.
"""

from __future__ import annotations

import numpy as np


def diffracted_frame(film, kernel, passes: dict | None = None) -> dict:
    """{"Combined": the frame's (W H, 4) Combined (the film's, or `passes`' from the
    denoiser) with its colour convolved with `kernel` (core.diffraction.DiffractionKernel)}.
    The denoiser's array is convolved in place (nothing else reads it); the film's is not."""
    from ..core.diffraction import convolve
    h, w = film.height, film.width
    if passes is not None:
        comb = passes["Combined"]
        out = comb
    else:
        comb = film.frame("Combined")
        out = np.empty_like(comb)
        out[:, 3] = comb[:, 3]
    convolve(comb.reshape(h, w, 4), kernel, out=out.reshape(h, w, 4))
    return {"Combined": out}
