"""One object's evaluated mesh as arrays, for the surface lookups of its ray hits.

Built the first time a ray hits the object (the render's worker threads read Blender's mesh
data one at a time, under BPY_READS): the material row of each polygon of the evaluated
mesh (material_index -> material slot -> row) and its smooth flags; on demand the mesh's loop
triangles in world space, its world corner normals (the vertex normals where Blender's
normals domain says they are the same; normals transform by the inverse transpose of the
object's matrix M: n' = n M^-1 for row vectors) and its UV maps.
A hit x on polygon P is located in the triangle (a, b, c) of P that contains it: the one whose
smallest barycentric coordinate is largest, with
    x = (1 - v - w) a + v b + w c,   (v, w) solving the 2 x 2 normal equations of
    x - a = v (b - a) + w (c - a).
Those barycentric coordinates interpolate the triangle's corner UVs and normals.
"""

from __future__ import annotations

import threading

import numpy as np

from . import mesh_kernels, shading_kernels
from .vec import norm


#: the render's worker threads read meshes through Blender's API one at a time
BPY_READS = threading.Lock()
#: object types that carry geometry a ray can hit
GEOMETRY_TYPES = {"MESH", "CURVE", "SURFACE", "FONT", "META"}


def instance_triangles(inst, material_index: bool = False):
    """(world corners (T, 3, 3) float64, polygon of each triangle (T,), material index of each
    polygon (P,) or None) of one depsgraph instance's evaluated geometry (instance_mesh's
    triangles with their corners looked up); None for an instance without triangles."""
    read = instance_mesh(inst, material_index)
    if read is None:
        return None
    world, verts, poly, mi = read
    return world[verts], poly, mi


def instance_mesh(inst, material_index: bool = False):
    """(world vertices (V, 3) float64, each triangle's vertex indices (T, 3) int32, polygon of
    each triangle (T,), material index of each polygon (P,) or None) of one depsgraph
    instance's evaluated geometry, its vertices moved by the instance's matrix M (x' = M x);
    curves, surfaces, text and metaballs through to_mesh (cleared after). None for an
    instance without triangles."""
    ob = inst.object
    if ob.type not in GEOMETRY_TYPES:
        return None
    mesh, cleared = (ob.data, None) if ob.type == "MESH" else (None, ob)
    if mesh is None:
        try:
            mesh = ob.to_mesh()
        except RuntimeError:
            return None
    try:
        if len(mesh.loop_triangles) == 0:
            return None
        mi = None
        if material_index:
            mi = np.zeros(len(mesh.polygons), np.int32)
            mesh.polygons.foreach_get("material_index", mi)
        world, verts, poly, _ = mesh_triangles(mesh, inst.matrix_world)
    finally:
        if cleared is not None:
            cleared.to_mesh_clear()
    return world, verts, poly, mi


def mesh_triangles(mesh, matrix, loops: bool = False):
    """(world vertices (V, 3) float64, each loop triangle's vertex indices (T, 3) int32, its
    polygon (T,) int32, its corner loop indices (T, 3) int32 where `loops`, else None) of a
    mesh whose vertices the matrix M moves (x' = M x)."""
    tris = mesh.loop_triangles
    t = len(tris)
    verts = np.empty(3 * t, np.int32)
    poly = np.empty(t, np.int32)
    tris.foreach_get("vertices", verts)
    tris.foreach_get("polygon_index", poly)
    corner = None
    if loops:
        corner = np.empty(3 * t, np.int32)
        tris.foreach_get("loops", corner)
        corner = corner.reshape(-1, 3)
    co = np.empty(3 * len(mesh.vertices), np.float64)
    mesh.vertices.foreach_get("co", co)
    m = np.array(matrix, dtype=np.float64)
    return co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3], verts.reshape(-1, 3), poly, corner


class ObjectTable:
    """One object's evaluated mesh as arrays: polygon -> material row and smooth flag, and on
    demand its loop triangles in world space, world smooth-shading normals and UV maps."""

    def __init__(self, mesh, matrix: np.ndarray, poly_material: np.ndarray):
        self.mesh = mesh
        self.matrix = matrix
        self.poly_material = poly_material
        npoly = poly_material.size
        self.smooth = np.zeros(npoly, dtype=bool)
        if npoly:
            mesh.polygons.foreach_get("use_smooth", self.smooth)
        self._tris = None
        self._normals = None
        self._uv = {}

    def triangles(self):
        """(first triangle of each polygon (P,), count (P,), world vertices (V, 3), each
        triangle's vertex indices (T, 3), its corner loop indices (T, 3)), triangles sorted by
        polygon."""
        if self._tris is None:
            with BPY_READS:
                # the render's threads hit a mesh at once: the first reads, the others wait
                # for its table rather than read the mesh again after it
                if self._tris is None:
                    self._tris = self._read_triangles()
        return self._tris

    def _read_triangles(self):
        """`triangles`' table, read from the mesh (under BPY_READS)."""
        co, verts, tpoly, loops = mesh_triangles(self.mesh, self.matrix, loops=True)
        # Blender lists loop triangles polygon by polygon: sort only where it did not
        order = (slice(None) if np.all(tpoly[1:] >= tpoly[:-1])
                 else np.argsort(tpoly, kind="stable"))
        npoly = self.poly_material.size
        first = np.searchsorted(tpoly[order], np.arange(npoly))
        count = np.bincount(tpoly, minlength=npoly)
        # in the kernels' types (mesh_kernels), so that no call converts a whole mesh;
        # the vertices once, not a corner table three times their size
        return (first.astype(np.int64), count.astype(np.int64), np.ascontiguousarray(co),
                verts[order].astype(np.int64), loops[order].astype(np.int64))

    def smooth_normals(self):
        """(each triangle's three rows of the normals (T, 3), unit world-space normals (N, 3))
        that smooth shading interpolates: the vertex normals where Blender says they suffice
        (normals_domain POINT: every face smooth, no sharp edges or custom normals; the
        corner normals are then their copies, and a sixth of the data), else the corner
        normals. Normals transform by the inverse transpose of the object's matrix."""
        if self._normals is None:
            with BPY_READS:
                if self._normals is None:           # (another thread may have read them)
                    self._normals = self._read_normals()
        point, n = self._normals
        return self.triangles()[3 if point else 4], n

    def _read_normals(self):
        """`smooth_normals`' (whether per vertex, unit world normals), read from the mesh
        (under BPY_READS)."""
        point = getattr(self.mesh, "normals_domain", "CORNER") == "POINT"
        source = self.mesh.vertex_normals if point else self.mesh.corner_normals
        n = np.empty(3 * len(source), np.float64)
        source.foreach_get("vector", n)
        n = n.reshape(-1, 3)
        inverse = np.linalg.inv(self.matrix[:3, :3])
        if not np.array_equal(inverse, np.eye(3)):      # (an unmoved mesh: no product)
            n = n @ inverse
        n /= np.maximum(norm(n)[:, None], 1e-12)
        return point, n

    def uv(self, name):
        """(L, 2) corner UVs of the named map (None: the active render map), or None."""
        if name not in self._uv:
            with BPY_READS:
                if name not in self._uv:            # (another thread may have read it)
                    self._uv[name] = self._read_uv(name)
        return self._uv[name]

    def _read_uv(self, name):
        """`uv`'s map, read from the mesh (under BPY_READS)."""
        layers = self.mesh.uv_layers
        layer = layers.get(name) if name else None
        if layer is None:
            layer = next((lay for lay in layers if lay.active_render), None) or layers.active
        if layer is None:
            return None
        uv = np.empty(2 * len(self.mesh.loops), np.float64)
        layer.data.foreach_get("uv", uv)
        return uv.reshape(-1, 2)

    def locate(self, poly: np.ndarray, p: np.ndarray):
        """(triangle (K,), barycentrics (K, 3)) of hit points p on polygons poly: of the
        polygon's triangles, the one whose smallest barycentric coordinate is largest."""
        first, count, co, tv, _ = self.triangles()
        if shading_kernels.active():
            return mesh_kernels.run_locate(poly, p, first, count, co, tv)
        return self.locate_numpy(poly, p)

    def locate_smooth(self, poly: np.ndarray, p: np.ndarray, normal: np.ndarray):
        """(triangle, barycentrics, shading normal) of hit points p on polygons poly with face
        normals `normal` (K, 3): `locate`, and on smooth polygons the triangle's normals
        (smooth_normals) interpolated by the barycentrics, made unit and turned to the face
        normal's side."""
        smooth = self.smooth[poly]
        if not smooth.any():
            return (*self.locate(poly, p), normal)
        rows, normals = self.smooth_normals()
        if shading_kernels.active():
            first, count, co, tv, _ = self.triangles()
            return mesh_kernels.run_locate_smooth(poly, p, first, count, co, tv, rows, normals,
                                                  self.smooth, normal)
        tri, bary = self.locate_numpy(poly, p)
        n = np.einsum("ij,ijk->ik", bary[smooth], normals[rows[tri][smooth]])
        n /= np.maximum(norm(n)[:, None], 1e-12)
        g = normal[smooth]
        normal = normal.copy()
        normal[smooth] = np.where((np.einsum("ij,ij->i", n, g) < 0)[:, None], -n, n)
        return tri, bary, normal

    def locate_numpy(self, poly: np.ndarray, p: np.ndarray):
        """`locate` in numpy, the reference of the compiled kernel."""
        first, count, co, tv, _ = self.triangles()
        best = np.full(poly.size, -np.inf)
        tri = np.zeros(poly.size, np.int64)
        bary = np.zeros((poly.size, 3))
        for j in range(int(count[poly].max(initial=0))):
            has = j < count[poly]
            t = np.where(has, first[poly] + j, 0)
            c = co[tv[t]]
            b = _barycentric(p, c[:, 0], c[:, 1], c[:, 2])
            score = np.where(has, b.min(axis=1), -np.inf)
            better = score > best
            best = np.where(better, score, best)
            tri = np.where(better, t, tri)
            bary = np.where(better[:, None], b, bary)
        return tri, bary


def _barycentric(p, a, b, c):
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-30, den, 1e-30)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1.0 - v - w, v, w], axis=1)
