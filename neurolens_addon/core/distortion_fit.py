"""Standard distortion models fitted to a lens's exact chief-ray mapping (core.stmap), for the
match-moving tools that take coefficients rather than maps.

Both are OpenCV's, centred (no tangential terms: a centred lens of revolution has none), in
normalised coordinates: an undistorted point at field angle theta lies at radius t = tan(theta)
and the lens's image at r / f (r the chief ray's radius on the film, f core.stmap's pinhole
focal length, so f_x = f_y = f / pixel pitch in pixels and c_x, c_y the image's centre):
  brown_conrady   (cv::calibrateCamera, k1 k2 k3):  r / f = t (1 + k1 t^2 + k2 t^4 + k3 t^6)
  kannala_brandt  (cv::fisheye, k1..k4):  r / f = theta (1 + k1 theta^2 + k2 theta^4
                                                        + k3 theta^6 + k4 theta^8)
Each is fitted by linear least squares in r over the chief-ray table's radii within the
frame's corner (uniform in r), and carries its largest residual over them in pixels: where
the residual is large (Brown-Conrady on a fisheye), the model cannot hold the lens.

3DEqualizer's "3DE4 Radial - Standard, Degree 4", centred (its decentering U, V and
cylindric Phi, B terms 0: a centred lens of revolution has none), at the pinhole focal length
f: its coefficients undistort a distorted image (as 3DE's models do; Unreal's
CameraCalibrationCore documents the same for 3DE's anamorphic model), in 3DE's diagonally
normalised coordinates (mm from the lens's centre over half the filmback's diagonal, d):
    rho / d = (r / d) (1 + c2 (r / d)^2 + c4 (r / d)^4),   rho = f tan(theta)
(c2 "Distortion - Degree 2", c4 "Quartic Distortion - Degree 4"), fitted by linear least
squares in rho over the same radii; its residual is in the undistorted image's pixels.

An anamorphic lens (core.chief_grid) has no radial mapping (one radial term common to both
axes, even with OpenCV's two focal lengths, misses the 2x anamorphic's by 19 px at 1920 px
across): 3DEqualizer's "3DE4 Anamorphic - Standard, Degree 4" gives each axis its own
coefficients. In LDPK's form (tde4_ldp_anamorphic_standard_degree_4: the anamorphic
polynomial between the lens rotation, squeeze and pixel aspect extenders; Unreal's
CameraCalibrationCore documents the same parameters), with the lens rotation 0, a point p in
diagonally normalised coordinates (mm on the desqueezed filmback, F_w x F_h with
F_w / F_h = W a / H, from its centre over half its diagonal d) undistorts to
    p_u = (S_x a X, S_y Y),   X = xi (1 + sum_k cx_k T_k),  Y = eta (1 + sum_k cy_k T_k),
    (xi, eta) = (p_x / a, p_y),   T = (r^2, r^2 cos 2 phi, r^4, r^4 cos 2 phi, r^4 cos 4 phi)
          = (xi^2 + eta^2, xi^2 - eta^2, r^4, r^2 (xi^2 - eta^2), (xi^2 - eta^2)^2 - 4 xi^2 eta^2)
(Cx02, Cx22 "Degree 2", Cx04, Cx24, Cx44 "Degree 4", and Cy's), a the plate's pixel aspect:
the squeeze the renderers desqueeze by (core.paraxial.squeeze), for the squeezed plate. The
lens image's desqueezed point is p d, its pinhole point p_u d at the vertical focal length
f_y (the grid's pinhole, whose horizontal S f_x the squeezes take up); S_x, S_y and the
coefficients are fitted by linear least squares over ANAMORPHIC_POINTS^2 points of the frame
(S and S c per axis), the residual the largest over a lattice twice as fine, in the
undistorted image's pixels. Not checked against 3DEqualizer itself here.
"""

from __future__ import annotations

import math

import numpy as np


def _fit(table, r_max_mm: float, pixel_mm: float, model: str) -> dict:
    keep = table.r_mm <= r_max_mm
    r, th = table.r_mm[keep], table.theta[keep]
    f = table.f_p_mm
    if model == "brown_conrady":
        x = np.tan(th)
        powers, names = (3, 5, 7), ("k1", "k2", "k3")
    else:
        x = th
        powers, names = (3, 5, 7, 9), ("k1", "k2", "k3", "k4")
    a = np.stack([f * x ** p for p in powers], axis=1)
    k, *_ = np.linalg.lstsq(a, r - f * x, rcond=None)
    residual = float(np.max(np.abs(a @ k + f * x - r))) / pixel_mm
    out = {"model": "opencv_" + model, **{n: float(v) for n, v in zip(names, k)}}
    if model == "brown_conrady":
        out.update(p1=0.0, p2=0.0)
    out.update(max_residual_px=residual, fitted_to_radius_mm=float(r[-1]))
    return out


def _fit_3de(table, corner_mm: float, pixel_mm: float) -> dict:
    """3DE4 Radial - Standard, Degree 4 (module docstring), d = corner_mm."""
    keep = table.r_mm <= corner_mm
    r = table.r_mm[keep] / corner_mm
    rho = table.f_p_mm * np.tan(table.theta[keep]) / corner_mm
    a = np.stack([r ** 3, r ** 5], axis=1)
    (c2, c4), *_ = np.linalg.lstsq(a, rho - r, rcond=None)
    residual = float(np.max(np.abs(a @ np.array([c2, c4]) + r - rho))) * corner_mm / pixel_mm
    return {"model": "3de4_radial_standard_degree_4", "focal_length_mm": table.f_p_mm,
            "distortion_degree_2": float(c2), "quartic_distortion_degree_4": float(c4),
            "u_degree_2": 0.0, "v_degree_2": 0.0, "u_degree_4": 0.0, "v_degree_4": 0.0,
            "phi_cylindric_direction": 0.0, "b_cylindric_bending": 0.0,
            "filmback_half_diagonal_mm": corner_mm, "max_residual_px": residual,
            "fitted_to_radius_mm": float(table.r_mm[keep][-1])}


def fitted_models(table, frame) -> dict:
    """{model name: coefficients, f_x, f_y, c_x, c_y (pixels of the lens's image) and the
    largest residual in pixels} of OpenCV's two models, and 3DE's radial model, fitted within
    the frame's corner."""
    pixel = frame.sensor_width_mm / frame.width_px
    corner = 0.5 * math.hypot(frame.sensor_width_mm, frame.sensor_height_mm)
    camera = {"fx_px": table.f_p_mm / pixel, "fy_px": table.f_p_mm / pixel,
              "cx_px": 0.5 * frame.width_px, "cy_px": 0.5 * frame.height_px}
    fits = {m: {**_fit(table, corner, pixel, m), **camera}
            for m in ("brown_conrady", "kannala_brandt")}
    fits["tde4_radial_standard_degree_4"] = _fit_3de(table, corner, pixel)
    return fits


#: points each way over the frame the anamorphic model is fitted at
ANAMORPHIC_POINTS = 41
#: 3DE's names of the anamorphic model's coefficients, in the order of its terms T_k
TDE4_ANAMORPHIC_TERMS = ("02 - Degree 2", "22 - Degree 2", "04 - Degree 4", "24 - Degree 4",
                         "44 - Degree 4")


def _tde4_key(axis: str, term: str) -> str:
    """The lens data's key of 3DE's coefficient C{axis}{term} ("cx02_degree_2", ...)."""
    return "c" + axis + term.replace(" - Degree ", "_degree_")


def tde4_anamorphic_terms(xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """(N, 5) the terms T_k of 3DE's anamorphic model at (xi, eta) (module docstring)."""
    x2, y2 = xi * xi, eta * eta
    r2, c2 = x2 + y2, x2 - y2
    return np.stack([r2, c2, r2 * r2, r2 * c2, c2 * c2 - 4.0 * x2 * y2], axis=1)


def tde4_anamorphic(grid, frame) -> dict | None:
    """3DE4 Anamorphic - Standard, Degree 4 fitted to an anamorphic lens's chief-ray grid over
    the desqueezed frame (module docstring); None where the lens images too little of it."""
    pixel = frame.sensor_width_mm / frame.width_px
    d = 0.5 * math.hypot(frame.sensor_width_mm, frame.sensor_height_mm)
    aspect = float(grid.squeeze)

    def samples(n):
        """(xi, eta, X, Y) at n x n points of the frame that the lens images: the pinhole at
        f_y both ways (3DE's one focal length), P scaled from S f_x to f_y."""
        u = np.linspace(-1.0, 1.0, n)
        p, q = (a.ravel() for a in np.meshgrid(0.5 * frame.sensor_width_mm * u,
                                                0.5 * frame.sensor_height_mm * u))
        big_p, big_q, ok = grid.pinhole_of_lens(p, q)
        big_p = big_p[ok] * grid.f_y_mm / (grid.squeeze * grid.f_x_mm)
        return (p[ok] / (d * aspect), q[ok] / d, big_p / (d * aspect), big_q[ok] / d)

    xi, eta, big_x, big_y = samples(ANAMORPHIC_POINTS)
    if xi.size < 16:
        return None
    terms = tde4_anamorphic_terms(xi, eta)
    out = {"model": "3de4_anamorphic_standard_degree_4", "focal_length_mm": grid.f_y_mm}
    squeezes = {}
    for axis, base, target in (("x", xi, big_x), ("y", eta, big_y)):
        a = base[:, None] * np.concatenate([np.ones((base.size, 1)), terms], axis=1)
        b, *_ = np.linalg.lstsq(a, target, rcond=None)
        squeezes[axis] = float(b[0])
        for name, c in zip(TDE4_ANAMORPHIC_TERMS, b[1:] / b[0]):
            out[_tde4_key(axis, name)] = float(c)
    out.update({"lens_rotation_deg": 0.0, "squeeze_x": squeezes["x"],
                "squeeze_y": squeezes["y"], "pixel_aspect": aspect,
                "filmback_mm": [frame.sensor_width_mm, frame.sensor_height_mm],
                "filmback_half_diagonal_mm": d})
    # the residual over twice as fine a lattice as the fit's (between its points too)
    xi, eta, big_x, big_y = samples(2 * ANAMORPHIC_POINTS - 1)
    x_u, y_u = tde4_anamorphic_undistort(out, xi * d * aspect, eta * d)
    miss = np.hypot(x_u - big_x * d * aspect, y_u - big_y * d)
    out["max_residual_px"] = float(np.max(miss)) / pixel
    return out


def tde4_anamorphic_undistort(coeffs: dict, p_mm: np.ndarray, q_mm: np.ndarray):
    """The pinhole point (mm on the desqueezed filmback, at the model's focal length) of the
    lens image's desqueezed point (p, q) by 3DE's anamorphic model (module docstring)."""
    d, a = coeffs["filmback_half_diagonal_mm"], coeffs["pixel_aspect"]
    xi, eta = np.asarray(p_mm) / (d * a), np.asarray(q_mm) / d
    t = tde4_anamorphic_terms(xi, eta)
    cx, cy = (np.array([coeffs[_tde4_key(axis, n)] for n in TDE4_ANAMORPHIC_TERMS])
              for axis in "xy")
    return (coeffs["squeeze_x"] * a * xi * (1.0 + t @ cx) * d,
            coeffs["squeeze_y"] * eta * (1.0 + t @ cy) * d)


def tde4_undistorted_radius(coeffs: dict, r_mm: np.ndarray) -> np.ndarray:
    """The undistorted (pinhole) radius (mm) of lens-image radii r (3DE's radial model)."""
    d = coeffs["filmback_half_diagonal_mm"]
    x = np.asarray(r_mm) / d
    return d * x * (1.0 + coeffs["distortion_degree_2"] * x * x
                    + coeffs["quartic_distortion_degree_4"] * x ** 4)


def brown_conrady_radius(coeffs: dict, t: np.ndarray, f_mm: float) -> np.ndarray:
    """The lens image's radius (mm) of undistorted normalised radii t (OpenCV's model)."""
    t2 = t * t
    return f_mm * t * (1.0 + coeffs["k1"] * t2 + coeffs["k2"] * t2 ** 2
                       + coeffs["k3"] * t2 ** 3)
