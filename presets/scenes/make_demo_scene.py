"""Build presets/scenes/demo.blend, the scene `make demo` renders through the double Gauss.

    python presets/scenes/make_demo_scene.py [OUT.blend]

A table-top: a checkerboard floor (a 2 x 2 image texture through scaled UVs, 15 cm squares), a
red sphere in focus 1.6 m from the camera, a glossy blue cube in front of it, a gold metal
sphere and a white cylinder behind, a sun and a soft point light, a dark blue-grey world, and
small bright emitters 6-10 m away that the lens turns into bokeh discs (cat's eyes towards
the corners). The camera carries the NeuroLens custom properties (lens preset, learned model),
focus 1.6 m, f/2, a 32 mm wide film (its half diagonal stays inside the learned lens's
domain); 480 x 270 pixels; `make demo` asks for 16 samples per pixel.
Everything is built from code, so the .blend stays small and can be regenerated at any time.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import bpy

HERE = Path(__file__).resolve().parent


def principled(name, base, metallic=0.0, roughness=0.5, emission=None, strength=0.0):
    m = bpy.data.materials.new(name)
    nt = m.node_tree if m.node_tree is not None else _nodes(m)
    b = nt.nodes.get("Principled BSDF")
    b.inputs["Base Color"].default_value = (*base, 1.0)
    b.inputs["Metallic"].default_value = metallic
    b.inputs["Roughness"].default_value = roughness
    if emission is not None:
        b.inputs["Emission Color"].default_value = (*emission, 1.0)
        b.inputs["Emission Strength"].default_value = strength
    m.diffuse_color = (*base, 1.0)
    return m


def _nodes(m):
    m.use_nodes = True                      # Blender < 5 only
    return m.node_tree


def checker_material():
    img = bpy.data.images.new("checker_2x2", 2, 2, alpha=False)
    dark, light = 0.05, 0.8
    img.pixels = [light, light, light, 1, dark, dark, dark, 1,
                  dark, dark, dark, 1, light, light, light, 1]
    img.pack()
    m = principled("checker", (0.8, 0.8, 0.8), roughness=0.6)
    nt = m.node_tree
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.interpolation = "Closest"
    tex.extension = "REPEAT"
    nt.links.new(tex.outputs["Color"], nt.nodes["Principled BSDF"].inputs["Base Color"])
    return m


def add(obj_op, material, **kw):
    obj_op(**kw)
    ob = bpy.context.object
    ob.data.materials.append(material)
    return ob


def build():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    # floor: 24 x 24 m, UVs scaled so the 2 x 2 image repeats into 0.15 m squares
    floor = add(bpy.ops.mesh.primitive_plane_add, checker_material(), size=24.0,
                location=(0.0, 8.0, 0.0))
    for loop in floor.data.uv_layers.active.data:
        loop.uv = (loop.uv[0] * 80.0, loop.uv[1] * 80.0)

    def sphere(material, radius, location):
        ob = add(bpy.ops.mesh.primitive_uv_sphere_add, material, radius=radius,
                 location=location, segments=48, ring_count=24)
        bpy.ops.object.shade_smooth()
        return ob

    sphere(principled("red", (0.8, 0.08, 0.05), roughness=0.45), 0.12, (0.0, 0.0, 0.12))
    sphere(principled("gold", (1.0, 0.77, 0.34), metallic=1.0, roughness=0.2), 0.15,
           (0.42, 0.9, 0.15))
    cube = add(bpy.ops.mesh.primitive_cube_add,
               principled("blue", (0.05, 0.2, 0.8), roughness=0.15), size=0.16,
               location=(-0.3, -0.22, 0.08))
    cube.rotation_euler = (0.0, 0.0, math.radians(30))
    add(bpy.ops.mesh.primitive_cylinder_add, principled("white", (0.85, 0.85, 0.85)),
        radius=0.07, depth=0.36, location=(-0.32, 1.5, 0.18), vertices=48)
    bpy.ops.object.shade_smooth()

    # small bright emitters far behind the focus: bokeh discs
    glow = principled("glow", (0.0, 0.0, 0.0), emission=(1.0, 0.85, 0.6), strength=10.0)
    for x, y, z in [(-1.9, 6.0, 0.5), (-1.0, 7.5, 0.9), (-0.2, 6.5, 0.35), (0.7, 8.0, 0.8),
                    (1.5, 6.8, 0.45), (2.3, 8.5, 1.1), (-2.6, 8.5, 1.0), (0.25, 9.0, 1.25)]:
        sphere(glow, 0.06, (x, y, z))

    bpy.ops.object.light_add(type="SUN", location=(0, 0, 5),
                             rotation=(math.radians(55), 0.0, math.radians(-40)))
    sun = bpy.context.object.data
    sun.energy = 2.5
    sun.angle = math.radians(3.0)
    bpy.ops.object.light_add(type="POINT", location=(-0.8, -0.9, 1.0))
    pt = bpy.context.object.data
    pt.energy = 40.0
    pt.shadow_soft_size = 0.1

    world = bpy.data.worlds.new("sky")
    scene.world = world
    world.color = (0.05, 0.06, 0.09)
    if world.node_tree is not None:
        bg = world.node_tree.nodes.get("Background")
        if bg is not None:
            bg.inputs["Color"].default_value = (0.05, 0.06, 0.09, 1.0)
            bg.inputs["Strength"].default_value = 1.0

    bpy.ops.object.camera_add(location=(0.0, -1.6, 0.32))
    cam = bpy.context.object
    target = (0.05, 0.0, 0.17)
    d = [t - c for t, c in zip(target, cam.location)]
    cam.rotation_euler = (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0,
                          -math.atan2(d[0], d[1]))
    scene.camera = cam
    cd = cam.data
    cd.sensor_fit = "HORIZONTAL"
    cd.sensor_width = 32.0
    cd.lens = 50.0
    cd.dof.use_dof = True
    cd.dof.focus_distance = 1.6
    cd.dof.aperture_fstop = 2.0
    cd["neurolens_lens"] = "double_gauss_50mm_f2"
    cd["neurolens_model"] = "learned"

    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 480, 270, 100
    scene.view_settings.view_transform = "Standard"
    return scene


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else HERE / "demo.blend"
    build()
    bpy.context.preferences.filepaths.save_version = 0      # no OUT.blend1 backup
    bpy.ops.wm.save_as_mainfile(filepath=str(out.resolve()), compress=True)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
