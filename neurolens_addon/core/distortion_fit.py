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
