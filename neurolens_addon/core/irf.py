"""The imaging regression function's planes and its input frames (shared by the trainer and
the learned-lens runtime).

A learned lens maps a ray on the input plane Pi_1 (the plane of the rear vertex, on the sensor
side) to the aperture-stop plane (stage 1), and a ray on the stop plane to the output plane
Pi_2 just in front of the front vertex (stage 2). Sensor focusing is free-space propagation from
the sensor plane z_s to Pi_1:  x_1 = x_s + (z_1 - z_s) u / w. Pi_1 sits at the rear vertex rather
than at the image plane (the paper's choice) because there a ray's (x, y) is nearly where it
meets the rear element: the free-space step x + d u / w, which is not polynomial, stays out of
what the networks learn (the error this saves: docs/measurements.md).
Pi_1 is only a parametrisation of the sensor ray's line; a surface bulging past it is fine.

A rotationally symmetric lens commutes with rotations about the axis, so each stage is learned in
the ray's radial frame: with phi = atan2(y, x), r = |(x, y)|, the rotated direction
    u_r =  cos(phi) u + sin(phi) v,    u_t = -sin(phi) u + cos(phi) v,
the stage sees (r, u_r, u_t, w[, lambda]) and returns (x'_r, x'_t, u'_r, u'_t), rotated back by
+phi; w' = sqrt(1 - u'^2 - v'^2). At r = 0 any phi is consistent (we use phi = 0).

A group of surfaces with an anamorphic one (a cylinder, toroid or biconic) does not commute
with rotations, so its stage is learned in the "cartesian" frame: no rotation, the stage sees
X = (x, y, u, v, w[, lambda]) and returns (x', y', u', v') in lens space. The frame is chosen
per stage: a front anamorphic attachment leaves the rear group (stage 1) a surface of
revolution, learned radially, with the symmetry's accuracy. A frame's `base` columns (radial:
r, u_r, u_t; cartesian: x, y, u, v) are those its occupancy grid covers and the sparse skip's
base polynomial spans; w and lambda follow them. model.json names each stage's frame
(stages[k].frame; absent: the model's "frame", absent: radial, as models written before
frames existed); the model's "frame" is cartesian when any stage is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .prescription import Lens

#: gap between the front vertex and the output plane Pi_2 (mm)
OUTPUT_PLANE_GAP_MM = 1.0


@dataclass(frozen=True)
class StageFrame:
    """How a stage sees a ray (module docstring): its input columns and their roles."""

    name: str
    base: int            # leading input columns: occupancy axes and the skip's base monomials
    rotates: bool        # radial: inputs and outputs in the ray's rotated frame
    mirror: bool         # the map is mirror-symmetric in column MIRROR_COLUMN (radial: u_t)

    @property
    def w_column(self) -> int:
        return self.base

    def d_in(self, dispersion: bool) -> int:
        """Input columns: the base, w, and lambda with dispersion."""
        return self.base + 1 + int(bool(dispersion))


RADIAL = StageFrame("radial", 3, True, True)
CARTESIAN = StageFrame("cartesian", 4, False, False)
FRAMES = {f.name: f for f in (RADIAL, CARTESIAN)}
#: the column a radial stage's map is mirror-symmetric in (u_t)
MIRROR_COLUMN = 2


def stage_frames(lens: Lens) -> tuple[StageFrame, StageFrame]:
    """The frames the two stages of a lens are learned in: stage 1 the rear group (the stop
    and the surfaces behind it, as stage 1 traces them), stage 2 the front group (those
    before the stop); cartesian for a group with an anamorphic surface, else radial."""
    stop = lens.stop_index

    def frame(surfaces) -> StageFrame:
        return (CARTESIAN if any(not s.shape.rotationally_symmetric for s in surfaces)
                else RADIAL)
    return frame(lens.surfaces[stop:]), frame(lens.surfaces[:stop])


def stage_columns(frame: StageFrame, x, y, u, v, w, lam, dispersion: bool):
    """(input columns X, rotation (c, s) or None) of rays at (x, y) with direction (u, v, w):
    radial (r, u_r, u_t, w[, lambda]) with c = cos phi, s = sin phi (phi = 0 at r = 0);
    cartesian (x, y, u, v, w[, lambda]) and no rotation."""
    tail = [w] + ([lam] if dispersion else [])
    if not frame.rotates:
        return [x, y, u, v] + tail, None
    r, ur, ut, c, s = to_radial(x, y, u, v)
    return [r, ur, ut] + tail, (c, s)


def stage_targets(o, d, rot) -> np.ndarray:
    """Target position/direction (N, 4) of output rays (o, d (3, N)) in the INPUT ray's frame:
    rotated by (c, s) = rot, or as they are (rot None)."""
    if rot is None:
        return np.stack([o[0], o[1], d[0], d[1]], axis=1)
    c, s = rot
    return np.stack([c * o[0] + s * o[1], -s * o[0] + c * o[1],
                     c * d[0] + s * d[1], -s * d[0] + c * d[1]], axis=1)


def model_frames(meta: dict) -> list[StageFrame]:
    """Each stage's frame a model.json dict names (stages[k].frame, else the model's "frame",
    else radial); KeyError for an unknown name (neural.modelfile checks them first, naming
    the file and field)."""
    default = meta.get("frame", RADIAL.name)
    return [FRAMES[st.get("frame", default)] for st in meta["stages"]]


@dataclass(frozen=True)
class IRFPlanes:
    input_z: float
    stop_z: float
    output_z: float

    def as_dict(self) -> dict:
        return {"input_z": self.input_z, "stop_z": self.stop_z, "output_z": self.output_z}


def irf_planes(lens: Lens) -> IRFPlanes:
    stop = lens.surfaces[lens.stop_index]
    if not stop.is_flat:
        raise ValueError(f"lens '{lens.name}': a learned lens needs a flat aperture stop "
                         f"(surface {lens.stop_index + 1} is curved)")
    return IRFPlanes(lens.rear_vertex_z, float(lens.vertex_z[lens.stop_index]),
                     lens.front_vertex_z + OUTPUT_PLANE_GAP_MM)


def propagate_to_z(o: np.ndarray, d: np.ndarray, z: float) -> np.ndarray:
    """Origins moved along their rays to the plane z (rays with d_z = 0, or invalid rays
    carried as zeros, get NaN: callers keep their validity masks)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (z - o[2]) / d[2]
        return np.stack([o[0] + t * d[0], o[1] + t * d[1], np.full_like(o[0], z)])


def from_frame(Y, rot):
    """Stage outputs Y (N, 4) back to lens space (x, y, u, v): rotated back, or as they are."""
    if rot is None:
        return Y[:, 0], Y[:, 1], Y[:, 2], Y[:, 3]
    return from_radial(Y[:, 0], Y[:, 1], Y[:, 2], Y[:, 3], *rot)


def to_radial(x, y, u, v):
    """(r, u_r, u_t, cos phi, sin phi) of rays at (x, y) with direction (u, v, .)."""
    r = np.hypot(x, y)
    safe = np.where(r > 0, r, 1.0)
    c = np.where(r > 0, x / safe, 1.0)
    s = np.where(r > 0, y / safe, 0.0)
    return r, c * u + s * v, -s * u + c * v, c, s


def from_radial(xr, xt, ur, ut, c, s):
    """Rotate radial-frame position and direction components back to (x, y, u, v)."""
    return c * xr - s * xt, s * xr + c * xt, c * ur - s * ut, s * ur + c * ut


def unit_w(u, v):
    """w = sqrt(1 - u^2 - v^2), NaN where the direction is not a unit vector."""
    with np.errstate(invalid="ignore"):
        return np.sqrt(1.0 - u * u - v * v)
