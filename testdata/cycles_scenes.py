"""Scenes built in code, rendered headless with real Cycles, read back as float arrays."""

from __future__ import annotations

import math
import os
import time

import bpy
import numpy as np

from neurolens_addon.blender.cycles_camera import ensure_osl_query_path, use_cycles_cpu

ensure_osl_query_path()


def empty_scene(width: int, height: int, samples: int, *, seed: int = 0, threads: int = 2):
    """A factory-empty scene rendered by Cycles on the CPU: no denoising, box-free defaults
    except what the caller sets; returns (scene, camera object)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    use_cycles_cpu(scene)
    c = scene.cycles
    c.samples = samples
    c.seed = seed
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.max_bounces = 1
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    data = bpy.data.cameras.new("Camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = 36.0
    data.clip_start = 1e-4
    data.clip_end = 1000.0
    cam = bpy.data.objects.new("Camera", data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return scene, cam


def world(scene, color=(0.0, 0.0, 0.0), strength: float = 1.0):
    w = bpy.data.worlds.new("World")
    scene.world = w
    bg = w.node_tree.nodes["Background"]
    bg.inputs[0].default_value = (*color, 1.0)
    bg.inputs[1].default_value = strength
    return w


def emission_material(name: str, color, strength: float = 1.0):
    m = bpy.data.materials.new(name)
    nt = m.node_tree
    nt.nodes.clear()
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs[0].default_value = (*color, 1.0)
    em.inputs[1].default_value = strength
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs[0], out.inputs[0])
    return m


def diffuse_material(name: str, color):
    m = bpy.data.materials.new(name)
    bsdf = m.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.6
    return m


def mesh_object(scene, name: str, verts, faces, material=None):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    me.update()
    ob = bpy.data.objects.new(name, me)
    if material is not None:
        me.materials.append(material)
    scene.collection.objects.link(ob)
    return ob


def uv_sphere(scene, name: str, center, radius: float, material=None, segments: int = 24):
    verts, faces = [], []
    rings = segments // 2
    for i in range(rings + 1):
        th = math.pi * i / rings
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts.append((center[0] + radius * math.sin(th) * math.cos(ph),
                          center[1] + radius * math.sin(th) * math.sin(ph),
                          center[2] + radius * math.cos(th)))
    for i in range(rings):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            faces.append((a, b, b + segments, a + segments))
    ob = mesh_object(scene, name, verts, faces, material)
    for p in ob.data.polygons:
        p.use_smooth = True
    return ob


def render(scene, path) -> tuple[np.ndarray, float]:
    """Render the still to an EXR at `path`; (RGBA float32 (H, W, 4), row 0 at the top,
    seconds the render call took)."""
    import OpenEXR
    scene.render.filepath = str(path)
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    dt = time.perf_counter() - t0
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGBA" in ch:
            img = np.asarray(ch["RGBA"].pixels, dtype=np.float32)
        else:
            img = np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGBA"], -1)
    os.remove(str(path))
    return img, dt


def look_down_minus_y(cam, location=(0.0, 0.0, 0.0)):
    """Point the camera along world +Y (Blender cameras look down their local -Z)."""
    cam.location = location
    cam.rotation_euler = (math.pi / 2, 0.0, 0.0)


def ssim(a: np.ndarray, b: np.ndarray, data_range: float | None = None, win: int = 7) -> float:
    """Mean structural similarity of two greyscale images (Wang et al. 2004), uniform
    win x win windows, constants K1 = 0.01, K2 = 0.03."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    L = data_range if data_range is not None else max(a.max(), b.max()) - min(a.min(), b.min())
    c1, c2 = (0.01 * L) ** 2, (0.03 * L) ** 2

    def box(x):
        c = np.cumsum(np.cumsum(np.pad(x, ((1, 0), (1, 0))), 0), 1)
        return (c[win:, win:] - c[:-win, win:] - c[win:, :-win] + c[:-win, :-win]) / win ** 2

    mu_a, mu_b = box(a), box(b)
    va = box(a * a) - mu_a ** 2
    vb = box(b * b) - mu_b ** 2
    cov = box(a * b) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (va + vb + c2))
    return float(s.mean())


def luminance(img: np.ndarray) -> np.ndarray:
    return img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])


def spheres_scene(width, height, samples, seed=3):
    """Three diffuse spheres at 1.5-3 m before an emissive checker wall, a sun and a sky."""
    scene, cam = empty_scene(width, height, samples, seed=seed)
    world(scene, (0.2, 0.25, 0.3))
    look_down_minus_y(cam)
    for i, (x, y, c) in enumerate([(-0.6, 1.5, (1, 0.2, 0.1)), (0.0, 2.0, (0.1, 1, 0.2)),
                                   (0.7, 3.0, (0.2, 0.3, 1))]):
        uv_sphere(scene, f"ball{i}", (x, y, 0.0), 0.25, diffuse_material(f"m{i}", c))
    verts, faces, n = [], [], 8
    for i in range(n):
        for j in range(n):
            if (i + j) % 2:
                continue
            x0, z0, k = -2 + 4 * i / n, -1.5 + 3 * j / n, len(verts)
            verts += [(x0, 4, z0), (x0 + 4 / n, 4, z0), (x0 + 4 / n, 4, z0 + 3 / n),
                      (x0, 4, z0 + 3 / n)]
            faces.append((k, k + 1, k + 2, k + 3))
    mesh_object(scene, "wall", verts, faces, emission_material("wall", (1, 1, 1), 2.0))
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 3.0
    ob = bpy.data.objects.new("sun", sun)
    ob.rotation_euler = (0.6, 0.2, 0.0)
    scene.collection.objects.link(ob)
    return scene, cam


def lit_wall(colours, width: int, height: int, samples: int):
    """A grey diffuse wall 2 m along +Y before the camera (looking down +Y), lit by one area
    light per colour from just behind the camera (lights hidden from camera rays)."""
    scene, cam = empty_scene(width, height, samples, seed=1)
    look_down_minus_y(cam)
    mesh_object(scene, "wall", [(-3, 2, -3), (3, 2, -3), (3, 2, 3), (-3, 2, 3)], [(0, 1, 2, 3)],
                diffuse_material("grey", (0.5, 0.5, 0.5)))
    for i, colour in enumerate(colours):
        light = bpy.data.lights.new(f"l{i}", "AREA")
        light.energy, light.size, light.color = 300.0, 3.0, colour
        ob = bpy.data.objects.new(f"l{i}", light)
        ob.location = (0.5 - i, -0.5, 0.0)
        ob.rotation_euler = (math.pi / 2, 0.0, 0.0)     # its emitting -Z along +Y
        ob.visible_camera = False
        scene.collection.objects.link(ob)
    return scene, cam
