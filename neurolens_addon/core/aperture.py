"""Aperture stop shapes in normalised stop coordinates, and f-number -> stop radius.

Coordinates: (x, y) in the stop plane divided by the current stop radius, so the full circular
opening is the unit disc. Every shape lies inside the disc of radius `bounding_radius()`.
All methods are vectorised over broadcastable arrays; NaN / inf points are never inside.

Shapes and their equations
- CircularAperture: inside iff x^2 + y^2 <= 1; area pi. `sample` uses Shirley & Chiu's
  concentric square -> disc map (low distortion, keeps stratification):
      a = 2 u1 - 1, b = 2 u2 - 1;  |a| > |b|: r = a, phi = (pi/4) b/a;
                                   else:       r = b, phi = pi/2 - (pi/4) a/b.
- PolygonAperture(blades n, rotation_deg, curvature kappa): the iris inscribed in the unit circle,
  vertex j at angle rot + 2 pi j / n (counter-clockwise from +x). With alpha = pi / n, the edge
  midpoint lies at distance a = cos(alpha), half-chord h = sin(alpha). Each blade edge is a
  circular arc through its two vertices with curvature kappa (1 / radius, in units of
  1 / stop radius) bulging outward: kappa = 0 straight blades (regular polygon), kappa = 1 the
  unit circle itself; in between the arc's sagitta is
      s = h^2 kappa / (1 + sqrt(1 - kappa^2 h^2)).
  In the local frame of an edge (polar angle beta in [-alpha, alpha] from the edge normal) the
  boundary is at radius
      r_max(beta) = (2 - kappa (a + s)) (a + s) / (sqrt(1 - q^2 sin^2 beta) - q cos beta),
      q = kappa (a + s) - 1,
  (stable for kappa -> 0, where it becomes a / cos(beta)); inside iff rho <= r_max(beta).
  The shape is convex for 0 <= kappa <= 1. Area (exact):
      A = n (a h + A_seg),  A_seg = (x - sin x) / (2 kappa^2),  x = 2 asin(kappa h)
  (A_seg = 0 at kappa = 0; a series is used for small x).
  `sample`: u1 picks the fan sector j = floor(n u1) (sector = triangle O-v_j-v_{j+1} plus its
  circular segment, all of equal area) and its fractional part t sets the swept area
  A(beta) = t A_sector, where
      A(beta) = 1/2 r_max(beta) sin(beta + alpha) + A_seg(chord from v_j to P(beta)),
  inverted in closed form for kappa = 0 (beta = atan(2 A / a^2 - tan alpha)) and otherwise by
  safeguarded Newton iterations (dA/dbeta = r_max^2 / 2, bisection when a step leaves the
  bracket) from a tabulated first guess, to ~1e-15; then rho = r_max(beta) sqrt(u2).
  This is an exact, deterministic warp of the unit square onto the shape: uniform density.
- ImageMaskAperture(mask): an (H, W) transmittance image in [0, 1] stretched over [-1, 1]^2,
  row 0 at the top (y = +1), column 0 at the left (x = -1), pixel centres at
      x_j = -1 + (2 j + 1) / W,   y_i = 1 - (2 i + 1) / H.
  transmittance(x, y) is the bilinear interpolation of the pixel values (edge pixels extended up
  to the image border, 0 outside the square); inside iff transmittance > 0.5.
  area = sum(mask) * 4 / (H W) (the integral of the pixelwise-constant transmittance).
  `sample` draws from the piecewise-constant density proportional to the pixel values by a 2-D
  inverse CDF (u2 picks the row from the marginal, u1 the column from that row's conditional,
  continuous inside the pixel). For a binary mask this is uniform over the lit pixels; for a
  soft mask, weighting each sample by area() gives the transmittance-weighted integral. The
  pixel footprint and the bilinear "> 0.5" region agree for a binary mask except within half a
  pixel of a corner of the lit region, where bilinear interpolation rounds the corner.

f-number: the entrance pupil scales with the stop, so (paraxially, pupil magnification fixed)
    stop_radius(N) = design_stop_radius * design_N / N,
and N below the design's (wider than the lens opens) is refused.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import ApertureError

#: Points this close outside the boundary (relative) still count as inside, so that samples
#: generated on the boundary itself never fail `inside` by rounding.
_EDGE_TOL = 1e-12


def _xy(x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Broadcast to float64 arrays; also return the finite mask (NaN-safe copies at 0)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    ok = np.isfinite(x) & np.isfinite(y)
    return np.where(ok, x, 0.0), np.where(ok, y, 0.0), ok


def _uv(u1, u2) -> tuple[np.ndarray, np.ndarray]:
    u1, u2 = np.broadcast_arrays(np.asarray(u1, dtype=np.float64),
                                 np.asarray(u2, dtype=np.float64))
    top = np.nextafter(1.0, 0.0)
    return (np.clip(np.nan_to_num(u1, nan=0.0), 0.0, top),
            np.clip(np.nan_to_num(u2, nan=0.0), 0.0, top))


class Aperture:
    """Common interface. Subclasses implement inside, sample, area, bounding_radius."""

    kind = "aperture"

    def inside(self, x, y) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def transmittance(self, x, y) -> np.ndarray:
        """Fraction of light passed at (x, y): 1.0 inside, 0.0 outside for hard shapes."""
        return self.inside(x, y).astype(np.float64)

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def area(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def bounding_radius(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def pdf(self) -> float:
        """Density of `sample` per unit (normalised) area: 1 / area() (uniform shapes)."""
        return 1.0 / self.area()


class CircularAperture(Aperture):
    """The unit disc."""

    kind = "circle"

    def inside(self, x, y) -> np.ndarray:
        x, y, ok = _xy(x, y)
        return ok & (x * x + y * y <= 1.0 + _EDGE_TOL)

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = _uv(u1, u2)
        a = 2.0 * u1 - 1.0
        b = 2.0 * u2 - 1.0
        first = np.abs(a) > np.abs(b)
        r = np.where(first, a, b)
        safe_a = np.where(a == 0.0, 1.0, a)
        safe_b = np.where(b == 0.0, 1.0, b)
        phi = np.where(first, (np.pi / 4.0) * (b / safe_a),
                       np.pi / 2.0 - (np.pi / 4.0) * (a / safe_b))
        phi = np.where((a == 0.0) & (b == 0.0), 0.0, phi)
        return r * np.cos(phi), r * np.sin(phi)

    def area(self) -> float:
        return math.pi

    def bounding_radius(self) -> float:
        return 1.0

    def __repr__(self) -> str:
        return "CircularAperture()"


def _segment_area(chord, kappa: float) -> np.ndarray:
    """Area between a chord of length `chord` and its minor arc of curvature kappa (>= 0)."""
    chord = np.asarray(chord, dtype=np.float64)
    if kappa == 0.0:
        return np.zeros_like(chord)
    x = 2.0 * np.arcsin(np.clip(0.5 * kappa * chord, 0.0, 1.0))
    x2 = x * x
    series = x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    diff = np.where(x < 1e-2, series, x - np.sin(x))
    return diff / (2.0 * kappa * kappa)


class PolygonAperture(Aperture):
    """A regular n-blade iris inscribed in the unit circle, blade edges optionally curved."""

    kind = "polygon"

    def __init__(self, blades: int, rotation_deg: float = 0.0, curvature: float = 0.0):
        try:
            n = int(blades)
        except (TypeError, ValueError):
            raise ApertureError(f"aperture blades must be an integer >= 3, got {blades!r}")
        if n != blades or n < 3:
            raise ApertureError(f"aperture blades must be an integer >= 3, got {blades!r}")
        rot = float(rotation_deg)
        kappa = float(curvature)
        if not math.isfinite(rot):
            raise ApertureError(f"aperture rotation must be finite (degrees), got {rotation_deg!r}")
        if not (0.0 <= kappa <= 1.0):
            raise ApertureError("aperture blade curvature must be in [0, 1] (0 straight blades, "
                                f"1 circular), got {curvature!r}")
        self.blades = n
        self.rotation_deg = rot
        self.curvature = kappa
        self._rot = math.radians(rot)
        self._alpha = math.pi / n
        self._a = math.cos(self._alpha)
        self._h = math.sin(self._alpha)
        kh = kappa * self._h
        self._s = self._h * kh / (1.0 + math.sqrt(max(0.0, 1.0 - kh * kh)))
        self._apex = self._a + self._s
        self._q = kappa * self._apex - 1.0
        self._num = (2.0 - kappa * self._apex) * self._apex
        self._tri = self._a * self._h
        self._seg = float(_segment_area(2.0 * self._h, kappa))
        self._sector = self._tri + self._seg
        if kappa > 0.0:   # table of the swept area: a close first guess for Newton's method
            self._beta_tab = np.linspace(-self._alpha, self._alpha, 1025)
            self._area_tab = self._swept_area(self._beta_tab)[0]

    # -- geometry in an edge's local frame --------------------------------------------------
    def _r_max(self, beta) -> np.ndarray:
        sb, cb = np.sin(beta), np.cos(beta)
        q = self._q
        return self._num / (np.sqrt(np.maximum(1.0 - q * q * sb * sb, 0.0)) - q * cb)

    def _swept_area(self, beta) -> tuple[np.ndarray, np.ndarray]:
        """Area of the sector part from beta = -alpha to beta, and r_max(beta)."""
        r = self._r_max(beta)
        tri = 0.5 * r * np.sin(beta + self._alpha)
        px, py = r * np.cos(beta), r * np.sin(beta)
        chord = np.hypot(px - self._a, py + self._h)
        return tri + _segment_area(chord, self.curvature), r

    def vertices(self) -> np.ndarray:
        """(n, 2) polygon vertices on the unit circle (the arcs' end points)."""
        ang = self._rot + 2.0 * self._alpha * np.arange(self.blades)
        return np.stack([np.cos(ang), np.sin(ang)], axis=1)

    def _local(self, x, y):
        rho = np.hypot(x, y)
        phi = np.arctan2(y, x) - self._rot
        width = 2.0 * self._alpha
        k = np.floor(phi / width)
        beta = phi - (k + 0.5) * width
        return rho, np.clip(beta, -self._alpha, self._alpha)

    def inside(self, x, y) -> np.ndarray:
        x, y, ok = _xy(x, y)
        rho, beta = self._local(x, y)
        return ok & (rho <= self._r_max(beta) * (1.0 + _EDGE_TOL))

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = _uv(u1, u2)
        n = self.blades
        scaled = u1 * n
        sector = np.minimum(np.floor(scaled), n - 1)
        frac = np.clip(scaled - sector, 0.0, 1.0)
        alpha = self._alpha
        if self.curvature == 0.0:   # closed-form inverse for the straight-edged triangle
            beta = np.arctan(2.0 * frac * self._tri / (self._a * self._a) - math.tan(alpha))
        else:
            target = frac * self._sector
            beta = np.interp(target, self._area_tab, self._beta_tab)
            lo = np.full_like(beta, -alpha)
            hi = np.full_like(beta, alpha)
            for _ in range(60):
                area, r = self._swept_area(beta)
                f = area - target
                lo = np.where(f < 0.0, beta, lo)
                hi = np.where(f > 0.0, beta, hi)
                step = f / (0.5 * r * r)
                new = beta - step
                bad = (new < lo) | (new > hi)       # Newton left the bracket: bisect
                new = np.where(bad, 0.5 * (lo + hi), new)
                change = np.max(np.abs(new - beta)) if new.size else 0.0
                beta = new
                if change < 1e-14:
                    break
            beta = np.clip(beta, -alpha, alpha)
        rho = self._r_max(beta) * np.sqrt(u2)
        phi = self._rot + (2.0 * sector + 1.0) * alpha + beta
        return rho * np.cos(phi), rho * np.sin(phi)

    def area(self) -> float:
        return self.blades * self._sector

    def bounding_radius(self) -> float:
        return 1.0

    def __repr__(self) -> str:
        return (f"PolygonAperture(blades={self.blades}, rotation_deg={self.rotation_deg:g}, "
                f"curvature={self.curvature:g})")


class ImageMaskAperture(Aperture):
    """A transmittance image over [-1, 1]^2 (row 0 at the top). Values are clipped to [0, 1]."""

    kind = "image"

    def __init__(self, mask_2d_array, source: str | None = None):
        where = f"aperture mask {source}: " if source else "aperture mask: "
        m = np.asarray(mask_2d_array)
        if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
            raise ApertureError(f"{where}expected a 2-D image, got shape {m.shape}")
        m = m.astype(np.float64)
        if not np.all(np.isfinite(m)):
            raise ApertureError(f"{where}contains NaN or infinite values")
        m = np.clip(m, 0.0, 1.0)
        if not np.any(m > 0.0):
            raise ApertureError(f"{where}is completely black: it would block all light")
        self.source = source
        self.mask = m
        self.mask.setflags(write=False)
        h, w = m.shape
        self._h, self._w = h, w
        # 2-D piecewise-constant distribution: marginal over rows, conditional over columns
        row_sum = m.sum(axis=1)
        total = row_sum.sum()
        self._row_cdf = np.concatenate([[0.0], np.cumsum(row_sum) / total])
        self._row_cdf[-1] = 1.0
        safe = np.where(row_sum[:, None] > 0, m, 1.0)
        cond = np.cumsum(safe, axis=1) / safe.sum(axis=1, keepdims=True)
        self._col_cdf = np.concatenate([np.zeros((h, 1)), cond], axis=1)
        self._col_cdf[:, -1] = 1.0
        self._flat_cdf = (self._col_cdf + np.arange(h)[:, None]).ravel()
        self._area = float(total * 4.0 / (h * w))
        # conservative bounding radius: farthest corner of any pixel with light
        ii, jj = np.nonzero(m > 0.0)
        xs = np.stack([-1.0 + 2.0 * jj / w, -1.0 + 2.0 * (jj + 1) / w])
        ys = np.stack([1.0 - 2.0 * ii / h, 1.0 - 2.0 * (ii + 1) / h])
        self._bound = float(np.sqrt(np.max(np.abs(xs), axis=0) ** 2
                                    + np.max(np.abs(ys), axis=0) ** 2).max())

    def transmittance(self, x, y) -> np.ndarray:
        x, y, ok = _xy(x, y)
        h, w = self._h, self._w
        inbox = ok & (np.abs(x) <= 1.0) & (np.abs(y) <= 1.0)
        fx = np.clip((x + 1.0) * 0.5 * w - 0.5, 0.0, w - 1.0)
        fy = np.clip((1.0 - y) * 0.5 * h - 0.5, 0.0, h - 1.0)
        j0 = np.minimum(np.floor(fx).astype(np.intp), max(w - 2, 0))
        i0 = np.minimum(np.floor(fy).astype(np.intp), max(h - 2, 0))
        j1 = np.minimum(j0 + 1, w - 1)
        i1 = np.minimum(i0 + 1, h - 1)
        tx = fx - j0
        ty = fy - i0
        m = self.mask
        v = ((1 - ty) * ((1 - tx) * m[i0, j0] + tx * m[i0, j1])
             + ty * ((1 - tx) * m[i1, j0] + tx * m[i1, j1]))
        return np.where(inbox, v, 0.0)

    def inside(self, x, y) -> np.ndarray:
        return self.transmittance(x, y) > 0.5

    def sample(self, u1, u2) -> tuple[np.ndarray, np.ndarray]:
        u1, u2 = _uv(u1, u2)
        h, w = self._h, self._w
        rc = self._row_cdf
        i = np.clip(np.searchsorted(rc, u2, side="right") - 1, 0, h - 1)
        fy = i + np.clip((u2 - rc[i]) / (rc[i + 1] - rc[i]), 0.0, 1.0)
        idx = np.searchsorted(self._flat_cdf, i + u1, side="right") - 1
        j = np.clip(idx - i * (w + 1), 0, w - 1)
        cc = self._col_cdf
        lo, hi = cc[i, j], cc[i, j + 1]
        fx = j + np.clip((u1 - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0, 1.0)
        return -1.0 + 2.0 * fx / w, 1.0 - 2.0 * fy / h

    def area(self) -> float:
        return self._area

    def bounding_radius(self) -> float:
        return self._bound

    def __repr__(self) -> str:
        src = f", source={self.source!r}" if self.source else ""
        return f"ImageMaskAperture(shape={self.mask.shape}{src})"


# ---- f-number ---------------------------------------------------------------------------------

def _check_f(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ApertureError(f"{name} must be a positive number, got {value!r}")
    return v


def stop_radius_for_f_number(design_stop_radius: float, design_f_number: float,
                             f_number: float) -> float:
    """Stop radius (mm) that gives `f_number`: design_stop_radius * design_f_number / f_number.

    Raises ApertureError (a ValueError) when f_number is wider (smaller) than the design's.
    """
    r0 = _check_f("design stop radius", design_stop_radius)
    n0 = _check_f("design f-number", design_f_number)
    n = _check_f("f-number", f_number)
    if n < n0 * (1.0 - 1e-9):
        raise ApertureError(f"f/{n:g} is wider than this lens allows: its widest aperture is "
                            f"f/{n0:g} (requested f-number {n:g} < design f-number {n0:g})")
    return r0 * n0 / n


def clamp_f_number(f_number: float, design_f_number: float) -> tuple[float, str | None]:
    """(usable f-number, message or None): f-numbers wider than the design's are clamped to it."""
    n0 = _check_f("design f-number", design_f_number)
    n = _check_f("f-number", f_number)
    if n < n0 * (1.0 - 1e-9):
        return n0, (f"f/{n:g} is wider than this lens allows; using its widest aperture "
                    f"f/{n0:g} (design f-number {n0:g})")
    return n, None


# ---- factory ----------------------------------------------------------------------------------

_SHAPES = {
    "circle": "circle", "circular": "circle", "round": "circle",
    "polygon": "polygon", "blades": "polygon", "iris": "polygon",
    "image": "image", "mask": "image", "custom": "image",
}


def load_mask_image(path) -> np.ndarray:
    """Read a PNG (matplotlib.image.imread) as an (H, W) transmittance in [0, 1].

    RGB(A) is converted to Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B, times alpha when
    present (transparent = opaque blade). Integer images are scaled by their type's maximum.
    """
    import matplotlib.image as mpimg  # imported lazily: only image masks need matplotlib

    try:
        img = np.asarray(mpimg.imread(str(path)))
    except Exception as exc:  # missing file, not an image, unsupported format
        raise ApertureError(f"aperture mask {path}: cannot read image ({exc})") from exc
    if np.issubdtype(img.dtype, np.integer):
        img = img.astype(np.float64) / np.iinfo(img.dtype).max
    img = img.astype(np.float64)
    if img.ndim == 2:
        lum = img
    elif img.ndim == 3 and img.shape[2] in (1, 2, 3, 4):
        c = img.shape[2]
        if c in (1, 2):
            lum = img[..., 0]
        else:
            lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
        if c in (2, 4):
            lum = lum * img[..., -1]
    else:
        raise ApertureError(f"aperture mask {path}: expected a grey, RGB or RGBA image, "
                            f"got array shape {img.shape}")
    return lum


def aperture_from_settings(shape: str, blades: int = 0, rotation_deg: float = 0.0,
                           curvature: float = 0.0, mask_path=None) -> Aperture:
    """Build an aperture from UI settings.

    shape (case-insensitive): "circle" (also "circular", "round"), "polygon" ("blades",
    "iris") or "image" ("mask", "custom"); blades / rotation_deg / curvature are used by the
    polygon, mask_path (a PNG) by the image mask.
    """
    key = _SHAPES.get(str(shape).strip().lower())
    if key is None:
        raise ApertureError(f"aperture shape must be one of 'circle', 'polygon', 'image', "
                            f"got {shape!r}")
    if key == "circle":
        return CircularAperture()
    if key == "polygon":
        return PolygonAperture(blades, rotation_deg, curvature)
    if mask_path is None or str(mask_path).strip() == "":
        raise ApertureError("aperture shape 'image' needs a mask image file (mask_path)")
    return ImageMaskAperture(load_mask_image(mask_path), source=str(mask_path))
