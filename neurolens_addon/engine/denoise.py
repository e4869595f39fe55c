"""Denoising the engine's frame with Intel Open Image Denoise (OIDN).

OIDN is the denoiser Blender itself ships (Cycles' "OpenImageDenoise"); the engine reaches it
through `pyoidn` (MIT, OIDN 2.x builds for Linux, Windows and macOS, a numpy interface,
released with OIDN's versions), the maintained binding of the current OIDN: the older `oidn`
package wraps OIDN 1.x and has not been released since 2021. It runs the "RT" filter in HDR
mode on the Combined colour, guided by the first hit's albedo and normal (film.py's Denoising
Albedo and Normal passes), and leaves alpha alone:
    denoised_rgb = OIDN_RT(colour, albedo, normal),  Combined = (denoised_rgb, alpha),
with the noisy Combined kept as the Noisy Image pass (as Cycles does).
Without pyoidn the frame stays noisy and the render says so once.
"""

from __future__ import annotations

import numpy as np


class DenoiserUnavailable(RuntimeError):
    """pyoidn is not installed (or OIDN cannot run here)."""


def _oidn():
    try:
        import pyoidn
    except Exception as exc:      # ImportError, or OIDN's libraries failing to load
        raise DenoiserUnavailable(f"the pyoidn package (Open Image Denoise) is not usable "
                                  f"here ({exc})") from None
    return pyoidn


def available() -> bool:
    try:
        _oidn()
    except DenoiserUnavailable:
        return False
    return True


def denoise(color: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None) -> np.ndarray:
    """The denoised (H, W, 3) float32 image of an HDR `color` (H, W, 3), optionally guided by
    `albedo` and `normal` of the same shape. Non-finite input is refused (ValueError)."""
    pyoidn = _oidn()
    c = np.ascontiguousarray(color, dtype=np.float32)
    if c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"colour must be (H, W, 3), got {c.shape}")
    if not np.isfinite(c).all():
        raise ValueError("the colour holds NaN or infinite values: not denoised")
    guides = {}
    if albedo is not None:
        guides["albedo"] = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), dtype=np.float32)
        if normal is not None:     # OIDN takes a normal only together with an albedo
            guides["normal"] = np.ascontiguousarray(np.clip(normal, -1.0, 1.0),
                                                    dtype=np.float32)
    out = pyoidn.denoise(c, hdr=True, **guides)
    return np.asarray(out, dtype=np.float32)


def denoised_frame(film, notes: list) -> dict | None:
    """The whole frame's passes with Combined denoised (Noisy Image keeps the noisy one), or
    None when the denoiser is not usable here (a note says why, once) or the colour is not
    finite."""
    from .plan import Tile
    passes = film.readout(Tile(0, 0, film.width, film.height))
    h, w = film.height, film.width
    comb = passes["Combined"]
    try:
        rgb = denoise(comb[:, :3].reshape(h, w, 3),
                      passes["Denoising Albedo"].reshape(h, w, 3),
                      passes["Denoising Normal"].reshape(h, w, 3))
    except (DenoiserUnavailable, ValueError) as exc:
        text = f"Not denoised: {exc}"
        if text not in notes:
            notes.append(text)
        return None
    out = comb.copy()
    out[:, :3] = rgb.reshape(-1, 3)
    passes["Combined"] = out
    passes["Noisy Image"] = comb
    return passes
