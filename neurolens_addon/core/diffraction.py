"""Diffraction at the aperture: the Fraunhofer pattern of the stop's shape as the image's
point-spread kernel (opt-in; starbursts on highlights, softening at small stops).

Model. A plane wave through the entrance pupil (the stop's image in object space, radius
R_ep, transmittance a(x, y) with (x, y) in units of R_ep: the stop's own shape, scaled)
leaves it with the far-field (Fraunhofer) intensity
    I(f) = |A(f)|^2,   A(f) = int a(x) exp(-2 pi i f.x) d^2x,
f the spatial frequency in cycles per R_ep (Goodman, Introduction to Fourier Optics, 3rd ed.,
sec. 4.3): on the sensor, behind the exit pupil, the pattern of frequency f lies at
    x = 2 N_w lambda f,
N_w the working f-number (1 / 2 sin of the image-side marginal ray: the exit pupil's radius
over its distance, equal to v / R_ep for v the image distance). The image with diffraction is
the image without it convolved, channel by channel, with
    K_c(x) = sum_lambda w_c(lambda) I(x / (2 N_w lambda)) / norm,
w_c the channel's sensor response (core.sensor_response) at wavelengths spread over its
range (the d line alone without dispersion): every highlight shows spikes in proportion to its
energy (N spikes for an even blade count N, 2N for an odd one: parallel edges share theirs,
longer in red than in blue), everything is softened as much as the stop diffracts, and each
kernel sums to 1: the image's energy is unchanged. A convolution is the converged limit of
turning every camera ray by a sample of the pattern, without that estimate's noise in the faint
spikes (a spike 30 pixels out carries ~1e-5 of the light per pixel).

Approximations: the pupil is the stop's shape on axis and the kernel the same over the frame
(off axis the real pupil is vignetted, which would widen the spikes there); defocused light
gets the same kernel; the wave is scalar and the pattern that of the pupil alone (aberrations
are the trace's); the kernel reaches RHO_MAX cycles per R_ep or the frame's size, and the
energy beyond is left out before normalising (`captured` says how much is kept).

Pattern. I is computed by FFT of the aperture's transmittance (cell coverage from
SUPERSAMPLE^2 points) at two resolutions, a fine frequency step for the core
(|f| < RHO_SWITCH) and a wide reach for the tail, and read bilinearly; a kernel pixel averages
PIXEL_POINTS^2 points of I times the pixel's area in frequency.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

#: the kernel's reach (cycles per entrance-pupil radius) and where the core's FFT gives way
RHO_MAX = 200.0
RHO_SWITCH = 16.0
SUPERSAMPLE = 4
#: (grid cells across the aperture's bounding square, FFT size) of the two FFTs: the
#: frequency step is cells / (2 b size), the reach cells / (4 b) cycles per R_ep (b the
#: shape's bounding radius, 1 for the library's shapes)
CORE_FFT = (128, 2048)
TAIL_FFT = (1024, 2048)
#: points per kernel pixel and axis; wavelengths per channel with dispersion
PIXEL_POINTS = 3
WAVELENGTHS_PER_CHANNEL = 7


@dataclass(frozen=True)
class FraunhoferPattern:
    """|A(f)|^2 of one aperture shape on two centred frequency grids (module docstring)."""

    core_step: float
    core: np.ndarray
    tail_step: float
    tail: np.ndarray
    area: float                       # int |a|^2 (Parseval: the pattern's whole energy)

    def intensity(self, fx, fy) -> np.ndarray:
        """I at frequencies (cycles per R_ep); 0 beyond RHO_MAX."""
        fx = np.asarray(fx, dtype=np.float64)
        fy = np.asarray(fy, dtype=np.float64)
        r = np.hypot(fx, fy)
        near = r < RHO_SWITCH
        out = np.where(near, _bilinear(self.core, self.core_step, fx, fy),
                       _bilinear(self.tail, self.tail_step, fx, fy))
        return np.where(r <= RHO_MAX, np.maximum(out, 0.0), 0.0)


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


def _power(coverage: np.ndarray, extent: float, size: int):
    """(frequency step, |A|^2 on the size^2 frequency grid, centred): A by FFT of the coverage,
    scaled by the cell area so that it estimates the continuous transform."""
    cells = coverage.shape[0]
    dx = 2.0 * extent / cells
    grid = np.zeros((size, size), dtype=np.complex64)
    grid[:cells, :cells] = coverage
    spec = np.fft.fftshift(np.fft.fft2(grid))
    power = (spec.real.astype(np.float64) ** 2 + spec.imag.astype(np.float64) ** 2) * dx ** 4
    return 1.0 / (size * dx), power


def _bilinear(power: np.ndarray, step: float, fx: np.ndarray, fy: np.ndarray) -> np.ndarray:
    """power at frequencies (fx, fy), bilinear between grid points (row = y, column = x)."""
    n = power.shape[0]
    gx = fx / step + n // 2
    gy = fy / step + n // 2
    ix = np.clip(np.floor(gx).astype(np.int64), 0, n - 2)
    iy = np.clip(np.floor(gy).astype(np.int64), 0, n - 2)
    tx, ty = np.clip(gx - ix, 0.0, 1.0), np.clip(gy - iy, 0.0, 1.0)
    return ((1 - ty) * ((1 - tx) * power[iy, ix] + tx * power[iy, ix + 1])
            + ty * ((1 - tx) * power[iy + 1, ix] + tx * power[iy + 1, ix + 1]))


def build_pattern(aperture) -> FraunhoferPattern:
    """The pattern of `aperture` (a core.aperture shape; None: the circle)."""
    if aperture is None:
        from .aperture import CircularAperture
        aperture = CircularAperture()
    extent = float(aperture.bounding_radius()) * 1.0001
    core_step, core = _power(_coverage(aperture, extent, CORE_FFT[0]), extent, CORE_FFT[1])
    # Parseval's energy from the fine grid (its edge cells are the thinnest share of it)
    fine = _coverage(aperture, extent, TAIL_FFT[0])
    tail_step, tail = _power(fine, extent, TAIL_FFT[1])
    area = float((fine * fine).sum() * (2.0 * extent / TAIL_FFT[0]) ** 2)
    return FraunhoferPattern(core_step, core, tail_step, tail, area)


@lru_cache(maxsize=4)
def _pattern_for(key: str, aperture) -> FraunhoferPattern:
    return build_pattern(aperture)


def pattern_for(aperture) -> FraunhoferPattern:
    """build_pattern, cached by the shape's repr (seconds each)."""
    return _pattern_for(repr(aperture), aperture)


def channel_wavelengths(dispersion: bool) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths (M,) nm, weights (M, 3)): each channel's response at M wavelengths, its
    column summing to 1; without dispersion the d line alone for all three."""
    from .prescription import WAVELENGTH_D_NM
    if not dispersion:
        return np.array([WAVELENGTH_D_NM]), np.ones((1, 3))
    from .sensor_response import sensor_response
    s = sensor_response()
    u = (np.arange(WAVELENGTHS_PER_CHANNEL) + 0.5) / WAVELENGTHS_PER_CHANNEL
    # per channel, wavelengths at the quantiles of its response: equal weights
    lam = np.concatenate([s.sample_channel(u, c) for c in range(3)])
    w = np.zeros((lam.size, 3))
    for c in range(3):
        w[c * u.size:(c + 1) * u.size, c] = 1.0 / u.size
    return lam, w


def kernel_radius(*, pixel_mm: float, working_f_number: float, dispersion: bool,
                  max_radius_px: int) -> int:
    """The radius in pixels of film_kernel's kernels (RHO_MAX at the longest wavelength, at
    most max_radius_px), without computing them (engine.memory sizes the render with it)."""
    lam, _w = channel_wavelengths(dispersion)
    per_px = pixel_mm / (2.0 * working_f_number * 1e-6)
    return max(int(min(max_radius_px, math.ceil(RHO_MAX * lam.max() / per_px))), 1)


@dataclass(frozen=True)
class DiffractionKernel:
    """Per-channel convolution kernels on the film's pixel grid, centred, each summing to 1."""

    kernels: np.ndarray          # (3, 2 r + 1, 2 r + 1)
    captured: float              # share of the pattern's energy within the kernel (green)
    pixel_cycles: float          # cycles per R_ep per pixel at the d line (the scale)


def film_kernel(pattern: FraunhoferPattern, *, pixel_mm: float, working_f_number: float,
                dispersion: bool, max_radius_px: int) -> DiffractionKernel:
    """The kernel of a film whose pixels are pixel_mm square behind a lens working at N_w:
    a pixel offset x maps to f = x pixel_mm / (2 N_w lambda)."""
    from .prescription import WAVELENGTH_D_NM
    if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0
               for v in (pixel_mm, working_f_number)):
        raise ValueError(f"diffraction kernel: the pixel ({pixel_mm!r} mm) and the working "
                         f"f-number ({working_f_number!r}) must be positive numbers")
    lam, w = channel_wavelengths(dispersion)
    per_px = pixel_mm / (2.0 * working_f_number * 1e-6)                  # cycles * nm per px
    r = kernel_radius(pixel_mm=pixel_mm, working_f_number=working_f_number,
                      dispersion=dispersion, max_radius_px=max_radius_px)
    kernels = np.zeros((3, 2 * r + 1, 2 * r + 1))
    captured = []
    for lam_i, w_i in zip(lam, w):
        k = monochrome_kernel(pattern, per_px / lam_i, r)
        captured.append(k.sum() / pattern.area)
        kernels += w_i[:, None, None] * (k / k.sum())[None]
    green = float(np.average(captured, weights=w[:, 1]))
    return DiffractionKernel(kernels, min(green, 1.0), per_px / WAVELENGTH_D_NM)


@lru_cache(maxsize=4)
def _kernel_cached(key: tuple, aperture, pixel_mm: float, working_f_number: float,
                   dispersion: bool, max_radius_px: int) -> DiffractionKernel:
    return film_kernel(pattern_for(aperture), pixel_mm=pixel_mm,
                       working_f_number=working_f_number, dispersion=dispersion,
                       max_radius_px=max_radius_px)


def kernel_for(aperture, *, pixel_mm: float, working_f_number: float, dispersion: bool,
               max_radius_px: int) -> DiffractionKernel:
    """film_kernel of the shape's pattern, cached by value (the frames of an animation that
    keep their film, stop and focus share one)."""
    key = (repr(aperture), round(float(pixel_mm), 12), round(float(working_f_number), 9),
           bool(dispersion), int(max_radius_px))
    return _kernel_cached(key, aperture, pixel_mm, working_f_number, dispersion, max_radius_px)


#: kernel rows evaluated at once by monochrome_kernel (its points times ~15 float64
#: temporaries: a large kernel's 30 M points would otherwise take gigabytes)
KERNEL_BLOCK_POINTS = 1 << 18


def monochrome_kernel(pattern: FraunhoferPattern, cycles_per_px: float, r: int,
                      block_points: int = KERNEL_BLOCK_POINTS) -> np.ndarray:
    """(2 r + 1)^2 energy of the pattern falling on each pixel (PIXEL_POINTS^2 points of I
    times the pixel's area in frequency), for pixels cycles_per_px cycles per R_ep wide; a
    block of kernel rows at a time (each row reads only its own points: the same values)."""
    q = (np.arange(PIXEL_POINTS) + 0.5) / PIXEL_POINTS - 0.5
    off = (np.arange(-r, r + 1)[:, None] + q[None, :]).ravel() * cycles_per_px
    # I(-f) = I(f) and the sub-pixel points are symmetric: rows -r..0 give rows 0..r
    top = np.empty((r + 1, 2 * r + 1))
    block = max(1, block_points // (off.size * PIXEL_POINTS))
    for i0 in range(0, r + 1, block):
        i1 = min(r + 1, i0 + block)
        fy, fx = np.meshgrid(off[i0 * PIXEL_POINTS:i1 * PIXEL_POINTS], off, indexing="ij")
        top[i0:i1] = pattern.intensity(fx, fy).reshape(i1 - i0, PIXEL_POINTS, 2 * r + 1,
                                                       PIXEL_POINTS).mean(axis=(1, 3))
    k = np.concatenate([top, top[:-1][::-1, ::-1]], axis=0)
    return k * cycles_per_px * cycles_per_px


#: points of one strip's FFT grid (rows times padded columns): bounds convolve's work arrays
#: (about 32 bytes a point) whatever the frame's size
STRIP_FFT_POINTS = 1 << 22


def strip_rows(height: int, width: int, r: int, points: int = STRIP_FFT_POINTS
               ) -> tuple[int, int, int]:
    """(output rows a strip, FFT rows, FFT columns) of convolve for a kernel of radius r: a
    strip of B rows reads B + 2 r rows and its linear convolution takes B + 4 r rows; B keeps
    that grid near `points` (at least r rows, so only the previous strip's last r rows are
    ever needed again; one strip when the frame fits)."""
    fw = _fft_size(width + 2 * r)
    b = max(r, 1, points // fw - 4 * r)
    if b + 2 * r >= height:
        b = height
    return b, _fft_size(min(height, b + 2 * r) + 2 * r), fw


def convolve(image: np.ndarray, kernel: DiffractionKernel, out: np.ndarray | None = None,
             strip_points: int = STRIP_FFT_POINTS) -> np.ndarray:
    """(H, W, >= 3) linear image convolved channel by channel (RGB; alpha and the rest kept),
    by FFT with zero padding: light the kernel spreads past the frame leaves it, as it would
    off a real sensor. The result goes to `out` (which may be `image` itself; default a copy
    of `image`, its dtype).

    A strip of output rows [y0, y1) is the linear convolution of input rows
    [y0 - r, y1 + r) (those inside the frame; the kernel reaches no farther), so the frame is
    convolved a strip of rows at a time (strip_rows): the same sums as one FFT of the whole
    frame, up to rounding, with work arrays bounded by `strip_points`."""
    h, w = image.shape[:2]
    k = kernel.kernels
    r = k.shape[1] // 2
    if out is None:
        out = np.array(image, copy=True)
    rows, fh, fw = strip_rows(h, w, r, strip_points)
    in_place = np.may_share_memory(out, image)
    for c in range(3):
        kspec = np.fft.rfft2(k[c], s=(fh, fw))
        halo = None                    # the previous strip's last r input rows, as they were
        for y0 in range(0, h, rows):
            y1 = min(h, y0 + rows)
            a0, a1 = max(0, y0 - r), min(h, y1 + r)
            strip = image[a0:a1, :, c].astype(np.float64)
            if halo is not None and in_place:
                strip[:halo.shape[0]] = halo      # rows this channel's last strip overwrote
            halo = image[max(y0, y1 - r):y1, :, c].astype(np.float64)
            spec = np.fft.rfft2(strip, s=(fh, fw))
            spec *= kspec
            full = np.fft.irfft2(spec, s=(fh, fw))
            o = y0 - a0 + r
            out[y0:y1, :, c] = np.maximum(full[o:o + (y1 - y0), r:r + w], 0.0)
            del spec, full
    return out


def _fft_size(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n (fast FFT lengths)."""
    best = 1 << max(n - 1, 0).bit_length()
    a = 1
    while a < best:
        b = a
        while b < best:
            c = b
            while c < best:
                if c >= n:
                    best = c
                c *= 5
            b *= 3
        a *= 2
    return best


def lens_working_f_number(lens, focus_mm: float, sensor_z_mm: float,
                          stop_radius_mm: float) -> float:
    """The paraxial working f-number of `lens` focused at focus_mm (from the sensor) with its
    stop opened to stop_radius_mm (the pupils scale with the stop)."""
    from .paraxial import working_f_number
    n_w = working_f_number(lens, focus_mm, sensor_z_mm)
    return n_w * lens.stop_radius_mm / float(stop_radius_mm)
