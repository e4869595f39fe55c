"""Diffraction at the aperture: the Fraunhofer pattern of the stop's shape as a turn of each
camera ray's scene-side direction (opt-in; starbursts on highlights, softening at small stops).

Model. A plane wave through the entrance pupil (the stop's image in object space, radius
R_ep, transmittance a(x, y) with (x, y) in units of R_ep: the stop's own shape, scaled)
leaves it with the far-field (Fraunhofer) intensity
    I(f) = |A(f)|^2,   A(f) = int a(x) exp(-2 pi i f.x) d^2x,
f the spatial frequency in cycles per R_ep; a direction cosine offset delta corresponds to
f = delta R_ep / lambda (Goodman, Introduction to Fourier Optics, 3rd ed., sec. 4.3). Each
camera ray leaving the lens along d is turned to
    d' = normalize(d + (lambda / R_ep) (f_x e_1 + f_y e_2)),   f ~ I / int I,
e_1, e_2 the lens-space x and y axes carried to d by the rotation that takes z to d
(tangent_frame): the rendered image is the geometric one convolved with the pupil's
diffraction pattern at each ray's wavelength, so a highlight shows spikes in proportion to its
energy (N spikes for an even blade count N, 2N for an odd one: parallel edges share theirs)
and everything is softened as much as the stop diffracts. Weights are unchanged: the energy of
the image is that without diffraction.

Approximations: the pupil is the stop's shape on axis (off axis the real pupil is vignetted,
which would widen the spikes there); the wave is scalar and the pattern that of the pupil
alone (aberrations are the trace's); frequencies beyond RHO_MAX cycles per R_ep are left out
and the rest renormalised (`captured`: the share of the pattern's energy the table holds).

Table. I is computed by FFT of the aperture's transmittance (cell coverage from SUPERSAMPLE^2
points) at two resolutions, the fine grid for the core (|f| < RHO_SWITCH) and the coarse-cell
grid reaching RHO_MAX for the tail, and integrated over a polar table: NR radial bins (the
disc |f| < RHO_0, then NR - 1 log-spaced to RHO_MAX) by NPHI angular bins over [0, pi)
(I(-f) = I(f) for a real aperture). A sample picks the radial bin by its marginal CDF with u1,
the angular bin by that row's CDF with u2, the half plane by the first half of u2's remainder,
and a point uniform in area within the cell from the remainders (sample_frequency).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: the table's inner disc and outer radius (cycles per entrance-pupil radius)
RHO_0 = 0.05
RHO_MAX = 200.0
#: below this |f| the pattern comes from the fine-frequency FFT, above from the wide one
RHO_SWITCH = 16.0
NR = 96
NPHI = 180
SUPERSAMPLE = 4
#: (grid cells across the aperture's bounding square, FFT size) of the two FFTs: the core's
#: frequency step is cells / (2 b FFT size), its reach cells / (4 b) cycles per R_ep
CORE_FFT = (128, 2048)
TAIL_FFT = (1024, 2048)
#: integration points per polar cell and axis
CELL_POINTS = 4


@dataclass(frozen=True)
class FraunhoferTable:
    """The polar sampling table of one aperture shape's Fraunhofer pattern (module docstring)."""

    rho_edges: np.ndarray        # (NR + 1,) radial bin edges, cycles per R_ep
    marginal: np.ndarray         # (NR + 1,) CDF over radial bins
    conditional: np.ndarray      # (NR, NPHI + 1) CDF over angular bins in [0, pi), per row
    captured: float              # share of the pattern's energy within RHO_MAX

    @property
    def energy(self) -> np.ndarray:
        """(NR, NPHI) probability of each polar cell over [0, pi) (the other half mirrors it)."""
        return np.diff(self.marginal)[:, None] * np.diff(self.conditional, axis=1)


def _coverage(aperture, extent: float, cells: int) -> np.ndarray:
    """(cells, cells) mean transmittance of each grid cell over [-extent, extent]^2."""
    dx = 2.0 * extent / cells
    centres = -extent + (np.arange(cells) + 0.5) * dx
    offsets = ((np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5) * dx
    out = np.zeros((cells, cells))
    for oy in offsets:
        y = (centres + oy)[:, None]
        for ox in offsets:
            out += aperture.transmittance((centres + ox)[None, :], y)
    return out / (SUPERSAMPLE * SUPERSAMPLE)


def _power(aperture, extent: float, cells: int, size: int):
    """(frequency step, |A|^2 on the size^2 frequency grid, centred): A by FFT of the coverage,
    scaled by the cell area so that it estimates the continuous transform."""
    dx = 2.0 * extent / cells
    grid = np.zeros((size, size), dtype=np.complex64)
    grid[:cells, :cells] = _coverage(aperture, extent, cells)
    spec = np.fft.fftshift(np.fft.fft2(grid))
    power = (spec.real.astype(np.float64) ** 2 + spec.imag.astype(np.float64) ** 2) * dx ** 4
    return 1.0 / (size * dx), power


def _bilinear(power: np.ndarray, step: float, fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
    """power at frequencies (fx, fy) (cycles per R_ep), bilinear between grid points."""
    n = power.shape[0]
    gx = fx / step + n // 2
    gy = fy / step + n // 2
    ix = np.clip(np.floor(gx).astype(np.int64), 0, n - 2)
    iy = np.clip(np.floor(gy).astype(np.int64), 0, n - 2)
    tx, ty = gx - ix, gy - iy
    return ((1 - ty) * ((1 - tx) * power[iy, ix] + tx * power[iy, ix + 1])
            + ty * ((1 - tx) * power[iy + 1, ix] + tx * power[iy + 1, ix + 1]))


def rho_edges() -> np.ndarray:
    return np.concatenate([[0.0], RHO_0 * (RHO_MAX / RHO_0) ** (np.arange(NR) / (NR - 1))])


def build_table(aperture) -> FraunhoferTable:
    """The polar table of `aperture` (a core.aperture shape; None: the circle)."""
    if aperture is None:
        from .aperture import CircularAperture
        aperture = CircularAperture()
    extent = float(aperture.bounding_radius()) * 1.0001
    core = _power(aperture, extent, *CORE_FFT)
    tail = _power(aperture, extent, *TAIL_FFT)
    edges = rho_edges()
    phi_edges = np.linspace(0.0, np.pi, NPHI + 1)
    # integration points uniform in rho^2 and phi within each cell (equal areas)
    q = (np.arange(CELL_POINTS) + 0.5) / CELL_POINTS
    r0, r1 = edges[:-1, None], edges[1:, None]
    rho = np.sqrt(r0 * r0 + q[None, :] * (r1 * r1 - r0 * r0))               # (NR, P)
    phi = phi_edges[:-1, None] + q[None, :] * (np.pi / NPHI)                # (NPHI, P)
    energy = np.empty((NR, NPHI))
    for k in range(NR):
        rr = rho[k][:, None, None, None]
        pp = phi[None, None, :, :]
        fx = (rr * np.cos(pp)).ravel()
        fy = (rr * np.sin(pp)).ravel()
        step, power = core if edges[k + 1] <= RHO_SWITCH else tail
        mean = _bilinear(power, step, fx, fy).reshape(CELL_POINTS, NPHI, CELL_POINTS)
        area = 0.5 * (edges[k + 1] ** 2 - edges[k] ** 2) * (np.pi / NPHI)
        energy[k] = mean.mean(axis=(0, 2)) * area
    energy = np.maximum(energy, 0.0)
    total = 2.0 * energy.sum()              # both half planes
    cov = _coverage(aperture, extent, CORE_FFT[0])
    parseval = float((cov * cov).sum() * (2.0 * extent / CORE_FFT[0]) ** 2)
    rows = energy.sum(axis=1)
    marginal = np.concatenate([[0.0], np.cumsum(rows)]) / rows.sum()
    safe = np.where(rows > 0.0, rows, 1.0)[:, None]
    cond = np.where(rows[:, None] > 0.0, np.cumsum(energy, axis=1) / safe,
                    np.arange(1, NPHI + 1)[None, :] / NPHI)
    conditional = np.concatenate([np.zeros((NR, 1)), cond], axis=1)
    conditional[:, -1] = 1.0
    marginal[-1] = 1.0
    return FraunhoferTable(edges, marginal, conditional, min(total / parseval, 1.0))


@lru_cache(maxsize=8)
def _table_for(key: str, aperture) -> FraunhoferTable:
    return build_table(aperture)


def table_for(aperture) -> FraunhoferTable:
    """build_table, cached by the shape's repr (a few seconds each)."""
    return _table_for(repr(aperture), aperture)


def sample_frequency(table: FraunhoferTable, u1, u2) -> tuple[np.ndarray, np.ndarray]:
    """(f_x, f_y) in cycles per R_ep, distributed as the pattern, from uniforms in [0, 1)."""
    u1 = np.clip(np.asarray(u1, dtype=np.float64), 0.0, np.nextafter(1.0, 0.0))
    u2 = np.clip(np.asarray(u2, dtype=np.float64), 0.0, np.nextafter(1.0, 0.0))
    m = table.marginal
    k = np.clip(np.searchsorted(m, u1, side="right") - 1, 0, NR - 1)
    r1 = (u1 - m[k]) / np.maximum(m[k + 1] - m[k], 1e-300)
    cond = table.conditional
    # every row runs 0..1: rows shifted by 2 k make one increasing array to search at once
    flat = (cond + 2.0 * np.arange(NR)[:, None]).ravel()
    pos = np.searchsorted(flat, u2 + 2.0 * k, side="right") - 1
    j = np.clip(pos - k * (NPHI + 1), 0, NPHI - 1)
    c0, c1 = cond[k, j], cond[k, j + 1]
    r2 = (u2 - c0) / np.maximum(c1 - c0, 1e-300)
    r2 = np.clip(r2, 0.0, np.nextafter(1.0, 0.0))
    half = r2 >= 0.5
    r3 = 2.0 * r2 - half
    e0, e1 = table.rho_edges[k], table.rho_edges[k + 1]
    rho = np.sqrt(e0 * e0 + np.clip(r1, 0.0, 1.0) * (e1 * e1 - e0 * e0))
    phi = (j + r3) * (np.pi / NPHI) + np.pi * half
    return rho * np.cos(phi), rho * np.sin(phi)


def tangent_frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e_1, e_2), each (3, N): the x and y axes turned by the rotation that takes +z to the
    unit directions d (3, N) (about the axis z x d); d = +z gives x and y themselves."""
    a, b, c = d
    inv = 1.0 / np.maximum(1.0 + c, 1e-12)
    e1 = np.stack([1.0 - a * a * inv, -a * b * inv, -a])
    e2 = np.stack([-a * b * inv, 1.0 - b * b * inv, -b])
    return e1, e2


def diffract(d: np.ndarray, wavelength_nm, pupil_radius_mm: float, table: FraunhoferTable,
             u1, u2) -> np.ndarray:
    """Unit scene-side directions d (3, N) turned by the pattern (module docstring) at each
    ray's wavelength, for an entrance pupil of radius pupil_radius_mm."""
    fx, fy = sample_frequency(table, u1, u2)
    s = np.asarray(wavelength_nm, dtype=np.float64) * 1e-6 / float(pupil_radius_mm)
    e1, e2 = tangent_frame(d)
    out = d + (s * fx) * e1 + (s * fy) * e2
    return out / np.linalg.norm(out, axis=0)


def entrance_pupil_radius_mm(lens, stop_radius_mm: float) -> float:
    """The paraxial entrance pupil's radius for the stop opened to stop_radius_mm."""
    from .paraxial import paraxial_data
    ep = paraxial_data(lens).entrance_pupil
    return 0.5 * ep.diameter_mm * float(stop_radius_mm) / lens.stop_radius_mm
