"""Checks of core.stmap that tests and the benchmark share: chief rays solved independently
(in two dimensions, at any azimuth), and the round trip of the two maps sampled as a
compositor samples them."""

from __future__ import annotations

import math

import numpy as np

from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace


def _aim_at_stop_centre(at_stop, k, steps=20, h=1e-5):
    """Aims (a_x, a_y) (k,) from 0 that bring at_stop(a_x, a_y) (where the rays cross the
    stop surface, (3, k)) to the stop's centre: Newton's method with a forward-difference
    2 x 2 Jacobian (rays that miss stay unfound: their aims go nan)."""
    ax, ay = np.zeros(k), np.zeros(k)
    with np.errstate(invalid="ignore", divide="ignore"):
        for _ in range(steps):
            p = at_stop(ax, ay)
            px, py = at_stop(ax + h, ay), at_stop(ax, ay + h)
            j11, j21 = (px[0] - p[0]) / h, (px[1] - p[1]) / h
            j12, j22 = (py[0] - p[0]) / h, (py[1] - p[1]) / h
            det = j11 * j22 - j12 * j21
            ax = ax - (j22 * p[0] - j12 * p[1]) / det
            ay = ay - (-j21 * p[0] + j11 * p[1]) / det
    return ax, ay


def chief_direction(lens, sensor_z, fx, fy, wavelength_nm=587.5618):
    """The scene-side direction (3, N) of the chief ray from lens-space film points (fx, fy):
    its aim on the paraxial exit pupil's plane, from its centre, solved in x and y by Newton's
    method (a 2 x 2 finite-difference Jacobian), so that it crosses the stop surface at its
    centre (to 1e-8 mm, asserted), and whether it was found ((N,) bool)."""
    k = fx.size
    n, stop = len(lens.surfaces), lens.stop_index
    z_a = paraxial_data(lens).exit_pupil.z_mm

    def traced(ax, ay, surfaces=(stop, n)):
        o = np.stack([fx, fy, np.full(k, sensor_z)])
        d = np.stack([ax - fx, ay - fy, np.full(k, z_a - sensor_z)])
        d /= np.linalg.norm(d, axis=0)
        return trace(lens, Rays(o, d, np.full(k, float(wavelength_nm))), from_sensor=True,
                     surfaces=surfaces, stop_radius=math.inf)

    ax, ay = _aim_at_stop_centre(lambda bx, by: traced(bx, by).rays.o, k)
    stop = traced(ax, ay)
    res = traced(ax, ay, surfaces=None)
    # where the start (the exit pupil's centre) misses the lens far off axis, Newton cannot
    # begin: those points are not checked (False)
    ok = res.valid & stop.valid
    assert np.abs(stop.rays.o[:2, ok]).max(initial=0.0) < 1e-8
    return res.rays.d, ok


def _imaged_pixels(frame, rgba, n, seed):
    """(columns, rows, image x, image y (mm from the centre)) of n random pixels of a map,
    those the lens images."""
    rng = np.random.default_rng(seed)
    i, j = rng.integers(0, frame.width_px, n), rng.integers(0, frame.height_px, n)
    keep = rgba[j, i, 2] == 1.0
    i, j = i[keep], j[keep]
    x = ((i + 0.5) / frame.width_px - 0.5) * frame.sensor_width_mm
    y = ((j + 0.5) / frame.height_px - 0.5) * frame.sensor_height_mm
    return i, j, x, y


def distort_error_px(table, frame, rgba, n=300, seed=1):
    """(the largest distance (lens-image pixels) between the pinhole point the distort map
    `rgba` samples at n random pixels and where their chief ray (chief_direction) points,
    how many were checked: those the lens images and the independent solve found)."""
    i, j, x, y = _imaged_pixels(frame, rgba, n, seed)
    from neurolens_addon.core.stmap import MAX_FIELD_DEG
    d, found = chief_direction(table.lens, table.sensor_z, -x, -y)   # image (x, y): film (-x, -y)
    tan = np.hypot(d[0], d[1]) / np.where(found, d[2], 1.0)
    ok = found & (tan < math.tan(math.radians(MAX_FIELD_DEG)))
    az = np.maximum(np.hypot(d[0], d[1]), 1e-300)
    px, py = table.f_p_mm * tan * d[0] / az, table.f_p_mm * tan * d[1] / az
    w, h = frame.pinhole_mm
    got = np.hypot((rgba[j, i, 0] - 0.5) * w - px, (rgba[j, i, 1] - 0.5) * h - py)
    return float(np.max(got[ok]) / (frame.sensor_width_mm / frame.width_px)), int(ok.sum())


def round_trip_px(frame, undistort, distort):
    """(largest error in pinhole pixels, share of pinhole pixels checked): each pixel of the
    pinhole image through the undistort map to the lens's image, and back through the
    distort map sampled bilinearly there (as an STMap node reads it), where the lens images
    all four of the pixels sampled."""
    pw, ph = frame.pinhole_px
    jj, ii = np.mgrid[0:ph, 0:pw]
    u = undistort[..., 0] * frame.width_px - 0.5
    v = undistort[..., 1] * frame.height_px - 0.5
    inside = (undistort[..., 2] == 1) & (u >= 0) & (v >= 0) & (u <= frame.width_px - 1) & (
        v <= frame.height_px - 1)
    u, v, ii, jj = u[inside], v[inside], ii[inside], jj[inside]
    i0 = np.minimum(u.astype(int), frame.width_px - 2)
    j0 = np.minimum(v.astype(int), frame.height_px - 2)
    a, b = (u - i0)[:, None], (v - j0)[:, None]
    c = [distort[j0, i0], distort[j0, i0 + 1], distort[j0 + 1, i0], distort[j0 + 1, i0 + 1]]
    # a point whose four neighbours the lens does not all image (the image circle's edge)
    # cannot be sampled back
    whole = np.all([q[..., 2] == 1 for q in c], axis=0)
    back = ((1 - a) * (1 - b) * c[0][:, :2] + a * (1 - b) * c[1][:, :2]
            + (1 - a) * b * c[2][:, :2] + a * b * c[3][:, :2])
    err = np.hypot(back[:, 0] * pw - 0.5 - ii, back[:, 1] * ph - 0.5 - jj)[whole]
    return (float(err.max()) if err.size else math.nan,
            float(whole.sum()) / float(inside.size))


def scene_point_image(lens, sensor_z, points, wavelength_nm=587.5618):
    """Where the chief ray from lens-space scene points (3, N) mm lands on the film, as image
    points (p, q) mm (the film point turned back: the read-out's 180 degrees), and whether it
    was found ((N,) bool): solved from the scene side, independently of core.projection's
    table: the ray from the point aimed at (a_x, a_y) on the paraxial entrance pupil's plane,
    traced to the stop surface, its aim corrected by Newton's method (2 x 2 finite-difference
    Jacobian) until it crosses the stop at its centre (1e-8 mm), then traced to the sensor."""
    points = np.asarray(points, dtype=np.float64)
    k = points.shape[1]
    stop = lens.stop_index
    z_e = paraxial_data(lens).entrance_pupil.z_mm

    def traced(ax, ay, to_stop=True):
        d = np.stack([ax - points[0], ay - points[1], z_e - points[2]])
        d /= np.linalg.norm(d, axis=0)
        kw = dict(surfaces=(0, stop + 1), sensor_z=None) if to_stop else dict(sensor_z=sensor_z)
        return trace(lens, Rays(points.copy(), d, np.full(k, float(wavelength_nm))),
                     from_sensor=False, stop_radius=math.inf, **kw)

    ax, ay = _aim_at_stop_centre(lambda bx, by: traced(bx, by).rays.o, k)
    at_stop = traced(ax, ay)
    res = traced(ax, ay, to_stop=False)
    ok = res.valid & at_stop.valid & (np.hypot(*at_stop.rays.o[:2]) < 1e-8)
    return -res.rays.o[0], -res.rays.o[1], ok


def grid_distort_error_px(lens, grid, frame, rgba, n=300, seed=1):
    """distort_error_px for an anamorphic lens's map (core.chief_grid): the pinhole point the
    map samples at n random pixels of the desqueezed lens image against the chief ray solved
    in 2-D at the pixel's film point (x / S, y turned), through the grid's pinhole
    (S f_x s, f_y t); in lens-image pixels, and how many were checked."""
    i, j, x, y = _imaged_pixels(frame, rgba, n, seed)
    d, found = chief_direction(lens, grid.sensor_z, -x / grid.squeeze, -y)
    dz = np.where(found, d[2], 1.0)
    px, py = grid.squeeze * grid.f_x_mm * d[0] / dz, grid.f_y_mm * d[1] / dz
    w, h = frame.pinhole_mm
    got = np.hypot((rgba[j, i, 0] - 0.5) * w - px, (rgba[j, i, 1] - 0.5) * h - py)
    return float(np.max(got[found]) / (frame.sensor_width_mm / frame.width_px)), int(found.sum())
