"""Compiled twin of core.coatings.stack_reflectance: a thin-film stack's unpolarised
reflectance per element, the same characteristic-matrix product (core.coatings' module
docstring) in complex arithmetic per ray rather than over whole arrays (the light tracer and
the ghost samples weigh every surface of every ray by it)."""

from __future__ import annotations

import math

import numpy as np

from . import jit

prange = jit.prange_or_range()


@jit.njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def stack_kernel(n0, ns, cos_i, lam, index, thickness, out):
    """out[i] = R of the stack (index[k], thickness[k] nm, from the n0 side) on the interface
    n0[i] -> ns[i] at cos_i[i] and lam[i] (1-D float64 arrays of one length): 1 past the
    critical angle or where the product is not finite."""
    layers = index.shape[0]
    for i in prange(out.shape[0]):
        c = min(abs(cos_i[i]), 1.0)
        sin2 = max(1.0 - c * c, 0.0)
        r0 = n0[i] / ns[i]
        st2 = r0 * r0 * sin2
        if st2 > 1.0:
            out[i] = 1.0
            continue
        cos_s = math.sqrt(max(1.0 - st2, 0.0))
        total = 0.0
        for pol in range(2):
            # a zero admittance (grazing, p) makes numpy's product inf or nan: R = 1 there;
            # numba raises on a complex division by zero, so it is caught before
            if pol == 1 and (cos_s == 0.0 or c == 0.0):
                total = math.nan
                break
            eta_s = ns[i] * cos_s if pol == 0 else ns[i] / cos_s
            b = 1.0 + 0.0j
            cc = eta_s + 0.0j
            for k in range(layers - 1, -1, -1):
                n1 = index[k]
                q = n0[i] / n1
                cos1 = math.sqrt(max(1.0 - q * q * sin2, 0.0))
                e1 = n1 * cos1 if pol == 0 else (n1 / cos1 if cos1 > 0.0 else 0.0)
                if e1 == 0.0:
                    total = math.nan
                    break
                delta = 2.0 * math.pi * n1 * thickness[k] * cos1 / lam[i]
                cd, sd = math.cos(delta), math.sin(delta)
                b, cc = cd * b + 1j * sd * cc / e1, 1j * e1 * sd * b + cd * cc
            if not math.isfinite(total):
                break
            e0 = n0[i] * c if pol == 0 else n0[i] / c
            den = e0 * b + cc
            if den == 0.0:
                total = math.nan
                break
            r = (e0 * b - cc) / den
            total += 0.5 * (r.real * r.real + r.imag * r.imag)
        out[i] = 1.0 if not math.isfinite(total) else min(max(total, 0.0), 1.0)


def stack_reflectance(n0, ns, cos_i, wavelength_nm, layers) -> np.ndarray:
    """core.coatings.stack_reflectance through stack_kernel (arrays broadcast)."""
    given = [np.asarray(v, dtype=np.float64) for v in (n0, ns, cos_i, wavelength_nm)]
    shape = np.broadcast_shapes(*(a.shape for a in given))
    # contiguous arrays of their own of the full shape (numba's; a view may be read-only),
    # copied only where not already
    flat = [(a if a.shape == shape and a.flags.c_contiguous and a.flags.owndata
             else np.array(np.broadcast_to(a, shape))).ravel() for a in given]
    out = np.empty(flat[0].shape[0])
    table = np.array([[float(n), float(d)] for n, d in layers], dtype=np.float64).reshape(-1, 2)
    with jit.KERNEL_LOCK:
        stack_kernel(*flat, np.ascontiguousarray(table[:, 0]),
                     np.ascontiguousarray(table[:, 1]), out)
    return out.reshape(shape)
