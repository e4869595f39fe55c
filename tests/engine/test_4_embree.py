"""The two ray-cast backends agree: Embree (embreex) and Blender's BVH give the same hits ray
for ray, the same shadows, and the same image."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.slow          # engine renders
pytest.importorskip("embreex")

from neurolens_addon.engine.embree_cast import EmbreeCaster  # noqa: E402
from neurolens_addon.engine.casters import make_caster  # noqa: E402
from neurolens_addon.engine.scene_cast import SceneCaster  # noqa: E402
from testdata import engine_scenes as scenes  # noqa: E402


def _scene():
    """A floor, a subdivided monkey with an array modifier, a smooth sphere, and a collection
    instanced twice by empties (instances the export must place by their own matrices)."""
    scenes.reset()
    bpy.ops.mesh.primitive_plane_add(size=8.0, location=(0.0, 0.0, -3.0))
    bpy.ops.mesh.primitive_monkey_add(location=(-0.8, 0.2, -2.2))
    monkey = bpy.context.object
    monkey.modifiers.new("sub", "SUBSURF").levels = 1
    arr = monkey.modifiers.new("arr", "ARRAY")
    arr.count = 2
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=(0.9, -0.3, -2.0))
    bpy.ops.object.shade_smooth()
    coll = bpy.data.collections.new("inst")
    bpy.context.scene.collection.children.link(coll)
    bpy.ops.mesh.primitive_cube_add(size=0.3, location=(0.0, 0.0, 0.0))
    cube = bpy.context.object
    for c in cube.users_collection:
        c.objects.unlink(cube)
    coll.objects.link(cube)
    bpy.context.view_layer.layer_collection.children["inst"].exclude = True
    for x in (-0.5, 0.6):
        empty = bpy.data.objects.new(f"inst{x}", None)
        empty.instance_type = "COLLECTION"
        empty.instance_collection = coll
        empty.location = (x, 0.8, -1.5)
        empty.rotation_euler = (0.3, 0.2, x)
        bpy.context.scene.collection.objects.link(empty)
    scenes.camera(focus=2.0, fstop=2.0, sensor_width=24.0, model="exact")
    bpy.context.view_layer.update()
    return bpy.context.scene, bpy.context.evaluated_depsgraph_get()


def _rays(n=20000, seed=3):
    rng = np.random.default_rng(seed)
    o = np.zeros((n, 3)) + rng.normal(0.0, 0.05, (n, 3))
    d = np.stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.9, 0.9, n), -np.ones(n)], axis=1)
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_01_same_hits_ray_for_ray():
    """20 000 rays into a scene with modifiers, smooth shading and collection instances: the
    same rays hit, on the same original object and polygon, at the same point (1e-4 of the
    distance) with the same face normal (within 1e-3), and the same shadow rays are blocked."""
    scene, dg = _scene()
    o, d = _rays()
    ref = SceneCaster(scene, dg)
    emb = EmbreeCaster(dg)
    assert emb.triangles > 1000
    a, b = ref.closest(o, d), emb.closest(o, d)
    assert a.ray.size > 5000
    same = np.intersect1d(a.ray, b.ray)
    assert same.size >= 0.999 * max(a.ray.size, b.ray.size)       # edge rays may round apart
    ia, ib = np.searchsorted(a.ray, same), np.searchsorted(b.ray, same)
    obj_a = np.array([ref.objects[i].name for i in a.object[ia]])
    obj_b = np.array([emb.objects[i].name for i in b.object[ib]])
    agree = (obj_a == obj_b) & (a.polygon[ia] == b.polygon[ib])
    assert agree.mean() >= 0.999, agree.mean()
    dist = np.linalg.norm(a.location[ia] - o[same], axis=1)
    np.testing.assert_allclose(b.location[ib][agree], a.location[ia][agree],
                               atol=1e-4 * dist.max())
    dots = np.abs(np.einsum("ij,ij->i", a.normal[ia], b.normal[ib]))[agree]
    assert np.quantile(dots, 0.999) > 0.999 and dots.min() > 0.9
    t = np.full(o.shape[0], 1.5)
    occ_a, occ_b = ref.occluded(o, d, t), emb.occluded(o, d, t)
    assert occ_a.sum() > 100 and (occ_a == occ_b).mean() >= 0.999


def test_02_both_backends_render_the_same_image(tmp_path):
    """The engine through Embree and through Blender's BVH, same seed: the same image within
    float noise (mean within 0.5 %, 99 % of pixels within 1e-3 of the brightest), and the
    stats name the backend."""
    from neurolens_addon.blender.render_engine import LAST
    _scene()
    bpy.ops.object.light_add(type="SUN", rotation=(0.5, 0.3, 0.0))
    imgs = {}
    for backend in ("BLENDER", "EMBREE"):
        ch = scenes.render(tmp_path / f"{backend}.exr", 48, 32, 4, intersector=backend)
        imgs[backend] = np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1)
        assert LAST["stats"].intersector == backend.lower()
    a, b = imgs["BLENDER"], imgs["EMBREE"]
    assert a.mean() > 0.01
    assert abs(b.mean() / a.mean() - 1.0) < 0.005
    assert np.quantile(np.abs(a - b), 0.99) < 1e-3 * a.max()


def test_03_auto_picks_embree_and_blender_stays_available():
    scene, dg = _scene()
    notes = []
    assert make_caster(scene, dg, "AUTO", notes=notes).backend == "embree" and not notes
    assert make_caster(scene, dg, "BLENDER").backend == "blender"
    with pytest.raises(ValueError, match="intersector"):
        make_caster(scene, dg, "optix")
