"""ST-maps of a lens's distortion (Nuke's STMap convention): where each pixel of one image
samples another, between the lens's image and an ideal pinhole's, for matching CG to a plate.

Chief ray. From a film point at radius r (lens space, on +x, on the focused sensor plane z_s),
the chief ray passes the centre of the stop: aimed at the point (a, 0) of the paraxial exit
pupil's plane z_a, a solves x_stop(a) = 0 (x_stop: where the ray crosses the stop surface,
traced through the surfaces behind it), by Newton's method with a secant derivative, every
radius at once. Traced on through the lens it leaves at the field angle
    theta(r) = atan2(sqrt(d_x^2 + d_y^2), d_z)
of its scene-side direction d (towards -x: the image is inverted, and the read-out turns it
back, so an image point and its scene direction share their azimuth). A lens of revolution
maps every azimuth alike: the table theta_k = theta(r_k) over TABLE_RADII radii from 0 to
the largest film radius asked is the whole mapping, interpolated linearly both ways between
r and theta (the pinhole's tan(theta) taken of the interpolated angle). The radii are solved
outwards from the axis in blocks, each block's Newton started from a quadratic through the
aims of the two blocks before it. It ends
where theta stops rising, reaches MAX_FIELD_DEG (a pinhole images nothing at 90 degrees), or
the chief ray no longer passes: beyond, the lens images nothing the map can place.
The table also keeps where each chief ray's scene-side line meets the axis,
    z_c(r) = o_z - o_x d_z / d_x   (o the ray at the front surface),
the entrance pupil as seen from that field (core.projection places scene points with it).

Pinhole. The undistorted image is the ideal pinhole that agrees with the lens at the centre:
    rho = f_p tan(theta),   f_p = lim r / tan(theta(r)) as r -> 0
(the paraxial focal length at that focus: a lens focused near images at its image distance),
read from the table's first radius, r_1 = FIRST_RADIUS x the largest.

Images. The lens's image covers the sensor, w x h mm, in W x H pixels; the pinhole's covers
F w x F h mm in round(F W) x round(F H) pixels (F the overscan, >= 1: a CG render with the
border the distortion needs). A pixel (i, j) (i from the left edge, j from the bottom, centres
at i + 0.5) of an image of P x Q pixels over p x q mm lies at
    (x, y) = (((i + 0.5) / P - 0.5) p, ((j + 0.5) / Q - 0.5) q)   mm from its centre,
and a point (x, y) of the source image (s x t mm) has the map's values
    R = x / s + 0.5,   G = y / t + 0.5
(Nuke's STMap: x / width from the left, y / height from the bottom). The map's pixel and its
source point share their azimuth; their radii are r (lens) and rho (pinhole):
    undistort   output the pinhole image, source the lens's: r = r(rho) (the table inverted)
    distort     output the lens's image, source the pinhole's: rho = f_p tan(theta(r))
A pixel the lens does not image (beyond the table) gets R = G = INVALID (outside [0, 1], so
an STMap node reads nothing there) and A = 0; every other pixel A = 1 (its R, G may lie
outside [0, 1] too: a source point beyond the source image's edge). Nothing is NaN.

The overscan a frame needs (needed_overscan): the largest |x| / (w / 2), |y| / (h / 2) of the
pinhole points the lens image's border pixels sample, at least 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .aimed_rays import aim_plane_z, trace_aimed
from .errors import LensError
from .prescription import WAVELENGTH_D_NM, Lens

#: radii of the chief-ray table
TABLE_RADII = 4096
#: the table's first radius (for f_p), as a fraction of the largest
FIRST_RADIUS = 1e-4
#: the largest field angle the table holds (a pinhole's image of 90 degrees is infinite)
MAX_FIELD_DEG = 89.0
#: radii solved together, outwards from the axis, each block started from the last ones
CONTINUATION_BLOCK = 256
#: Newton iterations of the chief-ray aim, and the secant step (mm)
NEWTON_STEPS = 12
SECANT_MM = 1e-4
#: R and G of a pixel the lens does not image
INVALID = -1.0
DIRECTIONS = ("undistort", "distort")
#: how far beyond the pinhole image a chief-ray grid (an anamorphic lens) reaches
GRID_MARGIN = 1.15
#: an anamorphic lens's map over more pixels than this is solved every LATTICE_PX-th pixel
#: and interpolated between (core.stmap._grid_map)
LATTICE_MIN_PX = 1 << 20
LATTICE_PX = 4


@dataclass(frozen=True)
class ChiefRayTable:
    """The chief ray's mapping of a lens of revolution at one focus and wavelength."""

    r_mm: np.ndarray            # (K,) film radii, rising from 0
    theta: np.ndarray           # (K,) field angles (radians), rising
    f_p_mm: float               # the pinhole's focal length
    lens: Lens = None           # the lens as it stands, and its sensor plane (for checks)
    sensor_z: float = 0.0
    axis_z: np.ndarray | None = None   # (K,) where each chief ray's scene-side line meets the
                                       # axis (lens space, mm): core.projection's pupil

    @property
    def rho_mm(self) -> np.ndarray:
        """The pinhole image's radii of the table's field angles."""
        return self.f_p_mm * np.tan(self.theta)

    @property
    def r_max(self) -> float:
        return float(self.r_mm[-1])

    def pinhole_of_lens(self, r: np.ndarray) -> np.ndarray:
        """rho of lens-image radii r (nan beyond the table): theta interpolated, its tangent
        taken (tan's steepness near 90 degrees is the mapping's own, not the table's)."""
        rho = self.f_p_mm * np.tan(np.interp(r, self.r_mm, self.theta))
        return np.where(r <= self.r_max, rho, np.nan)

    def lens_of_pinhole(self, rho: np.ndarray) -> np.ndarray:
        """r of pinhole-image radii rho (nan beyond the table)."""
        theta = np.arctan(rho / self.f_p_mm)
        r = np.interp(theta, self.theta, self.r_mm)
        return np.where(theta <= self.theta[-1], r, np.nan)


def _chief_aims(lens: Lens, radii: np.ndarray, sensor_z: float, wavelength_nm: float):
    """(aim x on the plane z_a, z_a, passes (K,)) of the chief rays from film radii (module
    docstring)."""
    z_a = aim_plane_z(lens, sensor_z)
    stop, n = lens.stop_index, len(lens.surfaces)
    k = radii.size

    def x_stop(a, sel):
        r, zero = radii[sel], np.zeros(sel.size)
        res = trace_aimed(lens, r, zero, a, zero, sensor_z, z_a, wavelength_nm, (stop, n))
        return np.where(res.valid, res.rays.o[0], np.nan)

    def newton(sel, a):
        for _ in range(NEWTON_STEPS):
            g = x_stop(a, sel)
            slope = (x_stop(a + SECANT_MM, sel) - g) / SECANT_MM
            step = np.where(np.isfinite(g) & np.isfinite(slope) & (np.abs(slope) > 1e-12),
                            g / np.where(np.abs(slope) > 1e-12, slope, 1.0), 0.0)
            a = a - step
            if np.nanmax(np.abs(g), initial=0.0) < 1e-10:
                break
        return a

    # outwards from the axis in blocks, each started where the blocks before it point (the
    # aim moves smoothly with the radius; the exit pupil's centre, right near the axis, can
    # miss the lens far off it)
    a = np.zeros(k)
    for start in range(0, k, CONTINUATION_BLOCK):
        sel = np.arange(start, min(start + CONTINUATION_BLOCK, k))
        if start >= 2 * CONTINUATION_BLOCK:
            done = np.arange(start - 2 * CONTINUATION_BLOCK, start)
            coef = np.polyfit(radii[done], a[done], 2)
            a[sel] = np.polyval(coef, radii[sel])
        a[sel] = newton(sel, a[sel])
    g = x_stop(a, np.arange(k))
    return a, z_a, np.isfinite(g) & (np.abs(np.nan_to_num(g, nan=1.0)) < 1e-6)


def chief_ray_table(lens: Lens, sensor_z: float, film_radius_mm: float, *,
                    wavelength_nm: float = WAVELENGTH_D_NM) -> ChiefRayTable:
    """The chief-ray table of a lens of revolution out to `film_radius_mm` (module
    docstring). LensError for an anamorphic lens (its mapping is not radial) or a lens whose
    chief rays do not pass near the axis."""
    if lens.anamorphic:
        raise LensError(f"lens '{lens.name}': the radial chief-ray table is for lenses of "
                        "revolution; an anamorphic lens's mapping differs along x and y (its "
                        "chief rays: core.chief_grid)", path=lens.path)
    r_max = float(film_radius_mm)
    radii = np.concatenate([[FIRST_RADIUS * r_max],
                            np.linspace(0.0, r_max, TABLE_RADII)[1:]])
    a, z_a, ok = _chief_aims(lens, radii, sensor_z, wavelength_nm)
    k = radii.size
    zero = np.zeros(k)
    res = trace_aimed(lens, radii, zero, a, zero, sensor_z, z_a, wavelength_nm)
    ok &= res.valid
    out = res.rays.d
    theta = np.arctan2(np.hypot(out[0], out[1]), out[2])
    towards = out[0] <= 0.0                  # the image is inverted: +x film looks to -x
    ok &= towards & (theta < math.radians(MAX_FIELD_DEG))
    if not ok[0]:
        raise LensError(f"lens '{lens.name}': no chief ray passes near the axis at sensor z "
                        f"{sensor_z:g} mm", path=lens.path)
    f_p = float(radii[0] / math.tan(theta[0]))
    # the scene-side line x = o_x + (z - o_z) d_x / d_z meets the axis at z = o_z - o_x d_z / d_x
    # (the first radius's, a paraxial ray's, stands for the axis: the entrance pupil)
    o = res.rays.o
    with np.errstate(divide="ignore", invalid="ignore"):
        axis_z = o[2] - o[0] * out[2] / out[0]
    # the table: from the axis while the chief ray passes and theta rises
    r_tab = np.concatenate([[0.0], radii[1:]])
    t_tab = np.concatenate([[0.0], theta[1:]])
    good = np.concatenate([[True], ok[1:]])
    rising = np.concatenate([[True], np.diff(t_tab) > 0.0])
    end = np.flatnonzero(~(good & rising))
    last = int(end[0]) if end.size else k
    if last < 2:
        raise LensError(f"lens '{lens.name}': the chief ray passes only on the axis",
                        path=lens.path)
    return ChiefRayTable(r_tab[:last].copy(), t_tab[:last].copy(), f_p, lens, float(sensor_z),
                         axis_z[:last].copy())


def chief_mapping(lens: Lens, sensor_z: float, frame: "MapFrame", *, squeeze: float | None = None,
                  wavelength_nm: float = WAVELENGTH_D_NM):
    """The chief-ray mapping a frame's maps need: the radial table of a lens of revolution,
    or for an anamorphic lens its grid (core.chief_grid) over the frame, desqueezed by
    `squeeze` (None: the lens's own, core.paraxial.squeeze)."""
    if not lens.anamorphic:
        return chief_ray_table(lens, sensor_z, frame.film_radius_mm, wavelength_nm=wavelength_nm)
    from .chief_grid import chief_ray_grid
    from .paraxial import squeeze as lens_squeeze
    k = float(squeeze) if squeeze else float(lens_squeeze(lens))
    hx, hy = frame.half_extent_mm
    return chief_ray_grid(lens, sensor_z, hx / k, hy, squeeze=k, wavelength_nm=wavelength_nm)


@dataclass(frozen=True)
class MapFrame:
    """The lens image's sensor and pixels, and the pinhole image's overscan."""

    width_px: int
    height_px: int
    sensor_width_mm: float
    overscan: float = 1.0

    @classmethod
    def checked(cls, width_px, height_px, sensor_width_mm, overscan=1.0) -> "MapFrame":
        """A frame from command-line values, ValueError (one line) for one that is none."""
        if not (isinstance(width_px, int) and isinstance(height_px, int)
                and 0 < width_px <= 65536 and 0 < height_px <= 65536):
            raise ValueError(f"resolution {width_px}x{height_px}: expected 1 to 65536 pixels "
                             "each way")
        if not (math.isfinite(sensor_width_mm) and sensor_width_mm > 0):
            raise ValueError(f"sensor width {sensor_width_mm!r} mm: expected a positive number")
        if not (math.isfinite(overscan) and 1.0 <= overscan <= 4.0):
            raise ValueError(f"overscan {overscan!r}: expected a number from 1 to 4")
        return cls(int(width_px), int(height_px), float(sensor_width_mm), float(overscan))

    @property
    def sensor_height_mm(self) -> float:
        return self.sensor_width_mm * self.height_px / self.width_px

    @property
    def pinhole_px(self) -> tuple[int, int]:
        return (max(1, round(self.overscan * self.width_px)),
                max(1, round(self.overscan * self.height_px)))

    @property
    def pinhole_mm(self) -> tuple[float, float]:
        """The pinhole image's extent: its pixels at the lens image's pixel size."""
        pw, ph = self.pinhole_px
        return (self.sensor_width_mm * pw / self.width_px,
                self.sensor_height_mm * ph / self.height_px)

    @property
    def half_extent_mm(self) -> tuple[float, float]:
        """The largest half-width and half-height (desqueezed mm) either map can ask for
        along x and y: the pinhole image's, grown for a lens that images its corners beyond
        them (pincushion)."""
        w, h = self.pinhole_mm
        return 0.5 * w * GRID_MARGIN, 0.5 * h * GRID_MARGIN

    @property
    def film_radius_mm(self) -> float:
        """The largest lens-image radius either map can ask for: the pinhole's corner's
        mapped back can lie beyond the sensor's corner, so the table reaches its overscan."""
        return 0.5 * math.hypot(*self.pinhole_mm) * 1.02


def _centres(n: int, size_mm: float) -> np.ndarray:
    """The pixel centres' coordinates (mm from the image's centre) along one axis."""
    return ((np.arange(n) + 0.5) / n - 0.5) * size_mm


def _mirror_index(n: int) -> np.ndarray:
    """For each of n pixel centres, the index of its distance from the centre among the
    centres of the upper half (n // 2 onwards): the grid is symmetric about its centre."""
    i = np.arange(n)
    return np.where(i >= n // 2, i - n // 2, (n - 1 - i) - n // 2)


def st_map(table: ChiefRayTable, frame: MapFrame, direction: str) -> np.ndarray:
    """The map (rows from the bottom, (Q, P, 3) float32: R, G, A) of `direction` (module
    docstring).
    The source's radius over the pixel's depends on the pixel's distance from the centre
    alone, so it is computed over one quadrant and mirrored."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {', '.join(DIRECTIONS)}, got "
                         f"{direction!r}")
    if not isinstance(table, ChiefRayTable):          # an anamorphic lens's grid
        return _grid_map(table, frame, direction)
    lens_mm = (frame.sensor_width_mm, frame.sensor_height_mm)
    if direction == "undistort":
        out_px, out_mm, src_mm = frame.pinhole_px, frame.pinhole_mm, lens_mm
    else:
        out_px, out_mm, src_mm = (frame.width_px, frame.height_px), lens_mm, frame.pinhole_mm
    xs, ys = _centres(out_px[0], out_mm[0]), _centres(out_px[1], out_mm[1])
    qx, qy = np.abs(xs[out_px[0] // 2:]), np.abs(ys[out_px[1] // 2:])
    radius = np.hypot(qx[None, :], qy[:, None])
    src = (table.lens_of_pinhole(radius) if direction == "undistort"
           else table.pinhole_of_lens(radius))
    ok = np.isfinite(src)
    # the source point on the pixel's azimuth (the centre pixel's source is the centre)
    scale = np.where(ok & (radius > 0), src / np.where(radius > 0, radius, 1.0), 1.0)
    # in float32, as the EXR stores the map (1e-7 of the source's size: 4e-4 px at 4K)
    rows, cols = _mirror_index(out_px[1]), _mirror_index(out_px[0])
    scale = np.where(ok, scale, np.nan).astype(np.float32)[rows][:, cols]
    out = np.empty((out_px[1], out_px[0], 3), dtype=np.float32)
    np.multiply(scale, (xs / src_mm[0]).astype(np.float32)[None, :], out=out[..., 0])
    np.multiply(scale, (ys / src_mm[1]).astype(np.float32)[:, None], out=out[..., 1])
    out[..., :2] += np.float32(0.5)
    bad = np.isnan(scale)
    out[..., 0][bad] = INVALID
    out[..., 1][bad] = INVALID
    out[..., 2] = ~bad
    return out


def _grid_map(grid, frame: MapFrame, direction: str, lattice: int | None = None) -> np.ndarray:
    """st_map of a chief-ray grid (core.chief_grid): each pixel's source point in 2-D. On a
    frame larger than LATTICE_MIN_PX pixels the source points are solved exactly at every
    LATTICE_PX-th pixel (and the last) and interpolated bilinearly between them (the mapping is
    smooth: within 0.01 px of the map solved at every pixel, tests/core/test_chief_grid.py); a
    pixel whose four lattice points are not all imaged is solved on its own."""
    lens_mm = (frame.sensor_width_mm, frame.sensor_height_mm)
    if direction == "undistort":
        out_px, out_mm, src_mm = frame.pinhole_px, frame.pinhole_mm, lens_mm
    else:
        out_px, out_mm, src_mm = (frame.width_px, frame.height_px), lens_mm, frame.pinhole_mm
    to = grid.lens_of_pinhole if direction == "undistort" else grid.pinhole_of_lens
    xs, ys = _centres(out_px[0], out_mm[0]), _centres(out_px[1], out_mm[1])
    if lattice is None:
        lattice = LATTICE_PX if out_px[0] * out_px[1] > LATTICE_MIN_PX else 1
    src = np.empty((out_px[1], out_px[0], 2))
    ok = np.empty((out_px[1], out_px[0]), bool)
    if lattice <= 1:
        px, py = np.meshgrid(xs, ys)
        sx, sy, good = to(px.ravel(), py.ravel())
        src[..., 0], src[..., 1] = sx.reshape(px.shape), sy.reshape(px.shape)
        ok[:] = good.reshape(px.shape)
    else:
        ix = np.unique(np.r_[np.arange(0, out_px[0], lattice), out_px[0] - 1])
        iy = np.unique(np.r_[np.arange(0, out_px[1], lattice), out_px[1] - 1])
        px, py = np.meshgrid(xs[ix], ys[iy])
        sx, sy, good = to(px.ravel(), py.ravel())
        nodes = np.stack([sx, sy], axis=1).reshape(iy.size, ix.size, 2)
        good = good.reshape(iy.size, ix.size)
        # each pixel's lattice cell and its place in it, along x then along y
        cx = np.clip(np.searchsorted(ix, np.arange(out_px[0]), side="right") - 1, 0,
                     ix.size - 2)
        cy = np.clip(np.searchsorted(iy, np.arange(out_px[1]), side="right") - 1, 0,
                     iy.size - 2)
        a = ((np.arange(out_px[0]) - ix[cx]) / (ix[cx + 1] - ix[cx]))[None, :, None]
        b = ((np.arange(out_px[1]) - iy[cy]) / (iy[cy + 1] - iy[cy]))[:, None, None]
        along_x = nodes[:, cx] * (1.0 - a) + nodes[:, cx + 1] * a
        src[:] = along_x[cy] * (1.0 - b) + along_x[cy + 1] * b
        gx = good[:, cx] & good[:, cx + 1]
        ok[:] = gx[cy] & gx[cy + 1]
        alone = np.flatnonzero(~ok.ravel())
        if alone.size:                    # the image's edge: those pixels solved exactly
            j, i = np.divmod(alone, out_px[0])
            sx, sy, good = to(xs[i], ys[j])
            flat = src.reshape(-1, 2)
            flat[alone, 0], flat[alone, 1] = sx, sy
            ok.ravel()[alone] = good
    out = np.empty((out_px[1], out_px[0], 3), dtype=np.float32)
    out[..., 0] = np.where(ok, src[..., 0] / src_mm[0] + 0.5, INVALID)
    out[..., 1] = np.where(ok, src[..., 1] / src_mm[1] + 0.5, INVALID)
    out[..., 2] = ok
    return out


def _border_points(frame: MapFrame):
    """The centres (mm) of the lens image's border pixels."""
    px, py = frame.width_px, frame.height_px
    xs, ys = _centres(px, frame.sensor_width_mm), _centres(py, frame.sensor_height_mm)
    return (np.concatenate([xs, xs, np.full(py, xs[0]), np.full(py, xs[-1])]),
            np.concatenate([np.full(px, ys[0]), np.full(px, ys[-1]), ys, ys]))


def needed_overscan(table: ChiefRayTable, frame: MapFrame) -> float:
    """The overscan F the pinhole image needs for the distort map to find every border pixel
    of the lens's image (module docstring): at least 1; inf where a border pixel is beyond
    what the lens images."""
    w, h = frame.sensor_width_mm, frame.sensor_height_mm
    px = frame.width_px
    bx, by = _border_points(frame)
    if isinstance(table, ChiefRayTable):
        r = np.hypot(bx, by)
        rho = table.pinhole_of_lens(r)
        if not np.isfinite(rho).all():
            return math.inf
        s = rho / np.maximum(r, 1e-300)
        big_x, big_y = bx * s, by * s
    else:                                              # an anamorphic lens's grid
        big_x, big_y, ok = table.pinhole_of_lens(bx, by)
        if not ok.all():
            return math.inf
    need = max(float(np.max(np.abs(big_x)) / (0.5 * w)),
               float(np.max(np.abs(big_y)) / (0.5 * h)))
    # the border pixels' centres lie half a pixel inside the edges
    return max(1.0, need * px / (px - 1.0))


def lens_at_setting(lens: Lens, *, focus_mm: float = math.inf, zoom_mm: float | None = None,
                    wavelength_nm: float = WAVELENGTH_D_NM, film_radius_mm: float,
                    frame: "MapFrame | None" = None):
    """(the lens as it stands, its sensor plane, its chief-ray mapping) at a focus distance
    (from the sensor) and a zoom lens's focal length: zoom and focusing groups moved
    (core.variable_gaps), the sensor at the exact focus (core.focus). The mapping: the radial
    table out to film_radius_mm, or an anamorphic lens's grid over `frame` (chief_mapping;
    desqueezed by its squeeze at infinity, as the renderers desqueeze)."""
    from .focus import focus_sensor_z
    from .variable_gaps import focus_position, lens_at, zoom_position
    if not (math.isfinite(wavelength_nm) and 300.0 <= wavelength_nm <= 1100.0):
        raise ValueError(f"wavelength {wavelength_nm!r} nm: expected 300 to 1100")
    if not focus_mm > 0:
        raise ValueError(f"focus {focus_mm / 1000.0!r} m: expected a positive distance")
    zoom = None
    if zoom_mm is not None:
        if lens.zoom_gaps is None:
            raise LensError(f"lens '{lens.name}' does not zoom: --zoom does not apply",
                            path=lens.path)
        zoom = zoom_position(lens, float(zoom_mm))
        lens = lens_at(lens, zoom=zoom)
    nominal = None
    if lens.anamorphic:
        from .paraxial import squeeze
        nominal = float(squeeze(lens))
    if lens.focus_gaps is not None:
        group = focus_position(lens, float(focus_mm))
        if group:
            lens = lens_at(lens, focus=group)
    sensor_z = float(focus_sensor_z(lens, float(focus_mm)))
    if lens.anamorphic:
        if frame is None:
            frame = MapFrame(1, 1, 2.0 * film_radius_mm / math.sqrt(2.0))
        return lens, sensor_z, chief_mapping(lens, sensor_z, frame, squeeze=nominal,
                                             wavelength_nm=wavelength_nm)
    table = chief_ray_table(lens, sensor_z, film_radius_mm, wavelength_nm=wavelength_nm)
    return lens, sensor_z, table


def lens_metadata(lens: Lens, table: ChiefRayTable, frame: MapFrame, *, focus_mm: float,
                  sensor_z: float, wavelength_nm: float) -> dict:
    """What a match-mover needs of the lens at this setting (the JSON sidecar of a map): its
    focal lengths, focus, design f-number, entrance pupil (the camera's centre of
    perspective) from the sensor, sensor, and the standard distortion models fitted to its
    chief ray (core.distortion_fit) with their residuals."""
    from .distortion_fit import fitted_models
    if getattr(lens, "table", False):
        # a lens known only from a ray table (camera.table_lens) has no prescription: its
        # focal length and f-number are those measured from its model (the pinhole that
        # frames alike, the working f-number), its entrance pupil where its chief rays meet
        # the axis
        efl, f_number = float(lens.focal_length_mm), float(lens.f_number)
        pupil_z = float(table.axis_z[0])
    else:
        from .paraxial import paraxial_data
        par = paraxial_data(lens, wavelength_nm=wavelength_nm)
        efl, f_number = float(par.efl_mm), float(lens.f_number)
        pupil_z = float(par.entrance_pupil.z_mm)
    if isinstance(table, ChiefRayTable):
        pinhole = {"pinhole_focal_length_mm": table.f_p_mm}
        distortion = fitted_models(table, frame)
    else:                       # anamorphic: two focal lengths, no radial model holds it
        from .distortion_fit import tde4_anamorphic
        pinhole = {"pinhole_focal_length_mm": table.f_y_mm,
                   "pinhole_focal_length_x_mm": table.squeeze * table.f_x_mm,
                   "pinhole_focal_length_y_mm": table.f_y_mm, "squeeze": table.squeeze}
        distortion = {"note": "anamorphic: the mapping differs along x and y, which the "
                              "radial models cannot hold; 3DE's anamorphic model gives each "
                              "axis its own terms, and the ST-maps carry the mapping"}
        fit = tde4_anamorphic(table, frame)
        if fit is not None:
            distortion["tde4_anamorphic_standard_degree_4"] = fit
    return {"lens": lens.name, "lens_file": lens.path,
            "paraxial_focal_length_mm": efl,
            **pinhole,
            "focus_distance_mm": focus_mm if math.isfinite(focus_mm) else None,
            "design_f_number": f_number,
            "entrance_pupil_from_sensor_mm": pupil_z - sensor_z,
            "sensor_mm": [frame.sensor_width_mm, frame.sensor_height_mm],
            "resolution_px": [frame.width_px, frame.height_px],
            "wavelength_nm": wavelength_nm,
            "overscan_needed": needed_overscan(table, frame),
            "distortion": distortion}


def map_header(meta: dict, frame: MapFrame, direction: str, sensor_z: float) -> dict:
    """The lens data an ST-map's EXR header carries (strings and numbers), from its
    lens_metadata: the lens, the convention, the pinhole, focus, sensor, overscan, and the
    fitted models' coefficients with their residuals (OpenCV's Brown-Conrady and 3DE's radial
    model, or for an anamorphic lens 3DE's anamorphic one)."""
    focus = meta["focus_distance_mm"]
    bc = meta["distortion"].get("brown_conrady")
    opencv = {} if bc is None else {
        "neurolens/opencv_k1": bc["k1"], "neurolens/opencv_k2": bc["k2"],
        "neurolens/opencv_k3": bc["k3"], "neurolens/opencv_residual_px": bc["max_residual_px"]}
    tde = meta["distortion"].get("tde4_radial_standard_degree_4")
    if tde is not None:
        opencv.update({"neurolens/3de4_radial_c2": tde["distortion_degree_2"],
                       "neurolens/3de4_radial_c4": tde["quartic_distortion_degree_4"],
                       "neurolens/3de4_radial_residual_px": tde["max_residual_px"]})
    ana = meta["distortion"].get("tde4_anamorphic_standard_degree_4")
    if ana is not None:
        opencv.update({f"neurolens/3de4_anamorphic_{k}": v for k, v in ana.items()
                       if k.startswith(("cx", "cy", "squeeze_", "pixel_aspect"))})
        opencv["neurolens/3de4_anamorphic_residual_px"] = ana["max_residual_px"]
    squeeze = {} if "squeeze" not in meta else {
        "neurolens/squeeze": meta["squeeze"],
        "neurolens/pinhole_focal_length_x_mm": meta["pinhole_focal_length_x_mm"]}
    return {"neurolens/lens": meta["lens"], "neurolens/direction": direction,
            "neurolens/convention": ("Nuke STMap: R = x / width from the left, G = y / height "
                                     f"from the bottom, of the source image; {INVALID:g} where "
                                     "the lens images nothing (A = 0)"),
            "neurolens/pinhole_focal_length_mm": meta["pinhole_focal_length_mm"],
            "neurolens/focus_mm": -1.0 if focus is None else focus,
            "neurolens/sensor_z_mm": sensor_z, "neurolens/wavelength_nm": meta["wavelength_nm"],
            "neurolens/sensor_width_mm": frame.sensor_width_mm,
            "neurolens/sensor_height_mm": frame.sensor_height_mm,
            "neurolens/overscan": frame.overscan,
            "neurolens/overscan_needed": meta["overscan_needed"], **opencv, **squeeze}


def lens_map(lens: Lens, table: ChiefRayTable, frame: MapFrame, direction: str, *,
             focus_mm: float, sensor_z: float, wavelength_nm: float):
    """(map, its EXR header, its lens data) of a lens as it stands: what every writer of a
    map writes (write_map)."""
    meta = lens_metadata(lens, table, frame, focus_mm=focus_mm, sensor_z=sensor_z,
                         wavelength_nm=wavelength_nm)
    return st_map(table, frame, direction), map_header(meta, frame, direction, sensor_z), meta


def write_map(path, rgba: np.ndarray, header: dict, meta: dict) -> None:
    """The map as EXR at `path` (core.exr: whole or not at all) and its lens data beside it
    (PATH.json)."""
    from .atomic import atomic_write_text
    from .exr import write_exr
    from .jsonout import dumps
    write_exr(path, {"R": rgba[..., 0], "G": rgba[..., 1], "A": rgba[..., 2]}, header)
    atomic_write_text(f"{path}.json", dumps(meta, indent=1) + "\n")
