"""Denoising the engine's frame with Intel Open Image Denoise (OIDN).

OIDN is the denoiser Blender itself ships (Cycles' "OpenImageDenoise"); the engine reaches it
through `pyoidn` (MIT, OIDN 2.x builds for Linux, Windows and macOS, a numpy interface,
released with OIDN's versions), the maintained binding of the current OIDN: the older `oidn`
package wraps OIDN 1.x and has not been released since 2021. It runs the "RT" filter in HDR
mode at high quality on the Combined colour, guided by the first hit's albedo and normal
(film.py's Denoising Albedo and Normal passes), and leaves alpha alone:
    denoised_rgb = OIDN_RT(colour, albedo, normal),  Combined = (denoised_rgb, alpha),
with the noisy Combined kept as the Noisy Image pass (as Cycles does).
Without pyoidn the frame stays noisy and the render says so once.

Memory. OIDN's scratch grows with the frame unless bounded: its own default took about 300
bytes a pixel (2.6 GB over the inputs at 3840 x 2160). The filter is given OIDN_MAX_MEMORY_MB
(OIDN's maxMemoryMB), above which OIDN cuts the frame into overlapping tiles itself, seamless
by design (the same pixels here: tests/engine/test_5_denoise.py). The frame's colour is read in
place from the Combined RGBA rows (a 16-byte pixel stride, no RGB copy) and the denoised colour
written into a new RGBA array the same way, so the frame costs its colour, guides and output
(16 + 12 + 12 + 16 bytes a pixel) plus OIDN's bounded scratch (engine.memory counts them).
"""

from __future__ import annotations

import threading

import numpy as np

#: OIDN's maxMemoryMB: the scratch it may use before it tiles the frame itself (512: as fast as
#: unbounded at 3840 x 2160 here, 27 s against 25 s, where 128 took 41 s)
OIDN_MAX_MEMORY_MB = 512
#: rows of pixels checked or clipped at once (bounds the temporaries of those steps)
_BLOCK = 1 << 18


class DenoiserUnavailable(RuntimeError):
    """pyoidn is not installed (or OIDN cannot run here)."""


def _oidn():
    try:
        pyoidn = _import_without_torch()
    except Exception as exc:      # ImportError, or OIDN's libraries failing to load
        raise DenoiserUnavailable(f"the pyoidn package (Open Image Denoise) is not usable "
                                  f"here ({exc})") from None
    return pyoidn


def _import_without_torch():
    """pyoidn, imported without its optional torch interop where torch is not yet loaded:
    pyoidn imports torch whenever it is installed (as in the trainer's venv), 1.9 s of a
    render's start for tensors the engine never passes it. A None in sys.modules makes that
    `import torch` fail, so pyoidn records torch as absent; the entry is removed after."""
    import sys
    if "pyoidn" in sys.modules or "torch" in sys.modules:
        import pyoidn
        return pyoidn
    sys.modules["torch"] = None
    try:
        import pyoidn
    finally:
        if sys.modules.get("torch", 0) is None:
            del sys.modules["torch"]
    return pyoidn


def available() -> bool:
    try:
        _oidn()
    except DenoiserUnavailable:
        return False
    return True


_LOCK = threading.Lock()
_DEVICE: list = []          # one committed OIDN CPU device for the process, made on first use


def _device(pyoidn):
    if not _DEVICE:
        dev = pyoidn.Device()
        dev.commit()
        _check(pyoidn, dev, "device creation")
        _DEVICE.append(dev)
    return _DEVICE[0]


def _check(pyoidn, dev, what: str) -> None:
    """OIDN reports errors on the device, not by return value: raise the one pending."""
    from pyoidn.capi import oidn_Capi, oidn_ffi
    msg = oidn_ffi.new("const char**")
    code = int(oidn_Capi.oidnGetDeviceError(dev._device, msg))
    if code != 0:
        text = oidn_ffi.string(msg[0]).decode("utf-8", "replace") if msg[0] else "no message"
        raise DenoiserUnavailable(f"Open Image Denoise failed at {what} ({text})")


def _finite(a: np.ndarray) -> bool:
    flat = a.reshape(-1, a.shape[-1])
    return all(np.isfinite(flat[i:i + _BLOCK]).all() for i in range(0, flat.shape[0], _BLOCK))


def _run(color: np.ndarray, albedo, normal, out: np.ndarray) -> None:
    """OIDN's RT filter on contiguous float32 (H, W, 3 or 4) colour into `out` (H, W, 3 or 4,
    only RGB written), guides (H, W, 3) contiguous float32 or None."""
    pyoidn = _oidn()
    with _LOCK:
        dev = _device(pyoidn)
        f = pyoidn.Filter(dev, "RT")
        try:
            f.set_image("color", color, pyoidn.OIDN_FORMAT_FLOAT3,
                        pixel_byte_stride=4 * color.shape[2])
            if albedo is not None:
                f.set_image("albedo", albedo, pyoidn.OIDN_FORMAT_FLOAT3)
                if normal is not None:     # OIDN takes a normal only together with an albedo
                    f.set_image("normal", normal, pyoidn.OIDN_FORMAT_FLOAT3)
            f.set_image("output", out, pyoidn.OIDN_FORMAT_FLOAT3,
                        pixel_byte_stride=4 * out.shape[2])
            f.set_bool("hdr", True)
            f.set_quality(pyoidn.OIDN_QUALITY_HIGH)
            f.set_int("maxMemoryMB", OIDN_MAX_MEMORY_MB)
            f.commit()
            _check(pyoidn, dev, "set-up")
            f.execute()
            _check(pyoidn, dev, "filtering")
        finally:
            f.release()


def _image(a, name: str, shape) -> np.ndarray:
    c = np.ascontiguousarray(a, dtype=np.float32)
    if c.shape != shape:
        raise ValueError(f"{name} must be {shape}, got {c.shape}")
    return c


def denoise(color: np.ndarray, albedo: np.ndarray | None = None,
            normal: np.ndarray | None = None) -> np.ndarray:
    """The denoised (H, W, 3) float32 image of an HDR `color` (H, W, 3), optionally guided by
    `albedo` and `normal` of the same shape (copies clipped to [0, 1] and [-1, 1]; the
    arguments are not changed). Non-finite input is refused (ValueError)."""
    c = np.ascontiguousarray(color, dtype=np.float32)
    if c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"colour must be (H, W, 3), got {c.shape}")
    if not _finite(c):
        raise ValueError("the colour holds NaN or infinite values: not denoised")
    a = None if albedo is None else np.clip(_image(albedo, "albedo", c.shape), 0.0, 1.0)
    n = None if normal is None else np.clip(_image(normal, "normal", c.shape), -1.0, 1.0)
    out = np.empty_like(c)
    _run(c, a, n, out)
    return out


def denoised_frame(film, notes: list) -> dict | None:
    """{"Combined": the frame's (W H, 4) Combined with its colour denoised, alpha kept}, or
    None when the denoiser is not usable here (a note says why, once) or the colour is not
    finite. The film's frame passes (film.Film.frame) are the inputs; its guides are clipped
    in place (a streamed film's stores serve nothing else)."""
    h, w = film.height, film.width
    text = None
    try:
        _oidn()
        comb = film.frame("Combined")
        if not _finite(comb[:, :3]):
            raise ValueError("the colour holds NaN or infinite values: not denoised")
        albedo = np.ascontiguousarray(film.frame("Denoising Albedo"))
        normal = np.ascontiguousarray(film.frame("Denoising Normal"))
        for i in range(0, h * w, _BLOCK):      # OIDN's ranges, without a clipped copy
            np.clip(albedo[i:i + _BLOCK], 0.0, 1.0, out=albedo[i:i + _BLOCK])
            np.clip(normal[i:i + _BLOCK], -1.0, 1.0, out=normal[i:i + _BLOCK])
        out = np.empty_like(comb)
        _run(np.ascontiguousarray(comb).reshape(h, w, 4), albedo.reshape(h, w, 3),
             normal.reshape(h, w, 3), out.reshape(h, w, 4))
        out[:, 3] = comb[:, 3]
    except (DenoiserUnavailable, ValueError) as exc:
        text = f"Not denoised: {exc}"
    if text is not None:
        if text not in notes:
            notes.append(text)
        return None
    return {"Combined": out}
