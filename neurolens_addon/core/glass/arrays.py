"""Evaluating index laws on wavelength arrays: shapes, `out=` arrays, scratch buffers, and NaN
for wavelengths that are not finite and positive.

Every medium's `index(wavelength_nm, out=None)` takes any shape (a scalar gives a 0-d result)
and returns float64 of that shape; `out`, if given, receives it. A wavelength that is not finite
or not positive gives NaN (never an exception): the ray tracer passes whole arrays, bad entries
included, and flags those rays.
"""

from __future__ import annotations

import math
import threading

import numpy as np


def as_wavelengths(wavelength_nm) -> np.ndarray:
    """float64 view of the wavelengths, at least 1-D (ufuncs with out= need real arrays)."""
    w = np.asarray(wavelength_nm, dtype=np.float64)
    return w.reshape(1) if w.ndim == 0 else w


#: Scratch arrays up to this many elements are kept per thread and reused between calls (a fresh
#: multi-megabyte temporary costs more in page faults than the arithmetic done in it).
_SCRATCH_MAX = 1 << 22
_tls = threading.local()


def scratch(shape: tuple[int, ...], k: int) -> list[np.ndarray]:
    """k float64 work arrays of `shape`, reused per thread (fresh ones for huge inputs)."""
    size = math.prod(shape)
    if size > _SCRATCH_MAX:
        return [np.empty(shape) for _ in range(k)]
    bufs = getattr(_tls, "bufs", None)
    if bufs is None or len(bufs) < k or bufs[0].size < size:
        cap = max(size, 1024, 0 if bufs is None else bufs[0].size)
        bufs = [np.empty(cap) for _ in range(max(k, 0 if bufs is None else len(bufs)))]
        _tls.bufs = bufs
    return [b[:size].reshape(shape) for b in bufs[:k]]


def output(out: np.ndarray | None, w: np.ndarray) -> np.ndarray:
    """The caller's `out` array (checked), or a fresh float64 array shaped like `w`."""
    if out is None:
        return np.empty(w.shape)
    if not isinstance(out, np.ndarray) or out.dtype != np.float64 or (
            out.shape != w.shape and not (out.ndim == 0 and w.shape == (1,))):
        raise ValueError(f"out must be a float64 array of shape {w.shape}, got "
                         f"{getattr(out, 'dtype', type(out).__name__)} "
                         f"{getattr(out, 'shape', '')}")
    if np.may_share_memory(out, w):
        raise ValueError("out must not share memory with the wavelength array")
    return out.reshape(w.shape)


def shaped(n: np.ndarray, wavelength_nm) -> np.ndarray:
    """Give a scalar input its 0-d result back."""
    return n.reshape(()) if np.ndim(wavelength_nm) == 0 else n


def nan_bad(n: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Set NaN where the wavelength is not finite or not positive (in place; returns n)."""
    if w.size == 0:
        return n
    lo, hi = w.min(), w.max()          # reductions: no temporaries; NaN propagates into both
    if lo > 0.0 and hi < math.inf:     # the usual case: all valid
        return n
    bad = ~(w > 0.0)                   # NaN, -inf, 0 and negatives
    bad |= np.isinf(w)
    n[bad] = np.nan
    return n
