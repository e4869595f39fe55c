"""Small test scenes for the NEUROLENS engine, built in code with the bpy module, and a render
helper that goes through the real engine (bpy.ops.render.render, Blender's EXR writer) and
reads the multilayer EXR back with the OpenEXR package."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import bpy

from neurolens_addon.blender import engine_registration as registration  # noqa: E402
from neurolens_addon.blender.render_engine import LAST  # noqa: E402
from presets.scenes.make_demo_scene import principled  # noqa: E402


def reset():
    """An empty scene with a black world, the engine registered and selected."""
    registration.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    world = bpy.data.worlds.new("black")
    world.color = (0.0, 0.0, 0.0)
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    scene.world = world
    scene.render.engine = "NEUROLENS"
    scene.view_settings.view_transform = "Standard"
    return scene


def material(name, base=(0.8, 0.8, 0.8), emission=None, strength=1.0, metallic=0.0,
             roughness=0.5):
    """A Principled material, built by the demo scene's own helper."""
    return principled(name, base, metallic=metallic, roughness=roughness, emission=emission,
                      strength=strength)


def camera(location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), *, lens="double_gauss_50mm_f2",
           model="exact", focus=2.0, fstop=2.0, sensor_width=8.0):
    """A camera looking down its -Z (identity rotation: down the world's -Z)."""
    bpy.ops.object.camera_add(location=location, rotation=rotation)
    cam = bpy.context.object
    bpy.context.scene.camera = cam
    cd = cam.data
    cd.sensor_fit = "HORIZONTAL"
    cd.sensor_width = sensor_width
    cd.dof.use_dof = True
    cd.dof.focus_distance = focus
    cd.dof.aperture_fstop = fstop
    cd["neurolens_lens"] = lens
    cd["neurolens_model"] = model
    return cam


def emitter_sphere(location, radius=0.005, strength=50.0):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location, segments=16,
                                         ring_count=8)
    ob = bpy.context.object
    ob.data.materials.append(material("glow", (0, 0, 0), emission=(1, 1, 1),
                                      strength=strength))
    return ob


def checker_plane(z, size, squares, *, emissive=True):
    """A square plane at depth z (normal +Z, facing a camera at the origin looking down -Z),
    `squares` x `squares` squares alternately white-emissive and black, as polygons with two
    materials (the engine's per-polygon material table)."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=squares, y_subdivisions=squares, size=size,
                                    location=(0.0, 0.0, z))
    ob = bpy.context.object
    white = material("white", (0.8, 0.8, 0.8), emission=(1, 1, 1) if emissive else None)
    black = material("black", (0.0, 0.0, 0.0))
    ob.data.materials.append(white)
    ob.data.materials.append(black)
    half = size / 2.0
    for poly in ob.data.polygons:
        cx, cy = poly.center[0] + half, poly.center[1] + half
        i, j = int(cx / size * squares), int(cy / size * squares)
        poly.material_index = (i + j) % 2
    return ob


def read_exr(path) -> dict:
    """{channel name without the view layer: (H, W) float32}, row 0 at the top."""
    import OpenEXR
    out = {}
    with OpenEXR.File(str(path)) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                short = name.split(".", 1)[1] if name.startswith("ViewLayer.") else name
                px = np.array(ch.pixels, dtype=np.float32)
                if px.ndim == 3:          # an RGBA part read as one channel
                    for k, c in enumerate("RGBA"[:px.shape[2]]):
                        out[f"{short}.{c}"] = px[..., k]
                else:
                    out[short] = px
    return out


def render(path: Path, width: int, height: int, samples: int, **settings) -> dict:
    """Render the scene with the NEUROLENS engine to a multilayer EXR at `path`; return its
    channels (read_exr). The engine's settings as keywords; denoising is off unless asked
    for (the tests measure the integrator's own estimate)."""
    settings.setdefault("denoise", False)
    scene = bpy.context.scene
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    props = scene.neurolens_engine
    props.samples = samples
    # the light-path limits and clamps are the scene's (Cycles' Light Paths); one bounce
    # unless asked
    scene.cycles.max_bounces = settings.pop("bounces", 1)
    for name in ("clamp_direct", "clamp_indirect"):
        if name in settings:
            setattr(scene.cycles, "sample_" + name, settings.pop(name))
    for k, v in settings.items():
        setattr(props, k, v)
    r.image_settings.media_type = "MULTI_LAYER_IMAGE"
    r.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    r.image_settings.color_depth = "32"
    r.filepath = str(path)
    LAST["stats"] = None
    bpy.ops.render.render(write_still=True)
    return read_exr(path)


def look_at_rotation(eye, target):
    d = [t - e for t, e in zip(target, eye)]
    return (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0, -math.atan2(d[0], d[1]))


def lit_wall(colours):
    """A grey wall 2 m in front of the camera, lit by one area light per colour."""
    reset()
    bpy.ops.mesh.primitive_plane_add(size=6.0, location=(0.0, 0.0, -2.0))
    bpy.context.object.data.materials.append(material("grey", (0.5, 0.5, 0.5)))
    for i, colour in enumerate(colours):
        bpy.ops.object.light_add(type="AREA", location=(0.5 - i, 0.0, 0.5))
        light = bpy.context.object.data
        light.energy, light.size, light.color = 300.0, 3.0, colour
    camera(focus=2.0, fstop=2.0, sensor_width=24.0, model="exact")


def sphere_on_plane():
    """A red sphere before a grey plane 2.5 m away, one area light, the exact double Gauss
    focused at 2 m: a small scene with edges, colour and a light (denoiser and memory tests)."""
    reset()
    bpy.ops.mesh.primitive_plane_add(size=6.0, location=(0.0, 0.0, -2.5))
    bpy.context.object.data.materials.append(material("grey", (0.6, 0.6, 0.6)))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.35, location=(0.2, 0.0, -2.0))
    bpy.context.object.data.materials.append(material("red", (0.8, 0.1, 0.1)))
    bpy.ops.object.light_add(type="AREA", location=(0.5, 0.5, 0.0))
    bpy.context.object.data.energy, bpy.context.object.data.size = 200.0, 1.0
    camera(focus=2.0, fstop=2.8, sensor_width=24.0, model="exact")
