"""The surface at each ray hit (engine.materials.SceneMaterials.lookup) against a computation
of its own, hit by hit through Blender's API: the material of the hit polygon's slot, the
smooth normal interpolated over the polygon's triangle containing the hit (mathutils'
barycentric weights), and an image texture read at the UV interpolated the same way."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("embreex")

from neurolens_addon.engine.embree_cast import EmbreeCaster  # noqa: E402
from neurolens_addon.engine.materials import SceneMaterials  # noqa: E402
from testdata import engine_scenes as scenes  # noqa: E402

CHECKER = 4


def _material(name, colour=None, image=None):
    mat = bpy.data.materials.new(name)
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    if colour is not None:
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    if image is not None:
        tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
        tex.image, tex.interpolation = image, "Closest"
        mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _scene():
    """A textured floor (a 4 x 4 checker of known texels), a smooth sphere, a flat cube with
    two material slots, a cone without material."""
    scenes.reset()
    img = bpy.data.images.new("checker", CHECKER, CHECKER, float_buffer=True)
    texels = np.random.default_rng(1).random((CHECKER, CHECKER, 3)) * 0.8 + 0.1
    img.pixels.foreach_set(np.concatenate([texels, np.ones((CHECKER, CHECKER, 1))],
                                          axis=2).astype(np.float32).ravel())
    bpy.ops.mesh.primitive_plane_add(size=6.0, location=(0.0, 0.0, -3.0))
    bpy.context.object.data.materials.append(_material("floor", image=img))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.7, 0.3, -2.0))
    bpy.ops.object.shade_smooth()
    bpy.context.object.data.materials.append(_material("sphere", (0.2, 0.5, 0.8)))
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(-0.8, -0.4, -2.2),
                                    rotation=(0.4, 0.3, 0.2))
    cube = bpy.context.object
    cube.data.materials.append(_material("red", (0.9, 0.1, 0.1)))
    cube.data.materials.append(_material("green", (0.1, 0.9, 0.1)))
    for poly in cube.data.polygons:            # the face towards the camera green, others red
        poly.material_index = 1 if poly.normal.z > 0.5 else 0
    bpy.ops.mesh.primitive_cone_add(radius1=0.4, depth=0.8, location=(-0.6, 0.9, -2.0))
    scenes.camera(focus=2.0, fstop=2.0, sensor_width=24.0, model="exact")
    bpy.context.view_layer.update()
    return bpy.context.evaluated_depsgraph_get(), texels


def _expected(ob, dg, polygon, x, face_normal, texels):
    """(base colour or None for the default, shading normal) of one hit, through bpy."""
    from mathutils import Vector
    from mathutils.geometry import intersect_point_tri
    from mathutils.interpolate import poly_3d_calc
    ev = ob.evaluated_get(dg)
    mesh, m = ev.data, ev.matrix_world
    poly = mesh.polygons[polygon]
    slots = ev.material_slots
    mat = slots[min(poly.material_index, len(slots) - 1)].material if len(slots) else None
    best = None
    for tri in mesh.loop_triangles:
        if tri.polygon_index != polygon:
            continue
        corners = [m @ mesh.vertices[v].co for v in tri.vertices]
        on = intersect_point_tri(Vector(x), *corners)
        # the triangle containing x (the nearest, for a hit within rounding of an edge);
        # inside a triangle poly_3d_calc's weights are its barycentric coordinates
        miss = 0.0 if on is not None else min((Vector(x) - c).length for c in corners)
        if best is None or miss < best[0]:
            best = (miss, tri, poly_3d_calc(corners, Vector(x)))
    _miss, tri, w = best
    normal = face_normal
    if poly.use_smooth:
        rot = m.to_3x3().inverted().transposed()
        n = sum((wi * (rot @ mesh.corner_normals[loop].vector) for wi, loop in
                 zip(w, tri.loops)), Vector())
        n.normalize()
        normal = np.array(n) * (1.0 if np.dot(n, face_normal) >= 0 else -1.0)
    if mat is None:
        return None, normal
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    if bsdf.inputs["Base Color"].is_linked:
        uv_layer = mesh.uv_layers.active.data
        uv = sum((wi * uv_layer[loop].uv for wi, loop in zip(w, tri.loops)), Vector((0, 0)))
        i = min(int(uv[1] % 1.0 * CHECKER), CHECKER - 1)
        j = min(int(uv[0] % 1.0 * CHECKER), CHECKER - 1)
        return texels[i, j], normal
    return np.array(bsdf.inputs["Base Color"].default_value[:3]), normal


def _hits(seed):
    """(depsgraph, texels, caster, hits) of 3000 rays from the origin down into _scene."""
    dg, texels = _scene()
    caster = EmbreeCaster(dg)
    rng = np.random.default_rng(seed)
    n = 3000
    d = np.stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.9, 0.9, n), -np.ones(n)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return dg, texels, caster, caster.closest(np.zeros((n, 3)), d)


def test_01_lookup_gives_the_material_normal_and_texel_of_every_hit():
    dg, texels, caster, hits = _hits(5)
    materials = SceneMaterials(dg)
    # two bundles: the first builds the object tables, the second reads them
    half = hits.ray.size // 2
    parts = [type(hits)(*(None if getattr(hits, f) is None else getattr(hits, f)[s]
                          for f in hits.__dataclass_fields__))
             for s in (slice(0, half), slice(half, None))]
    sps = [materials.lookup(part, caster.objects) for part in parts]
    base = np.concatenate([sp.base for sp in sps])
    normal = np.concatenate([sp.normal for sp in sps])
    default = materials.arrays()["base"][0]
    seen = set()
    for i in range(0, hits.ray.size, 7):
        ob = caster.objects[hits.object[i]]
        face = hits.normal[i] / np.linalg.norm(hits.normal[i])
        want_base, want_normal = _expected(ob, dg, int(hits.polygon[i]), hits.location[i],
                                           face, texels)
        want_base = default if want_base is None else want_base
        np.testing.assert_allclose(base[i], want_base, atol=1e-6, err_msg=ob.name)
        np.testing.assert_allclose(normal[i], want_normal, atol=1e-5, err_msg=ob.name)
        seen.add((ob.name, tuple(np.round(want_base, 3))))
    names = {name for name, _ in seen}
    assert names == {"Plane", "Sphere", "Cube", "Cone"}
    assert len({b for name, b in seen if name == "Cube"}) == 2      # both slots
    assert len({b for name, b in seen if name == "Plane"}) >= 8     # many texels


def test_02_the_compiled_lookup_equals_the_numpy_one(monkeypatch):
    """The lookup's rows and gathers through mesh_kernels.surface_rows (one pass) against the
    numpy gathers, every SurfacePoint field, over the same hits (smooth, textured and flat
    polygons, both of the cube's slots)."""
    from neurolens_addon.engine import shading_kernels
    if not shading_kernels.active():
        pytest.skip("the compiled kernels are not in use (NEUROLENS_KERNELS, numba)")
    dg, _texels, caster, hits = _hits(6)
    materials = SceneMaterials(dg)
    got = materials.lookup(hits, caster.objects)
    monkeypatch.setattr(shading_kernels, "active", lambda: False)
    want = materials.lookup(hits, caster.objects)
    for name in type(got).__dataclass_fields__:
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), rtol=1e-14,
                                   atol=1e-15, err_msg=name)
    assert len({tuple(b) for b in np.round(want.base, 3)}) > 8     # many materials and texels
