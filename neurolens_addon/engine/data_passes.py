"""Data passes of the first hit, through the real lens: Vector (motion), Position and UV.

Per camera sample whose ray hits the scene, at its first hit x (world space) on triangle
(a, b, c) of an object, x = beta_a a + beta_b b + beta_c c (mesh_tables locates it):
    Position  x, Blender's Position pass (world space)
    UV        the object's active render UV map interpolated by beta: (u, v, 1) (Cycles' UV
              pass, its third channel 1 where a surface is)
    Vector    where the same surface point was on the film one frame before and where it
              will be one frame after, against where it is now, in pixels (x right, y up):
                  (X_prev - X, Y_prev - Y, X - X_next, Y - Y_next)
              Cycles' convention (its motion_pre = prev - centre, motion_post = centre -
              next), which Blender's Vector Blur reads. The point one frame away is
              beta_a a' + beta_b b' + beta_c c' with the triangle's vertices a', b', c' at that
              frame (objects that move, deform or are parented alike; an object whose vertex
              count changes between frames counts as not moving, as in Cycles), and each
              point is placed on the film by the chief ray through the lens
              (core.projection), seen from the camera where it stands at that frame:
                  lens space (X, Y, Z) = (c_x / k, c_y / k, z_s - c_z / k),
                  c = R^T (x - t) its camera-space position (camera_rays.world_to_lens),
              so a distorting lens's vectors are its own, not a pinhole's.
Each pass is a mean over the pixel's image samples that hit (Position, UV: not blended with
the background, as Depth; UV's A is the share of the samples that hit, its coverage) or whose
three points the lens places (Vector); 0 where there are none. Ghost samples (the flare's)
are left out: their rays leave through the lens elsewhere. An instanced copy (a collection's,
a particle's, a geometry-nodes instance) moves rigidly with its matrix, x' = M' M^-1 x, the
copy the caster names (Embree by its triangles, Blender's BVH by the object and matrix its
ray_cast returns). The lens's focus and
zoom are the frame's own: an animated focus or zoom moves nothing in the Vector pass (as in
Cycles, whose vectors come from the camera's and the objects' motion).
Vector places points by the lens's chief rays: a lens of revolution's chief-ray table, an
anamorphic lens's chief-ray grid, a lens known only from a ray table's chief rays through its
model (camera.table_lens); where a lens has none (no chief ray passes near the axis) the pass
is left at 0 and the render says why (VECTOR_NOTE).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera_rays import world_to_lens
from .mesh_tables import instance_mesh

#: (name, channels, chan_id) of each data pass, as Blender names them
DATA_PASSES = (("Vector", 4, "XYZW"), ("Position", 3, "XYZ"), ("UV", 3, "UVA"))
#: the view layer's switch of each
SWITCHES = {"Vector": "use_pass_vector", "Position": "use_pass_position", "UV": "use_pass_uv"}
#: film columns of each pass's sums (Vector's fifth: the samples it counts); a layout adds two
#: more: the image samples that passed the lens, and those of them that hit
COLUMNS = {"Vector": 5, "Position": 3, "UV": 2}
#: a hit lies on the triangle located for it within this share of its distance from the
#: origin (else it is an instance's: the object's own triangles are elsewhere)
ON_TRIANGLE = 1e-4


@dataclass
class MotionStep:
    """The scene one frame away: the camera's rigid matrix, each object's world-space
    vertices (by the original object's full name) and each instanced copy's matrix (by its
    scene_cast.instance_key)."""

    camera_matrix: np.ndarray
    vertices: dict = field(default_factory=dict)
    instances: dict = field(default_factory=dict)


def read_motion_step(depsgraph, camera_matrix) -> MotionStep:
    """The evaluated scene as it stands (the caller has set its frame): every object's
    world-space vertices, and every instanced copy's matrix (an instance moves rigidly with
    it: its own deformation is not followed)."""
    from .scene_cast import instance_key
    step = MotionStep(np.asarray(camera_matrix, dtype=np.float64))
    for inst in depsgraph.object_instances:
        if inst.is_instance:
            step.instances[instance_key(inst)] = np.array(inst.matrix_world, np.float64)
            continue
        read = instance_mesh(inst)
        if read is not None:
            step.vertices[inst.object.original.name_full] = read[0]
    return step


@dataclass(frozen=True)
class DataLayout:
    """The data passes a frame writes and their columns in the film's data sums."""

    passes: tuple

    def __post_init__(self):
        unknown = set(self.passes) - set(COLUMNS)
        if unknown:
            raise ValueError(f"no such data pass: {', '.join(sorted(unknown))}")

    @property
    def width(self) -> int:
        return sum(COLUMNS[p] for p in self.passes) + 2      # + image samples, their hits

    def columns(self, name: str) -> slice:
        start = 0
        for p in self.passes:
            if p == name:
                return slice(start, start + COLUMNS[p])
            start += COLUMNS[p]
        raise KeyError(name)

    @property
    def channels(self) -> int:
        """Float channels of Blender's result for these passes."""
        return sum(c for n, c, _ in DATA_PASSES if n in self.passes)

    def readout(self, sums: np.ndarray) -> dict:
        """{pass: (n, channels) float32} of the data sums of n pixels."""
        out = {}
        samples, hits = sums[:, -2], sums[:, -1]
        inv_hits = np.where(hits > 0, 1.0 / np.where(hits > 0, hits, 1.0), 0.0)
        inv_samples = np.where(samples > 0, 1.0 / np.where(samples > 0, samples, 1.0), 0.0)
        for name in self.passes:
            s = sums[:, self.columns(name)]
            if name == "Vector":
                c = s[:, 4]
                out[name] = np.where(c[:, None] > 0, s[:, :4] / np.maximum(c, 1e-30)[:, None],
                                     0.0).astype(np.float32)
            elif name == "UV":
                uv = np.empty((s.shape[0], 3), np.float32)
                uv[:, :2] = s * inv_hits[:, None]
                uv[:, 2] = hits * inv_samples             # the surface's coverage
                out[name] = uv
            else:
                out[name] = (s * inv_hits[:, None]).astype(np.float32)
        return out


class FirstHitData:
    """The data passes' values at a bundle's first hits (module docstring). `placement` a
    core.projection.FilmPlacement of the frame's lens and film, or None (no Vector);
    `camera_matrix` the rigid camera matrix now, `steps` the MotionSteps one frame before and
    after (None: no Vector), mm_per_unit and sensor_z_mm the lens space's."""

    def __init__(self, layout: DataLayout, *, placement=None, camera_matrix=None, steps=None,
                 mm_per_unit: float = 1000.0, sensor_z_mm: float = 0.0):
        self.layout = layout
        self.placement = placement
        self.matrix = None if camera_matrix is None else np.asarray(camera_matrix, np.float64)
        self.steps = steps
        self.mm_per_unit = float(mm_per_unit)
        self.sensor_z = float(sensor_z_mm)
        self.vector = "Vector" in layout.passes and placement is not None and steps is not None

    def _pixels(self, points: np.ndarray, matrix: np.ndarray):
        """((K, 2) film pixels, (K,) placed) of world points seen by the camera at `matrix`."""
        return self.placement.pixels(world_to_lens(points, matrix, self.sensor_z,
                                                   self.mm_per_unit))

    def values(self, hits, objects: list, tables, instances=()) -> np.ndarray:
        """(K, layout.width) the data sums' columns of the first hits (scene_cast.Hits);
        `tables(object id)` their mesh_tables.ObjectTable (built: materials.lookup ran);
        `instances` the caster's instanced copies ((instance_key, matrix) each), which
        hits.instance indexes."""
        lay = self.layout
        k = hits.ray.size
        out = np.zeros((k, lay.width))
        out[:, -2:] = 1.0                          # an image sample, and it hit
        if "Position" in lay.passes:
            out[:, lay.columns("Position")] = hits.location
        need_bary = "UV" in lay.passes or self.vector
        moved = {step: hits.location.copy() for step in range(2)} if self.vector else None
        if need_bary and k:
            obj = np.asarray(hits.object, np.int64)
            for oid in np.unique(obj):
                rows = np.flatnonzero(obj == oid)
                tab = tables(int(oid))
                if tab is None or tab.poly_material.size == 0:
                    continue
                poly = np.clip(hits.polygon[rows], 0, tab.poly_material.size - 1)
                tri, bary = tab.locate(poly, hits.location[rows])
                _first, _count, co, tv, loops = tab.triangles()
                if "UV" in lay.passes:
                    uv = tab.uv(None)
                    if uv is not None:
                        out[rows, lay.columns("UV")] = np.einsum("ij,ijk->ik", bary,
                                                                 uv[loops[tri]])
                if self.vector:
                    # the surface point moves with its triangle: p + sum beta (v' - v); a hit
                    # off the triangle located for it is an instance's (the object's own
                    # triangles lie elsewhere), which counts as still
                    p = hits.location[rows]
                    corners = co[tv[tri]]
                    gap = np.abs(np.einsum("ij,ijk->ik", bary, corners) - p).max(axis=1)
                    on = gap <= ON_TRIANGLE * (1.0 + np.abs(p).max(axis=1))
                    name = objects[oid].name_full
                    for s, step in enumerate(self.steps):
                        there = step.vertices.get(name)
                        if there is not None and there.shape == co.shape:
                            shift = np.einsum("ij,ijk->ik", bary, there[tv[tri]] - corners)
                            moved[s][rows] = p + np.where(on[:, None], shift, 0.0)
        if self.vector and k and hits.instance is not None:
            self._instance_motion(hits, instances, moved)
        if self.vector and k:
            now, ok = self._pixels(hits.location, self.matrix)
            before, ok_b = self._pixels(moved[0], self.steps[0].camera_matrix)
            after, ok_a = self._pixels(moved[1], self.steps[1].camera_matrix)
            ok &= ok_b & ok_a
            v = lay.columns("Vector")
            vec = np.concatenate([before - now, now - after, np.ones((k, 1))], axis=1)
            out[:, v] = np.where(ok[:, None], vec, 0.0)
        return out


    def _instance_motion(self, hits, instances, moved) -> None:
        """An instanced copy's hits move rigidly with it: x' = M' M^-1 x (M its matrix now,
        M' at the other frame; a copy the other frame does not hold stays still)."""
        for i in np.unique(hits.instance[hits.instance >= 0]):
            rows = np.flatnonzero(hits.instance == i)
            key, now = instances[int(i)]
            p = hits.location[rows]
            for s, step in enumerate(self.steps):
                there = step.instances.get(key)
                if there is None:
                    moved[s][rows] = p
                    continue
                m = there @ np.linalg.inv(now)
                moved[s][rows] = p @ m[:3, :3].T + m[:3, 3]


#: why a frame's Vector pass is 0 where its lens has no chief-ray table
VECTOR_NOTE = "the Vector pass is left at 0: {why}; it places points by the lens's chief rays"
