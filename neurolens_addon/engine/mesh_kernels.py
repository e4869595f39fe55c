"""The location of ray hits in their polygons' triangles, compiled (numba): mesh_tables.
ObjectTable.locate's search row by row (the equations in mesh_tables' docstring), its numpy
version kept as the reference (tests/engine/test_shading_kernels.py). Differences: rounding
only, and a hit within rounding of two triangles' shared edge may be given either (the
barycentrics then agree to rounding)."""

from __future__ import annotations

import numpy as np

from ..core import jit

_njit = jit.njit(cache=True, nogil=True)


@_njit
def locate(poly, p, first, count, corners, tri, bary):
    """For each hit r on polygon poly[r] at p[r]: of the polygon's triangles (first[poly],
    count[poly] of them, corners (T, 3, 3)), the one whose smallest barycentric coordinate
    is largest, into tri (N,) and its barycentrics into bary (N, 3)."""
    for r in range(poly.shape[0]):
        q = poly[r]
        best = -np.inf
        tri[r] = 0
        bary[r, 0] = bary[r, 1] = bary[r, 2] = 0.0
        for j in range(count[q]):
            t = first[q] + j
            ax, ay, az = corners[t, 0, 0], corners[t, 0, 1], corners[t, 0, 2]
            v0x, v0y, v0z = corners[t, 1, 0] - ax, corners[t, 1, 1] - ay, corners[t, 1, 2] - az
            v1x, v1y, v1z = corners[t, 2, 0] - ax, corners[t, 2, 1] - ay, corners[t, 2, 2] - az
            v2x, v2y, v2z = p[r, 0] - ax, p[r, 1] - ay, p[r, 2] - az
            d00 = v0x * v0x + v0y * v0y + v0z * v0z
            d01 = v0x * v1x + v0y * v1y + v0z * v1z
            d11 = v1x * v1x + v1y * v1y + v1z * v1z
            d20 = v2x * v0x + v2y * v0y + v2z * v0z
            d21 = v2x * v1x + v2y * v1y + v2z * v1z
            den = d00 * d11 - d01 * d01
            if not abs(den) > 1e-30:
                den = 1e-30
            v = (d11 * d20 - d01 * d21) / den
            w = (d00 * d21 - d01 * d20) / den
            u = 1.0 - v - w
            score = min(u, v, w)
            if score > best:
                best = score
                tri[r] = t
                bary[r, 0], bary[r, 1], bary[r, 2] = u, v, w


def run_locate(poly, p, first, count, corners):
    k = poly.shape[0]
    tri, bary = np.empty(k, np.int64), np.empty((k, 3))
    locate(np.ascontiguousarray(poly, dtype=np.int64), np.ascontiguousarray(p, np.float64),
           np.ascontiguousarray(first, np.int64), np.ascontiguousarray(count, np.int64),
           np.ascontiguousarray(corners, np.float64), tri, bary)
    return tri, bary
