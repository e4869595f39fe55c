"""Compiled twin of core.coatings.stack_reflectance: a thin-film stack's unpolarised
reflectance per element, the same characteristic-matrix product (core.coatings' module
docstring) in complex arithmetic per ray rather than over whole arrays (the light tracer and
the ghost samples weigh every surface of every ray by it); and a ghost path's whole coating
weight per ray (path_weight_kernel, called by core.coatings.Coating.path_weight), every step
of a ray in one loop."""

from __future__ import annotations

import math

import numpy as np

from . import jit

prange = jit.prange_or_range()


@jit.njit(nogil=True, error_model="numpy", cache=True)
def _stack_r(n0, ns, cos_i, lam, index, thickness):
    """R of the stack (index[k], thickness[k] nm, from the n0 side) on the interface n0 -> ns
    at cos_i and lam: 1 past the critical angle or where the product is not finite."""
    layers = index.shape[0]
    c = min(abs(cos_i), 1.0)
    sin2 = max(1.0 - c * c, 0.0)
    r0 = n0 / ns
    st2 = r0 * r0 * sin2
    if st2 > 1.0:
        return 1.0
    cos_s = math.sqrt(max(1.0 - st2, 0.0))
    # a zero admittance (grazing, p) makes numpy's product inf or nan: R = 1 there; numba
    # raises on a complex division by zero, so it is caught before
    if cos_s == 0.0 or c == 0.0:
        return 1.0
    # both polarisations' characteristic matrices at once: each layer's angle and phase (its
    # cosine and sine, the kernel's cost) serve both
    b_s, c_s = 1.0 + 0.0j, ns * cos_s + 0.0j
    b_p, c_p = 1.0 + 0.0j, ns / cos_s + 0.0j
    for k in range(layers - 1, -1, -1):
        n1 = index[k]
        q = n0 / n1
        cos1 = math.sqrt(max(1.0 - q * q * sin2, 0.0))
        if cos1 == 0.0:
            return 1.0
        e_s, e_p = n1 * cos1, n1 / cos1
        delta = 2.0 * math.pi * n1 * thickness[k] * cos1 / lam
        cd, isd = math.cos(delta), 1j * math.sin(delta)
        b_s, c_s = cd * b_s + isd * c_s / e_s, e_s * isd * b_s + cd * c_s
        b_p, c_p = cd * b_p + isd * c_p / e_p, e_p * isd * b_p + cd * c_p
    e0_s, e0_p = n0 * c, n0 / c
    den_s, den_p = e0_s * b_s + c_s, e0_p * b_p + c_p
    if den_s == 0.0 or den_p == 0.0:
        return 1.0
    r_s = (e0_s * b_s - c_s) / den_s
    r_p = (e0_p * b_p - c_p) / den_p
    total = 0.5 * (r_s.real * r_s.real + r_s.imag * r_s.imag
                   + r_p.real * r_p.real + r_p.imag * r_p.imag)
    return 1.0 if not math.isfinite(total) else min(max(total, 0.0), 1.0)


@jit.njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def stack_kernel(n0, ns, cos_i, lam, index, thickness, out):
    """out[i] = _stack_r of element i (1-D float64 arrays of one length)."""
    for i in prange(out.shape[0]):
        out[i] = _stack_r(n0[i], ns[i], cos_i[i], lam[i], index, thickness)


@jit.njit(nogil=True, error_model="numpy", cache=True)
def _fresnel_r(n0, ns, cos_i):
    """core.coatings.fresnel_reflectance of one interface."""
    c = min(abs(cos_i), 1.0)
    sin2_t = (n0 / ns) ** 2 * max(1.0 - c * c, 0.0)
    if sin2_t > 1.0:
        return 1.0
    cos_t = math.sqrt(max(1.0 - sin2_t, 0.0))
    rs = (n0 * c - ns * cos_t) / (n0 * c + ns * cos_t)
    rp = (ns * c - n0 * cos_t) / (ns * c + n0 * cos_t)
    r = 0.5 * (rs * rs + rp * rp)
    return 1.0 if not math.isfinite(r) else min(max(r, 0.0), 1.0)


@jit.njit(parallel=True, nogil=True, error_model="numpy", cache=True)
def path_weight_kernel(bare, idx, m1, m2, reflect, cos_out, wl, fwd_index, fwd_thickness,
                       rev_index, rev_thickness, air_max, live, weight):
    """weight[i] *= prod over steps s (cos_out[s, i] not nan) of R (reflect[s]) or 1 - R, R
    the coating's reflectance between idx[m1[s], i] and idx[m2[s], i] (core.coatings.Coating
    .reflectance for a bare, single or multi-layer coating: 0 between equal indices, Fresnel's
    on a bare or cemented surface, else the stack, reversed from the glass side); for the
    rays `live` only (a ray the trace has killed gets weight 0 whatever its coatings)."""
    steps = cos_out.shape[0]
    for i in prange(weight.shape[0]):
        if not live[i]:
            continue
        w = weight[i]
        for s in range(steps):
            c = cos_out[s, i]
            if math.isnan(c):
                continue
            n1, n2 = idx[m1[s], i], idx[m2[s], i]
            if n1 == n2:
                r = 0.0
            elif bare or (n1 > air_max and n2 > air_max):
                r = _fresnel_r(n1, n2, c)
            elif n1 <= n2:
                r = _stack_r(n1, n2, c, wl[i], fwd_index, fwd_thickness)
            else:
                r = _stack_r(n1, n2, c, wl[i], rev_index, rev_thickness)
            w *= r if reflect[s] else 1.0 - r
        weight[i] = w


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
