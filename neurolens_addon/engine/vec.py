"""Row-wise operations on (N, 3) arrays of vectors, used throughout the shading code.

numpy's reductions along a 3-wide last axis (np.linalg.norm(v, axis=1), np.abs(v).max(axis=1))
are several times slower than these, which are on the engine's hot path.
"""

from __future__ import annotations

import numpy as np


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products."""
    return np.einsum("ij,ij->i", a, b)


def norm(v: np.ndarray) -> np.ndarray:
    """Row lengths."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def absmax3(v: np.ndarray) -> np.ndarray:
    """max(|v_0|, |v_1|, |v_2|) per row."""
    a = np.abs(v)
    return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])
