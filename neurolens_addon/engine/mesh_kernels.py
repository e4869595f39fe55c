"""Ray hits on the meshes, compiled (numba): the triangles' face normals and Embree's answers
gathered into hits (embree_cast.EmbreeCaster.closest: the rays that hit, where, the triangle's
face normal, polygon and object), and their location in their polygons' triangles
(mesh_tables.ObjectTable.locate's search row by row, the equations in mesh_tables'
docstring), and each hit's material row and parameters (materials.SceneMaterials.lookup's
gathers). The numpy versions stay the reference (tests/engine/test_shading_kernels.py).
Differences: none for the gather; rounding only for the normals and the location, and a hit
within rounding of two triangles' shared edge may be given either (the barycentrics then agree
to rounding)."""

from __future__ import annotations

import math

import numpy as np

from ..core import jit

_njit = jit.njit(cache=True, nogil=True)
_inline = jit.njit(cache=True, nogil=True, inline="always")


@_njit
def gather_hits(geom, prim, tfar, origin, direction, normal, tri_poly, tri_obj, ray, loc, nrm,
                poly, obj):
    """The rays with a hit (geom >= 0), in order, into ray, loc = o + tfar d, nrm (the
    triangle prim's face normal), poly and obj; their count returned."""
    n = 0
    for r in range(geom.shape[0]):
        if geom[r] < 0:
            continue
        t = prim[r]
        dist = np.float64(tfar[r])
        ray[n] = r
        for c in range(3):
            loc[n, c] = origin[r, c] + dist * direction[r, c]
            nrm[n, c] = normal[t, c]
        poly[n] = tri_poly[t]
        obj[n] = tri_obj[t]
        n += 1
    return n


@_njit
def face_normals(vertices, indices, out):
    """Each triangle's unit face normal (b - a) x (c - a) / |...| (zero for a degenerate one)
    into out (T, 3), its corners the vertex rows `indices` (T, 3)."""
    for t in range(indices.shape[0]):
        a, b, c = indices[t, 0], indices[t, 1], indices[t, 2]
        e1x = vertices[b, 0] - vertices[a, 0]
        e1y = vertices[b, 1] - vertices[a, 1]
        e1z = vertices[b, 2] - vertices[a, 2]
        e2x = vertices[c, 0] - vertices[a, 0]
        e2y = vertices[c, 1] - vertices[a, 1]
        e2z = vertices[c, 2] - vertices[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
        out[t, 0], out[t, 1], out[t, 2] = nx / ln, ny / ln, nz / ln


@_njit
def surface_rows(obj, polygon, normal, offset, npoly, flat_material, flat_smooth, texture,
                 scalars, vectors, out_mat, out_need, out_normal, out_scalars, out_vectors):
    """Per hit r on polygon polygon[r] of object obj[r]: its material row (the object's
    polygons start at offset[obj] in flat_material, npoly[obj] of them; a polygon out of range
    is clamped into them), whether it needs locating (a smooth polygon or a textured row),
    its face normal made unit, and the row's parameters: out_scalars[j][r] =
    scalars[j][row] ((R,) arrays), out_vectors[j][r] = vectors[j][row] ((R, 3) arrays)."""
    for r in range(obj.shape[0]):
        o = obj[r]
        at = offset[o] + min(max(polygon[r], 0), max(npoly[o] - 1, 0))
        m = flat_material[at]
        out_mat[r] = m
        out_need[r] = flat_smooth[at] or texture[m] >= 0
        nx, ny, nz = normal[r, 0], normal[r, 1], normal[r, 2]
        ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
        out_normal[r, 0], out_normal[r, 1], out_normal[r, 2] = nx / ln, ny / ln, nz / ln
        for j in range(len(scalars)):
            out_scalars[j][r] = scalars[j][m]
        for j in range(len(vectors)):
            for c in range(3):
                out_vectors[j][r, c] = vectors[j][m, c]


@_inline
def _locate_one(q, px, py, pz, first, count, co, tv):
    """Of polygon q's triangles (triangle t's corners co[tv[t]]), the one whose smallest
    barycentric coordinate at (px, py, pz) is largest: (triangle, u, v, w); (0, 0, 0, 0) for a
    polygon without triangles."""
    best = -np.inf
    tri, bu, bv, bw = 0, 0.0, 0.0, 0.0
    for j in range(count[q]):
        t = first[q] + j
        i0, i1, i2 = tv[t, 0], tv[t, 1], tv[t, 2]
        ax, ay, az = co[i0, 0], co[i0, 1], co[i0, 2]
        v0x, v0y, v0z = co[i1, 0] - ax, co[i1, 1] - ay, co[i1, 2] - az
        v1x, v1y, v1z = co[i2, 0] - ax, co[i2, 1] - ay, co[i2, 2] - az
        v2x, v2y, v2z = px - ax, py - ay, pz - az
        d00 = v0x * v0x + v0y * v0y + v0z * v0z
        d01 = v0x * v1x + v0y * v1y + v0z * v1z
        d11 = v1x * v1x + v1y * v1y + v1z * v1z
        d20 = v2x * v0x + v2y * v0y + v2z * v0z
        d21 = v2x * v1x + v2y * v1y + v2z * v1z
        den = d00 * d11 - d01 * d01
        if not abs(den) > 1e-30:
            den = 1e-30
        v = (d11 * d20 - d01 * d21) / den
        w = (d00 * d21 - d01 * d20) / den
        u = 1.0 - v - w
        score = min(u, v, w)
        if score > best:
            best = score
            tri, bu, bv, bw = t, u, v, w
    return tri, bu, bv, bw


@_njit
def locate(poly, p, first, count, co, tv, tri, bary):
    """For each hit r on polygon poly[r] at p[r]: of the polygon's triangles (first[poly],
    count[poly] of them, triangle t's corners the vertices co[tv[t]] (V, 3)), the one whose
    smallest barycentric coordinate is largest, into tri (N,) and its barycentrics into bary
    (N, 3)."""
    for r in range(poly.shape[0]):
        tri[r], bary[r, 0], bary[r, 1], bary[r, 2] = _locate_one(
            poly[r], p[r, 0], p[r, 1], p[r, 2], first, count, co, tv)


@_njit
def locate_smooth(poly, p, first, count, co, tv, loops, corner_normals, smooth, normal, tri,
                  bary):
    """`locate`, and where the hit polygon is smooth, the corner normals of the triangle's
    loops interpolated by the barycentrics, made unit and turned to the side of the face
    normal normal[r] (written over it)."""
    for r in range(poly.shape[0]):
        t, u, v, w = _locate_one(poly[r], p[r, 0], p[r, 1], p[r, 2], first, count, co, tv)
        tri[r], bary[r, 0], bary[r, 1], bary[r, 2] = t, u, v, w
        if not smooth[poly[r]]:
            continue
        a, b, c = loops[t, 0], loops[t, 1], loops[t, 2]
        nx = u * corner_normals[a, 0] + v * corner_normals[b, 0] + w * corner_normals[c, 0]
        ny = u * corner_normals[a, 1] + v * corner_normals[b, 1] + w * corner_normals[c, 1]
        nz = u * corner_normals[a, 2] + v * corner_normals[b, 2] + w * corner_normals[c, 2]
        ln = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)
        nx, ny, nz = nx / ln, ny / ln, nz / ln
        if nx * normal[r, 0] + ny * normal[r, 1] + nz * normal[r, 2] < 0.0:
            nx, ny, nz = -nx, -ny, -nz
        normal[r, 0], normal[r, 1], normal[r, 2] = nx, ny, nz


def run_locate(poly, p, first, count, co, tv):
    k = poly.shape[0]
    tri, bary = np.empty(k, np.int64), np.empty((k, 3))
    locate(np.ascontiguousarray(poly, dtype=np.int64), np.ascontiguousarray(p, np.float64),
           np.ascontiguousarray(first, np.int64), np.ascontiguousarray(count, np.int64),
           np.ascontiguousarray(co, np.float64), np.ascontiguousarray(tv, np.int64), tri, bary)
    return tri, bary


def run_gather_hits(geom, prim, tfar, origin, direction, normal, tri_poly, tri_obj):
    """`gather_hits`: (ray, location, normal, polygon, object) of the rays that hit."""
    k = geom.shape[0]
    ray, loc, nrm = np.empty(k, np.int64), np.empty((k, 3)), np.empty((k, 3))
    poly, obj = np.empty(k, np.int64), np.empty(k, np.int32)
    n = gather_hits(geom, prim, tfar, np.ascontiguousarray(origin, np.float64),
                    np.ascontiguousarray(direction, np.float64), normal, tri_poly, tri_obj,
                    ray, loc, nrm, poly, obj)
    return ray[:n], loc[:n], nrm[:n], poly[:n], obj[:n]


def run_face_normals(vertices, indices):
    """`face_normals`: (T, 3) unit face normals of the triangles."""
    out = np.empty((indices.shape[0], 3))
    face_normals(np.ascontiguousarray(vertices, np.float64),
                 np.ascontiguousarray(indices, np.int32), out)
    return out


def run_surface_rows(obj, polygon, normal, offset, npoly, flat_material, flat_smooth,
                     texture, scalars, vectors):
    """`surface_rows`: (material rows, need, unit normals, scalars' values, vectors' values)."""
    k = obj.shape[0]
    mat, need, unit = np.empty(k, np.int64), np.empty(k, np.bool_), np.empty((k, 3))
    out_s = tuple(np.empty(k) for _ in scalars)
    out_v = tuple(np.empty((k, 3)) for _ in vectors)
    surface_rows(np.ascontiguousarray(obj, np.int64), np.ascontiguousarray(polygon, np.int64),
                 np.ascontiguousarray(normal, np.float64), offset, npoly, flat_material,
                 flat_smooth, texture, scalars, vectors, mat, need, unit, out_s, out_v)
    return mat, need, unit, out_s, out_v


def run_locate_smooth(poly, p, first, count, co, tv, loops, corner_normals, smooth, normal):
    """`locate_smooth`: (tri, bary, normal with the smooth polygons' normals)."""
    k = poly.shape[0]
    tri, bary = np.empty(k, np.int64), np.empty((k, 3))
    out = np.array(normal, dtype=np.float64, order="C")
    locate_smooth(np.ascontiguousarray(poly, dtype=np.int64), np.ascontiguousarray(p, np.float64),
                  np.ascontiguousarray(first, np.int64), np.ascontiguousarray(count, np.int64),
                  np.ascontiguousarray(co, np.float64), np.ascontiguousarray(tv, np.int64),
                  np.ascontiguousarray(loops, np.int64),
                  np.ascontiguousarray(corner_normals, np.float64),
                  np.ascontiguousarray(smooth, np.bool_), out, tri, bary)
    return tri, bary, out
