"""The film's accumulation compiled (numba): film.Film.add's sums in one pass over a bundle's
rays, the numpy version (bincount per pass) kept as the reference
(tests/engine/test_shading_kernels.py). Bit for bit the same: each pass is summed in float64 in
the rays' order, as bincount sums, then added to the float32 sums of the tile's pixels."""

from __future__ import annotations

import numpy as np

from ..core import jit

_njit = jit.njit(cache=True, nogil=True)
#: float64 scratch columns a pixel: count, valid, illumination, hits, depth, rgb 3, normal 3,
#: albedo 3, uncertainty, its count
_COLUMNS = 16


@_njit
def add(lp, rows, share, rgb, valid, hit, depth, normal, illum, unc, albedo, f_rgb, f_count,
        f_valid, f_illum, f_hits, f_depth, f_normal, f_albedo, f_unc, f_unc_count):
    """Film.add: rays at tile pixels lp (N,) into the sums at `rows` (the tile's pixels' rows
    of the sums, (M,)); unc and albedo of length 0 when the bundle has none."""
    m = rows.shape[0]
    s = np.zeros((m, _COLUMNS))
    with_unc, with_albedo = unc.shape[0] > 0, albedo.shape[0] > 0
    for r in range(lp.shape[0]):
        p = lp[r]
        v, h = valid[r], hit[r]
        s[p, 0] += share
        s[p, 1] += (1.0 if v else 0.0) * share
        s[p, 2] += illum[r] * share
        s[p, 3] += (1.0 if h else 0.0) * share
        s[p, 4] += (depth[r] if h else 0.0) * share
        for c in range(3):
            s[p, 5 + c] += rgb[r, c]
            s[p, 8 + c] += (normal[r, c] if h else 0.0) * share
            if with_albedo:
                s[p, 11 + c] += (albedo[r, c] if h else 0.0) * share
        if with_unc:
            s[p, 14] += (unc[r] if v else 0.0) * share
            s[p, 15] += (1.0 if v else 0.0) * share
    for p in range(m):
        j = rows[p]
        f_count[j] += np.float32(s[p, 0])
        f_valid[j] += np.float32(s[p, 1])
        f_illum[j] += np.float32(s[p, 2])
        f_hits[j] += np.float32(s[p, 3])
        f_depth[j] += np.float32(s[p, 4])
        for c in range(3):
            f_rgb[j, c] += np.float32(s[p, 5 + c])
            f_normal[j, c] += np.float32(s[p, 8 + c])
            if with_albedo:
                f_albedo[j, c] += np.float32(s[p, 11 + c])
        if with_unc:
            f_unc[j] += np.float32(s[p, 14])
            f_unc_count[j] += np.float32(s[p, 15])


def run_add(sums, rows, lp, share, rgb, valid, hit, depth, normal, illumination, uncertainty,
            albedo):
    """`add` into film._Sums `sums` at `rows` (an index array of the tile's pixels)."""
    def f(a):
        return np.ascontiguousarray(a, dtype=np.float64)
    empty1, empty3 = np.zeros(0), np.zeros((0, 3))
    add(np.ascontiguousarray(lp, dtype=np.int64), np.ascontiguousarray(rows, dtype=np.int64),
        float(share), f(rgb), np.ascontiguousarray(valid, dtype=np.bool_),
        np.ascontiguousarray(hit, dtype=np.bool_), f(depth), f(normal), f(illumination),
        empty1 if uncertainty is None else f(uncertainty),
        empty3 if albedo is None else f(albedo), sums.rgb, sums.count, sums.valid,
        sums.illum, sums.hits, sums.depth, sums.normal, sums.albedo, sums.unc,
        sums.unc_count)
