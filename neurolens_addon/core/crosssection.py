"""Lens cross-section thumbnails, rasterised with numpy, written as PNG with zlib.

Blender does not ship matplotlib, so the preset picker cannot use core.plots; this draws the
same picture (glass elements, the stop, the sensor and a few traced ray fans, as in
core.plots.lens_diagram) straight into an RGBA array. Pure Python + numpy (no bpy).

Picture: lens space y-z with the scene on the right, the sensor plane at the left edge,
uniform scale, centred on the canvas. Row 0 of the array is the top of the picture.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from .prescription import Lens

#: bump when the drawing changes, so cached thumbnails are redrawn
RENDER_VERSION = 1

_BACKGROUND = (0.16, 0.16, 0.17, 1.0)
_GLASS = (0.42, 0.62, 0.80, 1.0)
_EDGE = (0.80, 0.88, 0.95, 1.0)
_STOP = (0.98, 0.98, 0.98, 1.0)
_SENSOR = (0.95, 0.55, 0.20, 1.0)
_AXIS = (0.40, 0.40, 0.42, 1.0)
_FANS = ((0.95, 0.85, 0.30, 1.0), (0.45, 0.85, 0.45, 1.0), (0.90, 0.45, 0.75, 1.0))


class _Canvas:
    def __init__(self, width: int, height: int, z_range, y_half: float, margin: int):
        self.w, self.h = int(width), int(height)
        self.img = np.empty((self.h, self.w, 4), dtype=np.float64)
        self.img[:] = _BACKGROUND
        z0, z1 = z_range
        scale_z = (self.w - 2 * margin) / max(z1 - z0, 1e-9)
        scale_y = (self.h - 2 * margin) / max(2.0 * y_half, 1e-9)
        self.s = min(scale_z, scale_y)
        self.cz = 0.5 * (z0 + z1)
        self.cy = 0.0

    def to_px(self, z, y):
        col = (np.asarray(z, dtype=np.float64) - self.cz) * self.s + 0.5 * self.w
        row = 0.5 * self.h - (np.asarray(y, dtype=np.float64) - self.cy) * self.s
        return col, row

    def to_lens(self, col, row):
        z = (np.asarray(col, dtype=np.float64) + 0.5 - 0.5 * self.w) / self.s + self.cz
        y = (0.5 * self.h - (np.asarray(row, dtype=np.float64) + 0.5)) / self.s + self.cy
        return z, y

    def dots(self, z, y, colour, radius: int = 0):
        col, row = self.to_px(z, y)
        ok = np.isfinite(col) & np.isfinite(row)
        ci = np.rint(col[ok]).astype(int)
        ri = np.rint(row[ok]).astype(int)
        for dc in range(-radius, radius + 1):
            for dr in range(-radius, radius + 1):
                c, r = ci + dc, ri + dr
                keep = (c >= 0) & (c < self.w) & (r >= 0) & (r < self.h)
                self.img[r[keep], c[keep]] = colour

    def polyline(self, z, y, colour, radius: int = 0):
        z = np.asarray(z, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if z.size < 2:
            self.dots(z, y, colour, radius)
            return
        col, row = self.to_px(z, y)
        seg = np.hypot(np.diff(col), np.diff(row))
        n = np.maximum(2, np.ceil(seg * 1.5).astype(int) + 1)
        zz = np.concatenate([np.linspace(z[i], z[i + 1], n[i]) for i in range(z.size - 1)])
        yy = np.concatenate([np.linspace(y[i], y[i + 1], n[i]) for i in range(y.size - 1)])
        self.dots(zz, yy, colour, radius)


def _profile(lens: Lens, i: int, y):
    from .trace import sag
    return lens.vertex_z[i] - sag(lens, i, np.abs(y))


def cross_section_rgba(lens: Lens, width: int = 256, height: int = 128, *,
                       fields=(0.0, 0.6, 1.0), rays_per_fan: int = 5,
                       sensor_z: float = 0.0) -> np.ndarray:
    """(height, width, 4) float RGBA in [0, 1], row 0 at the top: the lens's y-z section."""
    from .field import half_field_deg
    from .plots import fan_paths

    vz = lens.vertex_z
    sds = np.array([s.semi_diameter_mm for s in lens.surfaces])
    y_half = 1.15 * float(sds.max())
    z_lo = min(float(sensor_z), float(vz.min())) - 0.04 * float(vz.max())
    z_hi = float(vz.max()) + 0.06 * float(vz.max() - min(0.0, sensor_z))
    cv = _Canvas(width, height, (z_lo, z_hi), y_half, margin=4)

    # optical axis
    cv.polyline([z_lo, z_hi], [0.0, 0.0], _AXIS)
    # glass: between surface i (front) and i + 1 wherever surface i is followed by glass
    cols = np.arange(cv.w)
    rows = np.arange(cv.h)
    zc, yc = cv.to_lens(cols[None, :], rows[:, None])
    zc = np.broadcast_to(zc, (cv.h, cv.w))
    yc = np.broadcast_to(yc, (cv.h, cv.w))
    with np.errstate(invalid="ignore"):
        for i, s in enumerate(lens.surfaces[:-1]):
            if s.material.is_air:
                continue
            r = min(sds[i], sds[i + 1])
            y_rows = yc[:, 0]
            band = np.abs(y_rows) <= r
            if not band.any():
                continue
            front = _profile(lens, i, y_rows[band])
            back = _profile(lens, i + 1, y_rows[band])
            inside = (zc[band] <= front[:, None]) & (zc[band] >= back[:, None])
            sub = cv.img[band]
            sub[inside] = _GLASS
            cv.img[band] = sub
    # surface outlines
    for i, s in enumerate(lens.surfaces):
        if s.stop:
            zs = float(vz[i])
            top = max(1.35 * s.semi_diameter_mm, s.semi_diameter_mm + 0.04 * y_half)
            cv.polyline([zs, zs], [s.semi_diameter_mm, top], _STOP, radius=1)
            cv.polyline([zs, zs], [-s.semi_diameter_mm, -top], _STOP, radius=1)
            continue
        ys = np.linspace(-sds[i], sds[i], 96)
        cv.polyline(_profile(lens, i, ys), ys, _EDGE)
    # ray fans from the scene to the sensor
    try:
        hf = half_field_deg(lens)
    except Exception:  # noqa: BLE001 - a lens without paraxial data still gets a drawing
        hf = 0.0
    for frac, colour in zip(fields, _FANS):
        field = frac * hf * (0.98 if frac == 1.0 else 1.0)
        fan = fan_paths(lens, field, 161, rays_per_fan, sensor_z, threads=1)
        if fan is None:
            continue
        zz, yy = fan
        for k in range(zz.shape[1]):
            cv.polyline(zz[:, k], yy[:, k], colour)
    # the sensor
    cv.polyline([sensor_z, sensor_z], [-0.8 * y_half, 0.8 * y_half], _SENSOR, radius=1)
    return np.clip(cv.img, 0.0, 1.0)


def png_bytes(rgba: np.ndarray) -> bytes:
    """An 8-bit RGBA PNG of an (H, W, 4) float image in [0, 1] (row 0 at the top)."""
    img = np.asarray(rgba, dtype=np.float64)
    if img.ndim != 3 or img.shape[2] != 4:
        raise ValueError(f"expected an (H, W, 4) RGBA image, got shape {img.shape}")
    h, w = img.shape[:2]
    data = np.rint(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)
    raw = b"".join(b"\x00" + data[r].tobytes() for r in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))

    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 6))
            + chunk(b"IEND", b""))


def write_png(path, rgba: np.ndarray) -> None:
    """Write `rgba` as a PNG atomically (core.atomic: a temporary file renamed into place)."""
    from .atomic import atomic_write_bytes
    atomic_write_bytes(path, png_bytes(rgba))
