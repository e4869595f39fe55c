"""Rays against the frame's triangles with Intel Embree (the `embreex` package), whole batches
per call.

Export, once per frame: every instance of the evaluated depsgraph (`depsgraph.object_instances`:
objects, collection and geometry-node instances, modifiers applied) that has geometry is read
with `foreach_get` (its loop triangles, their polygon indices, its vertices moved to world space
by the instance's matrix M: x' = M x) into one Embree triangle mesh, with per triangle the id of
the original object (`objects[id]`, the object scene.ray_cast would name) and the polygon.
Instances are flattened: a scene over MAX_TRIANGLES triangles is refused (EmbreeUnavailable,
the engine then uses Blender's BVH and says so).

Queries (float32, as Embree works; origins are offset off surfaces by the shader):
  closest   Embree's first hit t (tfar), primitive id -> (object, polygon); the location
            o + t d in float64 and the face normal of the hit triangle from its world corners,
            n = (b - a) x (c - a) / |...| (Blender's winding: the normal scene.ray_cast gives
            for a planar polygon), so both backends hand the shader the same hits;
  occluded  Embree's occlusion query with tfar = the ray's distance.
"""

from __future__ import annotations

import time

import numpy as np

from . import mesh_kernels, shading_kernels
from .mesh_tables import instance_mesh
from .vec import norm

from .scene_cast import CHUNK, FAR, Caster, Hits, instance_key

#: most triangles exported (flattened instances included): about 2.4 GB of Embree and numpy
#: arrays at 48 bytes a triangle
MAX_TRIANGLES = 50_000_000
#: rays per Embree call (bounded memory of the result arrays)
EMBREE_CHUNK = 1 << 18


class EmbreeUnavailable(RuntimeError):
    """embreex is not installed, or the scene cannot be exported to it."""


def _embree():
    try:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
    except ImportError as exc:
        raise EmbreeUnavailable(f"the embreex package is not installed ({exc})") from None
    return rtcore_scene, TriangleMesh


def export_triangles(depsgraph, instances: list | None = None):
    """(world vertices (V, 3) float64, each triangle's vertex indices (T, 3) int32 into them,
    object per triangle (T,), polygon per triangle (T,), original objects) of every instance
    with geometry: each instance's vertices once, shared by its triangles. With `instances`
    (a list), the instanced copies' (instance_key, 4 x 4 matrix) are appended to it and a
    sixth item gives each triangle's index there (-1: an object's own geometry)."""
    vertices, indices, tri_obj, tri_poly, objects, ids = [], [], [], [], [], {}
    tri_inst = []
    total = nv = 0
    for inst in depsgraph.object_instances:
        read = instance_mesh(inst)
        if read is None:
            continue
        world, verts, poly, _ = read
        t = poly.size
        total += t
        if total > MAX_TRIANGLES:
            raise EmbreeUnavailable(f"the frame has over {MAX_TRIANGLES:,} triangles "
                                    "(instances flattened)")
        vertices.append(world)
        indices.append(verts + np.int32(nv))
        nv += world.shape[0]
        original = inst.object.original
        oid = ids.get(original)
        if oid is None:
            oid = ids[original] = len(objects)
            objects.append(original)
        tri_obj.append(np.full(t, oid, np.int32))
        tri_poly.append(poly)
        if instances is not None:
            k = -1
            if inst.is_instance:
                k = len(instances)
                instances.append((instance_key(inst), np.array(inst.matrix_world, np.float64)))
            tri_inst.append(np.full(t, k, np.int32))
    if not vertices:
        out = (np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0, np.int32),
               np.zeros(0, np.int32), objects)
        return out if instances is None else (*out, np.zeros(0, np.int32))
    out = (np.concatenate(vertices), np.concatenate(indices), np.concatenate(tri_obj),
           np.concatenate(tri_poly), objects)
    return out if instances is None else (*out, np.concatenate(tri_inst))


def face_normals(vertices: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(T, 3) unit face normals n = (b - a) x (c - a) / |...| of the triangles whose corners
    are the vertex rows `indices` (T, 3)."""
    if shading_kernels.active():
        return mesh_kernels.run_face_normals(vertices, indices)
    a = vertices[indices[:, 0]]
    n = np.cross(vertices[indices[:, 1]] - a, vertices[indices[:, 2]] - a)
    return n / np.maximum(norm(n)[:, None], 1e-300)


class EmbreeCaster(Caster):
    """Closest-hit and occlusion queries of whole ray arrays through Embree."""

    backend = "embree"
    thread_safe = True            # Embree's queries are; the scene is built before any

    def __init__(self, depsgraph, should_stop=None, chunk: int = CHUNK):
        super().__init__(should_stop, chunk)
        rtcore_scene, TriangleMesh = _embree()
        t0 = time.perf_counter()
        #: the instanced copies: (instance_key, matrix) each, and each triangle's index there
        #: (-1: an object's own geometry): the Vector pass follows an instance's motion
        self.instances: list = []
        vertices, indices, self._tri_obj, self._tri_poly, originals, self.triangle_instance = \
            export_triangles(depsgraph, self.instances)
        self.triangles = indices.shape[0]
        t1 = time.perf_counter()
        # object ids in export order, so the id of a triangle is its object's
        self._object_ids(originals)
        self._normal = face_normals(vertices, indices)
        self._scene = rtcore_scene.EmbreeScene()
        if self.triangles:
            # an indexed mesh: embreex copies each vertex once, not three times a triangle
            TriangleMesh(self._scene, np.ascontiguousarray(vertices, dtype=np.float32),
                         np.ascontiguousarray(indices, dtype=np.int32))
        # the first query builds the BVH: count it as build time, not cast time
        self._scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        self.export_seconds = t1 - t0
        self.build_seconds = time.perf_counter() - t1

    def _run(self, origin, direction, dists=None, query="INTERSECT"):
        n = origin.shape[0]
        o = np.ascontiguousarray(origin, dtype=np.float32)
        d = np.ascontiguousarray(direction, dtype=np.float32)
        out = []
        for lo in range(0, n, EMBREE_CHUNK):
            self._check()
            hi = min(n, lo + EMBREE_CHUNK)
            kw = {} if dists is None else {"dists": np.ascontiguousarray(dists[lo:hi],
                                                                         dtype=np.float32)}
            if query == "INTERSECT":
                out.append(self._scene.run(o[lo:hi], d[lo:hi], output=1, **kw))
            else:
                out.append(self._scene.run(o[lo:hi], d[lo:hi], query="OCCLUDED", **kw))
        return out

    def closest(self, origin: np.ndarray, direction: np.ndarray) -> Hits:
        """First hit of each ray (origin, unit direction: (N, 3) float arrays)."""
        t0 = time.perf_counter()
        n = origin.shape[0]
        if n == 0 or self.triangles == 0:
            hits = Hits(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                        np.zeros(0, np.int64), np.zeros(0, np.int32))
            self._account("closest", origin, direction, None, t0)
            return hits
        parts = self._run(origin, direction)
        prim, tfar, geom = ((parts[0][k] for k in ("primID", "tfar", "geomID"))
                            if len(parts) == 1 else
                            (np.concatenate([p[k] for p in parts])
                             for k in ("primID", "tfar", "geomID")))
        if shading_kernels.active():      # the gathers in one pass
            hits = Hits(*mesh_kernels.run_gather_hits(geom, prim, tfar, origin, direction,
                                                      self._normal, self._tri_poly,
                                                      self._tri_obj))
        else:
            ray = np.flatnonzero(geom >= 0)
            pid = prim[ray]
            loc = origin[ray] + tfar[ray, None].astype(np.float64) * direction[ray]
            hits = Hits(ray.astype(np.int64), loc, self._normal[pid],
                        self._tri_poly[pid].astype(np.int64), self._tri_obj[pid])
        if self.instances:                      # which instanced copy each hit is on
            hits.instance = self.triangle_instance[prim[hits.ray]]
        self._account("closest", origin, direction, None, t0)
        return hits

    def occluded(self, origin: np.ndarray, direction: np.ndarray,
                 distance: np.ndarray) -> np.ndarray:
        """Whether anything lies on each ray within its distance, (N,) bool."""
        t0 = time.perf_counter()
        dist = np.minimum(np.asarray(distance, dtype=np.float64), FAR)
        if origin.shape[0] == 0 or self.triangles == 0:
            out = np.zeros(origin.shape[0], dtype=bool)
        else:
            parts = self._run(origin, direction, dist, query="OCCLUDED")
            out = np.concatenate(parts) >= 0
        self._account("shadow", origin, direction, dist, t0)
        return out
