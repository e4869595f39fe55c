"""The film: where Blender's sensor settings put a rendered frame on the sensor (one place).

Pixels. A render of res_x x res_y at percentage P has R_x = max(1, floor(res_x P / 100))
columns (likewise R_y), as Blender and Cycles size the result. With pixel aspect (a_x, a_y)
the frame's shape is A_x : A_y = R_x a_x : R_y a_y.

Sensor fit. AUTO fits sensor_width to the longer side of the frame (HORIZONTAL when
A_x >= A_y, else VERTICAL with sensor_width as the height); HORIZONTAL fits sensor_width to
the width; VERTICAL fits sensor_height to the height:
    HORIZONTAL  W = size,            H = size A_y / A_x
    VERTICAL    W = size A_x / A_y,  H = size
Shift. Blender's lens shift (s_x, s_y) is in units of the larger film side:
    shift_mm = s max(W, H).
Image points. Pixel (i, j), i from the left and j from the bottom, with jitter (a, b) in
[0, 1)^2 lies at
    p = ((i + a) / R_x - 1/2) W + shift_x,   q = ((j + b) / R_y - 1/2) H + shift_y
(image x right, y up, mm from the optical axis). The pixel pitch is W / R_x by H / R_y.
Border. A render region (x0, y0, x1, y1) in [0, 1]^2 keeps [x0, x1] x [y0, y1] of the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .errors import NeuroLensError

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
FULL_FRAME = (0.0, 0.0, 1.0, 1.0)


class FilmError(NeuroLensError, ValueError):
    """Film settings that describe no image (names the setting)."""


def _positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FilmError(f"{name} must be a positive number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0.0):
        raise FilmError(f"{name} must be a positive number, got {value!r}")
    return v


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FilmError(f"{name} must be a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise FilmError(f"{name} must be a finite number, got {value!r}")
    return v


@dataclass(frozen=True)
class FilmSettings:
    """Blender's settings that decide the film (camera sensor and render output)."""

    sensor_width: float = 36.0
    sensor_height: float = 24.0
    sensor_fit: str = "AUTO"
    resolution_x: int = 1920
    resolution_y: int = 1080
    percentage: float = 100.0
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    border: tuple[float, float, float, float] = FULL_FRAME


@dataclass(frozen=True)
class Film:
    """The rendered frame on the sensor (module docstring)."""

    width_px: int
    height_px: int
    width_mm: float
    height_mm: float
    shift_x_mm: float = 0.0
    shift_y_mm: float = 0.0
    border: tuple[float, float, float, float] = FULL_FRAME

    @property
    def size_mm(self) -> tuple[float, float]:
        return self.width_mm, self.height_mm

    @property
    def pixel_pitch_mm(self) -> float:
        """The finer of the horizontal and vertical pixel pitches."""
        return min(self.width_mm / self.width_px, self.height_mm / self.height_px)

    @property
    def radius_mm(self) -> float:
        """Largest distance of a frame point from the axis (half diagonal plus shift)."""
        return math.hypot(0.5 * self.width_mm + abs(self.shift_x_mm),
                          0.5 * self.height_mm + abs(self.shift_y_mm))

    def on_lens(self, squeeze: float) -> "Film":
        """The film the lens itself images onto: an anamorphic lens's is 1 / squeeze as wide as
        the desqueezed frame (both renderers divide the frame's x by the squeeze), so its
        radius and its horizontal pixel pitch are the lens's."""
        if squeeze == 1.0:
            return self
        return replace(self, width_mm=self.width_mm / squeeze,
                       shift_x_mm=self.shift_x_mm / squeeze)

    @property
    def pixel_area_mm2(self) -> float:
        return (self.width_mm / self.width_px) * (self.height_mm / self.height_px)

    def pixel_coordinates(self, p, q):
        """(x, y) in pixels (from the left and bottom edges, pixel centres at i + 0.5) of
        image-space points (p, q) (mm): image_points inverted."""
        p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
        return (((p - self.shift_x_mm) / self.width_mm + 0.5) * self.width_px,
                ((q - self.shift_y_mm) / self.height_mm + 0.5) * self.height_px)

    def pixels_of(self, p, q):
        """The global pixel index (iy W + ix) of image-space points (p, q) (mm), -1 off the
        frame."""
        x, y = self.pixel_coordinates(p, q)
        ix, iy = np.floor(x), np.floor(y)
        ok = (ix >= 0) & (ix < self.width_px) & (iy >= 0) & (iy < self.height_px)
        return np.where(ok, iy * self.width_px + ix, -1).astype(np.int64)

    def image_points(self, ix, iy, jx, jy):
        """Image-space points (right, up; mm) of pixels (ix, iy) with jitter (jx, jy)."""
        p = ((ix + jx) / self.width_px - 0.5) * self.width_mm + self.shift_x_mm
        q = ((iy + jy) / self.height_px - 0.5) * self.height_mm + self.shift_y_mm
        return p, q

    def rect_mm(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1): the rendered part (the border) in mm, axis at 0, shift included."""
        w, h = self.width_mm, self.height_mm
        bx0, by0, bx1, by1 = self.border
        x = -0.5 * w + self.shift_x_mm
        y = -0.5 * h + self.shift_y_mm
        return (x + bx0 * w, y + by0 * h, x + bx1 * w, y + by1 * h)

    def radii_mm(self) -> tuple[float, float]:
        """[r_min, r_max]: the distances from the axis the rendered part covers."""
        x0, y0, x1, y1 = self.rect_mm()
        r_max = max(math.hypot(x, y) for x in (x0, x1) for y in (y0, y1))
        nx = 0.0 if x0 <= 0.0 <= x1 else min(abs(x0), abs(x1))
        ny = 0.0 if y0 <= 0.0 <= y1 else min(abs(y0), abs(y1))
        return math.hypot(nx, ny), r_max


#: the largest frame rendered: Blender's own limit per side, and 16 K x 16 K pixels in all
#: (within it, the engine's memory estimate refuses what the machine cannot hold: engine.memory)
MAX_SIDE_PX = 65536
MAX_FRAME_PIXELS = 16384 * 16384


def pixel_counts(resolution_x, resolution_y, percentage) -> tuple[int, int]:
    """(R_x, R_y): the rendered pixel counts (module docstring); a frame over MAX_SIDE_PX on a
    side or MAX_FRAME_PIXELS in all is refused before anything is allocated."""
    pct = _positive("resolution percentage", percentage) / 100.0
    for name, v in (("resolution_x", resolution_x), ("resolution_y", resolution_y)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise FilmError(f"{name} must be a positive integer, got {v!r}")
    rx, ry = max(1, int(resolution_x * pct)), max(1, int(resolution_y * pct))
    if max(rx, ry) > MAX_SIDE_PX or rx * ry > MAX_FRAME_PIXELS:
        raise FilmError(f"a {rx} x {ry} pixel frame ({resolution_x} x {resolution_y} at "
                        f"{percentage:g} %) is larger than the {MAX_SIDE_PX} pixels a side and "
                        f"{MAX_FRAME_PIXELS // 1_000_000} megapixels this renders")
    return rx, ry


def sensor_extent_mm(sensor_width, sensor_height, sensor_fit, aspect_x,
                     aspect_y) -> tuple[float, float]:
    """(W, H) of the film for a frame of shape aspect_x : aspect_y (module docstring)."""
    ax, ay = _positive("frame width", aspect_x), _positive("frame height", aspect_y)
    fit = str(sensor_fit).upper()
    if fit not in SENSOR_FITS:
        raise FilmError(f"sensor fit must be one of {', '.join(SENSOR_FITS)}, got {sensor_fit!r}")
    if fit == "AUTO":
        fit, size = ("HORIZONTAL" if ax >= ay else "VERTICAL"), sensor_width
    else:
        size = sensor_width if fit == "HORIZONTAL" else sensor_height
    size = _positive("sensor size", size)
    if fit == "HORIZONTAL":
        return size, size * ay / ax
    return size * ax / ay, size


def film_from_settings(s: FilmSettings) -> Film:
    """The Film of Blender's settings (module docstring)."""
    rx, ry = pixel_counts(s.resolution_x, s.resolution_y, s.percentage)
    w, h = sensor_extent_mm(s.sensor_width, s.sensor_height, s.sensor_fit,
                            rx * _positive("pixel aspect x", s.pixel_aspect_x),
                            ry * _positive("pixel aspect y", s.pixel_aspect_y))
    big = max(w, h)
    x0, y0, x1, y1 = (float(v) for v in s.border)
    if not (0.0 <= x0 < x1 <= 1.0 and 0.0 <= y0 < y1 <= 1.0):
        raise FilmError(f"render region must satisfy 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1, "
                        f"got {tuple(s.border)}")
    return Film(rx, ry, w, h, _finite("shift x", s.shift_x) * big,
                _finite("shift y", s.shift_y) * big, (x0, y0, x1, y1))
