"""Scenes for the lights' flare (engine.flare): a point lamp in the dark, a night street of
lamps, a sun in frame, and a disc of light twice (an area lamp, and an emissive mesh of the same
radiance: the camera-side ghosts see the mesh, light tracing the lamp). Each camera has ghosts
on (bare glass: the brightest ghosts), written as a .blend for the command line or opened in
this process."""

from __future__ import annotations

import math
from pathlib import Path

import bpy

from .agreement_scenes import _camera, _light_paths, _world_colour
from presets.scenes.make_demo_scene import principled

#: (lens preset, focus in metres, f-number) of the scenes' camera
CAMERA = ("double_gauss_50mm_f2", 6.0, 4.0)
#: the disc of light: radius (m), radiance (W / m^2 / sr), its centre (facing the camera)
DISC_RADIUS, DISC_RADIANCE = 0.3, 50.0
DISC_AT = (0.8, 8.0, 0.4)


def _empty(world=(0.0, 0.0, 0.0)):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.view_settings.view_transform = "Standard"
    _world_colour(world)
    return scene


def _ghost_camera(location, target, lens=CAMERA[0], focus=CAMERA[1], fstop=CAMERA[2],
                  coating="bare"):
    cam = _camera(location, target, focus, fstop, lens=lens)
    cd = cam.data
    cd["neurolens_ghosts"] = 1
    cd["neurolens_coating"] = coating
    props = getattr(cd, "neurolens", None)     # the add-on's panel, where it is registered
    if props is not None:
        props.ghosts, props.coating = True, coating.upper()
    return cam


def _lamp(kind, location, power, **kw):
    bpy.ops.object.light_add(type=kind, location=location, rotation=kw.pop("rotation",
                                                                           (0, 0, 0)))
    light = bpy.context.object
    light.data.energy = power
    for k, v in kw.items():
        setattr(light.data, k, v)
    return light


def point_lamp(lens=CAMERA[0]):
    """One point lamp (1 kW, radius 2 cm) 8 m ahead, a little off axis, in a black world: the
    frame holds nothing but the lamp's flare (camera rays never meet a lamp)."""
    scene = _empty()
    _lamp("POINT", (0.5, 8.0, 0.3), 1000.0, shadow_soft_size=0.02)
    _ghost_camera((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), lens=lens)
    _light_paths(0, 0, 0, 0)
    return scene


def night_street(lamps: int = 4):
    """`lamps` street lamps (point lamps, 400 W, 3 m up, in two rows along the street, 5 m
    ahead and on) over a dark rough ground and a wall, in a dim night sky: lamps in frame
    light the scene and flare."""
    scene = _empty((0.002, 0.003, 0.006))
    bpy.ops.mesh.primitive_plane_add(size=80.0, location=(0.0, 30.0, 0.0))
    bpy.context.object.data.materials.append(principled("asphalt", (0.08, 0.08, 0.08),
                                                        roughness=0.9))
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(4.0, 30.0, 2.0),
                                     rotation=(0.0, math.radians(-90.0), 0.0))
    bpy.context.object.scale = (4.0, 60.0, 1.0)
    bpy.context.object.data.materials.append(principled("wall", (0.4, 0.35, 0.3),
                                                        roughness=0.6))
    for i in range(lamps):
        side = -2.5 if i % 2 == 0 else 2.0
        _lamp("POINT", (side, 5.0 + 4.0 * (i // 2), 3.0), 400.0, shadow_soft_size=0.05,
              color=(1.0, 0.8, 0.55))
    _ghost_camera((0.0, -1.0, 1.6), (0.0, 12.0, 2.2))
    _light_paths(4, 2, 2, 2)
    return scene


def sun_in_frame():
    """A low sun (5 W/m^2, 0.5 degrees) in frame above a dark ground: the flare of the sun."""
    scene = _empty((0.02, 0.03, 0.05))
    bpy.ops.mesh.primitive_plane_add(size=200.0, location=(0.0, 50.0, 0.0))
    bpy.context.object.data.materials.append(principled("ground", (0.1, 0.1, 0.1),
                                                        roughness=0.8))
    # its light travels along its local -Z, tilted back towards the camera (-Y)
    _lamp("SUN", (0, 0, 10), 5.0, rotation=(math.radians(-80.0), 0.0, math.radians(8.0)),
          angle=math.radians(0.5))
    _ghost_camera((0.0, 0.0, 1.6), (0.0, 10.0, 2.6))
    _light_paths(4, 2, 2, 2)
    return scene


def disc_of_light(as_lamp: bool):
    """A disc of radius DISC_RADIUS and radiance DISC_RADIANCE facing the camera at DISC_AT in
    a black world: an area lamp (as_lamp; its power pi A L: engine.lights) or an emissive mesh
    disc (Emission strength L). The engine shows the lamp's ghosts by light tracing and the
    mesh's by its camera-side ghost samples: the same light, two estimators."""
    scene = _empty()
    x, y, z = DISC_AT
    # facing -Y (the camera): the lamp emits along its local -Z, the disc's normal is its +Z
    turn = (math.radians(-90.0), 0.0, 0.0)
    if as_lamp:
        area = math.pi * DISC_RADIUS ** 2
        _lamp("AREA", DISC_AT, math.pi * area * DISC_RADIANCE, rotation=turn, shape="DISK",
              size=2.0 * DISC_RADIUS)
    else:
        bpy.ops.mesh.primitive_circle_add(vertices=64, radius=DISC_RADIUS, fill_type="NGON",
                                          location=(x, y, z),
                                          rotation=(math.radians(90.0), 0.0, 0.0))
        glow = bpy.data.materials.new("glow")
        tree = glow.node_tree
        tree.nodes.clear()
        em = tree.nodes.new("ShaderNodeEmission")
        em.inputs["Strength"].default_value = DISC_RADIANCE
        tree.links.new(em.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs[0])
        bpy.context.object.data.materials.append(glow)
    _ghost_camera((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    _light_paths(0, 0, 0, 0)
    return scene


#: the environment with a sun: its size (texels), the sun's texels and their radiance
SKY_SIZE, SUN_TEXELS, SUN_RADIANCE = (128, 64), ((40, 33), (41, 33), (40, 34), (41, 34)), 2.0e4


def hdr_sun():
    """A black environment image but for a sun of four bright texels, a few degrees off the
    camera's axis: a world light the camera-side ghost samples find by chance, light tracing
    by its importance sampling. The camera looks along SUN_VIEW."""
    scene = _empty()
    w, h = SKY_SIZE
    img = bpy.data.images.new("sky", w, h, float_buffer=True, alpha=False)
    px = [0.0] * (w * h * 4)
    for x, y in SUN_TEXELS:
        k = 4 * (y * w + x)
        px[k:k + 3] = [SUN_RADIANCE] * 3
    for k in range(3, len(px), 4):
        px[k] = 1.0
    img.pixels.foreach_set(px)
    world = scene.world
    tree = world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    env.interpolation = "Closest"
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    # the sun's direction (equirectangular, as engine.lights.World reads it), the camera
    # turned 4 degrees from it
    x, y = (sum(t[0] for t in SUN_TEXELS) / 4 + 0.5) / w, (sum(t[1] for t in SUN_TEXELS) / 4
                                                           + 0.5) / h
    phi, elev = 2.0 * math.pi * (0.5 - x), math.pi * (y - 0.5)
    sun = (math.cos(elev) * math.cos(phi), math.cos(elev) * math.sin(phi), math.sin(elev))
    turn = math.radians(4.0)
    view = (sun[0] * math.cos(turn) - sun[1] * math.sin(turn),
            sun[0] * math.sin(turn) + sun[1] * math.cos(turn), sun[2])
    _ghost_camera((0.0, 0.0, 0.0), view)
    _light_paths(0, 0, 0, 0)
    return scene


SCENES = {"point_lamp": point_lamp, "night_street": night_street,
          "sun_in_frame": sun_in_frame}


def write(name: str, folder: Path, **kw) -> Path:
    """The named scene (its keywords: `kw`) as a .blend in `folder`."""
    SCENES[name](**kw)
    out = Path(folder) / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out), copy=True)
    return out
