"""The scenes on which the NEUROLENS engine and Cycles (with the project's exact OSL camera)
must estimate the same image: the demo scene, a glass and metal still life under an area
light, an environment-lit scene whose small bright texels defocus into bokeh, the still
life on a floor of a million triangles (for speed), and far lights in the dark seen through a
zoom lens focused near (their defocus discs: the stop each renderer uses). Each is
written as a .blend (with its environment image beside it) for the command line to render
with either engine; the light-path limits are the scene's, so both bounce light alike."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import bpy

from presets.scenes.make_demo_scene import principled

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "presets" / "scenes" / "demo.blend"
#: (name, lens preset, focus in metres, f-number) of each scene's camera
CAMERAS = {"demo": ("double_gauss_50mm_f2", 1.6, 2.0),
           "still_life": ("double_gauss_50mm_f2", 1.35, 2.8),
           "environment": ("double_gauss_50mm_f2", 0.9, 2.0),
           "million": ("double_gauss_50mm_f2", 1.35, 2.8),
           "far_lights": ("zoom_rf_24_70mm_f2_8", 0.5, 2.8),
           "backlit_street": ("double_gauss_50mm_f2", 12.0, 8.0)}
#: backlit_street: the sun's elevation and its azimuth off the street's axis (degrees)
STREET_SUN_ELEVATION, STREET_SUN_AZIMUTH = 6.0, 5.0
#: backlit_street's regions in its image (row 0 at the top): (rows, columns) as fractions
STREET_REGIONS = {"frame": ((0.0, 1.0), (0.0, 1.0)),
                  "sunlit ground": ((0.75, 1.0), (0.35, 0.65)),
                  "sunlit wall": ((0.0, 0.3), (0.8, 1.0))}
#: every scene camera's sensor width (mm, fitted horizontally)
SENSOR_WIDTH_MM = 32.0
#: far_lights: the spheres' radius, their distance and their spacing (m)
FAR_SPHERE, FAR_DISTANCE, FAR_SPACING = 0.25, 40.0, 6.0


def _camera(location, target, focus, fstop, lens="double_gauss_50mm_f2"):
    bpy.ops.object.camera_add(location=location)
    cam = bpy.context.object
    d = [t - c for t, c in zip(target, location)]
    cam.rotation_euler = (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0,
                          -math.atan2(d[0], d[1]))
    bpy.context.scene.camera = cam
    cd = cam.data
    cd.sensor_fit, cd.sensor_width, cd.lens = "HORIZONTAL", SENSOR_WIDTH_MM, 50.0
    cd.dof.use_dof, cd.dof.focus_distance, cd.dof.aperture_fstop = True, focus, fstop
    cd["neurolens_lens"] = lens
    cd["neurolens_model"] = "exact"
    return cam


def _light_paths(total, diffuse, glossy, transmission):
    c = bpy.context.scene.cycles
    c.max_bounces, c.diffuse_bounces = total, diffuse
    c.glossy_bounces, c.transmission_bounces = glossy, transmission
    # Cycles' Filter Glossy roughens sharp glass and mirrors after a diffuse bounce (caustics
    # converge faster, with bias); the engine does not: compare the unbiased estimates
    c.blur_glossy = 0.0


def _world_colour(rgb):
    w = bpy.data.worlds.new("world")
    bpy.context.scene.world = w
    w.color = rgb
    bg = w.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (*rgb, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    return w


def _sphere(material, radius, location):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location, segments=64,
                                         ring_count=32)
    ob = bpy.context.object
    ob.data.materials.append(material)
    bpy.ops.object.shade_smooth()
    return ob


def still_life():
    """A clear glass sphere, a gold sphere and a red box on a grey floor before a wall, under
    one rectangular area light; a dim grey world."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.view_settings.view_transform = "Standard"
    _world_colour((0.02, 0.02, 0.025))
    bpy.ops.mesh.primitive_plane_add(size=8.0)
    bpy.context.object.data.materials.append(principled("floor", (0.5, 0.5, 0.5),
                                                        roughness=0.6))
    bpy.ops.mesh.primitive_plane_add(size=8.0, location=(0.0, 1.2, 2.0),
                                     rotation=(math.radians(90), 0.0, 0.0))
    bpy.context.object.data.materials.append(principled("wall", (0.7, 0.65, 0.6),
                                                        roughness=0.8))
    glass = principled("glass", (1.0, 1.0, 1.0), roughness=0.0)
    b = glass.node_tree.nodes["Principled BSDF"]
    b.inputs["Transmission Weight"].default_value = 1.0
    b.inputs["IOR"].default_value = 1.45
    _sphere(glass, 0.16, (-0.2, 0.0, 0.16))
    _sphere(principled("gold", (1.0, 0.77, 0.34), metallic=1.0, roughness=0.25), 0.14,
            (0.22, 0.25, 0.14))
    bpy.ops.mesh.primitive_cube_add(size=0.16, location=(0.05, -0.25, 0.08),
                                    rotation=(0.0, 0.0, math.radians(25)))
    bpy.context.object.data.materials.append(principled("red", (0.7, 0.06, 0.04),
                                                        roughness=0.4))
    bpy.ops.object.light_add(type="AREA", location=(-0.6, -0.5, 1.4),
                             rotation=(math.radians(30), math.radians(-25), 0.0))
    area = bpy.context.object.data
    area.shape, area.size, area.size_y, area.energy = "RECTANGLE", 0.8, 0.4, 25.0
    _camera((0.0, -1.3, 0.5), (0.0, 0.05, 0.12), *CAMERAS["still_life"][1:])
    _light_paths(8, 4, 4, 8)
    return scene


def environment_image(width=512, height=256, seed=3) -> np.ndarray:
    """(H, W, 3) float radiance, row 0 at the bottom: a dusk sky (blue above, warm near the
    horizon), a dark ground, and a few hundred small lights of 20 to 200 below and just above
    the horizon, the kind of texels that defocus into bokeh discs."""
    rng = np.random.default_rng(seed)
    v = (np.arange(height) + 0.5) / height
    elev = np.pi * (v - 0.5)
    sky = np.where(elev[:, None] > 0,
                   np.array([0.15, 0.22, 0.45]) * (0.3 + 0.7 * np.sin(np.maximum(elev, 0)))[:, None]
                   + np.array([0.35, 0.18, 0.08]) * np.exp(-np.maximum(elev, 0) / 0.15)[:, None],
                   np.array([0.03, 0.03, 0.03]))
    img = np.repeat(sky[:, None, :], width, axis=1)
    rows = rng.integers(int(height * 0.42), int(height * 0.56), 300)
    cols = rng.integers(0, width, 300)
    warm = rng.random(300)[:, None]
    colour = warm * np.array([1.0, 0.7, 0.35]) + (1 - warm) * np.array([0.7, 0.85, 1.0])
    img[rows, cols] = colour * rng.uniform(20.0, 200.0, 300)[:, None]
    return img.astype(np.float32)


def environment(folder: Path):
    """A chrome sphere and a glossy white sphere on a dark floor in front of the camera,
    lit by environment_image() alone (saved as an OpenEXR file in `folder`)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.view_settings.view_transform = "Standard"
    px = environment_image()
    h, w = px.shape[:2]
    img = bpy.data.images.new("dusk", w, h, float_buffer=True)
    img.pixels.foreach_set(np.concatenate([px, np.ones((h, w, 1), np.float32)], 2).ravel())
    path = Path(folder) / "dusk.exr"
    img.filepath_raw = str(path)
    img.file_format = "OPEN_EXR"
    img.save()
    img.source = "FILE"
    img.colorspace_settings.name = "Linear Rec.709"      # radiance, as HDR files load
    world = _world_colour((0.0, 0.0, 0.0))
    tree = world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    bpy.context.object.data.materials.append(principled("ground", (0.2, 0.2, 0.22),
                                                        roughness=0.5))
    _sphere(principled("chrome", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.05), 0.15,
            (-0.12, 0.0, 0.15))
    _sphere(principled("porcelain", (0.85, 0.85, 0.8), roughness=0.2), 0.12,
            (0.2, 0.15, 0.12))
    _camera((0.0, -0.85, 0.25), (0.0, 0.0, 0.22), *CAMERAS["environment"][1:])
    _light_paths(4, 2, 4, 4)
    return scene


def backlit_street():
    """A street against a low sun: a dark rough ground (Principled base 0.05, roughness 1.0)
    between two walls 4 m high (roughness 0.5), the sun STREET_SUN_ELEVATION degrees above
    the horizon in front of the camera, turned STREET_SUN_AZIMUTH degrees off the street so
    that the right wall takes it at 85 degrees from its normal, the left wall and the left of
    the ground are in shade; a dim sky. Most of the ground's light and the sunlit wall's is
    the GGX lobe at grazing incidence scattered forwards to the camera: the case where the
    lobe's masking-shadowing decides the image (microfacet.py)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.view_settings.view_transform = "Standard"
    _world_colour((0.01, 0.012, 0.018))
    bpy.ops.mesh.primitive_plane_add(size=60.0, location=(0.0, 20.0, 0.0))
    bpy.context.object.data.materials.append(principled("asphalt", (0.05, 0.05, 0.05),
                                                        roughness=1.0))
    wall = principled("wall", (0.35, 0.3, 0.25), roughness=0.5)
    for x, turn in ((-4.0, 90.0), (4.0, -90.0)):
        bpy.ops.mesh.primitive_plane_add(size=1.0, location=(x, 20.0, 2.0),
                                         rotation=(0.0, math.radians(turn), 0.0))
        bpy.context.object.scale = (4.0, 40.0, 1.0)
        bpy.context.object.data.materials.append(wall)
    # the sun's light travels along its local -Z: tilted back towards the camera (-Y)
    bpy.ops.object.light_add(type="SUN", rotation=(math.radians(-(90.0 - STREET_SUN_ELEVATION)),
                                                   0.0, math.radians(STREET_SUN_AZIMUTH)))
    bpy.context.object.data.energy = 5.0
    _camera((0.0, -2.0, 1.6), (0.0, 12.0, 0.6), *CAMERAS["backlit_street"][1:])
    _light_paths(4, 2, 2, 2)
    return scene


def million():
    """The still life on a rippled floor of a million triangles (a 708 x 708 grid, shaded
    smooth): the scene where ray casting, not shading, would dominate a renderer's time."""
    scene = still_life()
    floor = next(o for o in scene.objects if o.type == "MESH"
                 and o.data.materials[0].name == "floor")
    bpy.data.objects.remove(floor)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=709, y_subdivisions=709, size=8.0)
    grid = bpy.context.object
    mesh = grid.data
    co = np.empty(3 * len(mesh.vertices), np.float64)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    r = np.hypot(co[:, 0], co[:, 1] + 0.3)
    co[:, 2] = 0.004 * np.sin(60.0 * r) - 0.004    # ripples below the objects' contact
    mesh.vertices.foreach_set("co", co.ravel())
    mesh.update()
    mesh.materials.append(bpy.data.materials["floor"])
    bpy.ops.object.shade_smooth()
    return scene


def far_lights():
    """Three small emissive spheres 40 m in front of the camera, in a row across the middle
    of the frame, in a black world; the camera (CAMERAS["far_lights"]) focuses at 0.5 m, so
    each light is its defocus disc: the image of the stop."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.view_settings.view_transform = "Standard"
    _world_colour((0.0, 0.0, 0.0))
    glow = bpy.data.materials.new("glow")
    tree = glow.node_tree
    tree.nodes.clear()
    em = tree.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1.0e3
    tree.links.new(em.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs[0])
    for x in (-FAR_SPACING, 0.0, FAR_SPACING):
        _sphere(glow, FAR_SPHERE, (x, FAR_DISTANCE, 0.0))
    _camera((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), *CAMERAS["far_lights"][1:],
            lens=CAMERAS["far_lights"][0])
    _light_paths(0, 0, 0, 0)
    # the engine's pixel: a box one pixel wide
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BOX", 1.0
    return scene


def middle_light_rms_px(img: np.ndarray, focal_mm: float) -> float:
    """The far_lights frame's middle light: the RMS radius (pixels) of its light about its
    centroid, over the columns within half the lights' spacing of the frame's middle."""
    from testdata.light_shape import spread_px
    lum = img @ np.array([0.2126, 0.7152, 0.0722])
    pitch = SENSOR_WIDTH_MM / lum.shape[1]
    half = 0.5 * focal_mm * FAR_SPACING / FAR_DISTANCE / pitch
    c = lum.shape[1] // 2
    return float(np.hypot(*spread_px(lum[:, int(c - half):int(c + half) + 1])))


def far_light_prediction(focal_mm: float, width_px: int, height_px: int) -> dict:
    """What the exact trace predicts for the far_lights camera at a focal length: the
    resolved set-up's f-number and stop radius, and the middle light's RMS radius in pixels:
    a point FAR_DISTANCE away traced from the scene through the derived camera's lens and
    stop onto its sensor plane, its spot's RMS radius combined in quadrature with the sphere's
    own image (a uniform disc of radius f tan(asin(r / d)), RMS radius / sqrt(2))."""
    from neurolens_addon.camera import CameraSettings, resolve_camera
    from neurolens_addon.camera.lenses import PRESETS_DIR
    from neurolens_addon.core.film import FilmSettings
    from neurolens_addon.core.rays import Rays
    from neurolens_addon.core.trace import trace
    lens_name, focus_m, fstop = CAMERAS["far_lights"]
    setup = resolve_camera(CameraSettings(
        camera="cam", lens_path=str(PRESETS_DIR / f"{lens_name}.toml"), model="exact",
        f_number=fstop, focus_distance_mm=1000.0 * focus_m, zoom_mm=focal_mm,
        dispersion=False, film=FilmSettings(sensor_width=SENSOR_WIDTH_MM,
                                            sensor_fit="HORIZONTAL", resolution_x=width_px,
                                            resolution_y=height_px)))
    c = setup.derived
    n = 200_000
    rng = np.random.default_rng(0)
    front = c.lens.surfaces[0].semi_diameter_mm
    r, phi = front * np.sqrt(rng.random(n)), 2.0 * np.pi * rng.random(n)
    z0 = 1000.0 * FAR_DISTANCE
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, c.lens.vertex_z[0] - z0)])
    d /= np.linalg.norm(d, axis=0)
    o = np.tile(np.array([[0.0], [0.0], [z0]]), (1, n))
    res = trace(c.lens, Rays(o, d, np.full(n, 587.5618)), from_sensor=False,
                sensor_z=c.sensor_z_mm, stop_radius=c.stop_radius_mm)
    x, y = res.rays.o[0, res.valid], res.rays.o[1, res.valid]
    spot = math.sqrt(((x - x.mean()) ** 2 + (y - y.mean()) ** 2).mean())
    sphere = setup.entry.efl_mm * math.tan(math.asin(FAR_SPHERE / FAR_DISTANCE))
    return {"f_number": c.f_number, "stop_radius_mm": c.stop_radius_mm,
            "rms_radius_px": math.hypot(spot, sphere / math.sqrt(2.0)) / (SENSOR_WIDTH_MM /
                                                                          width_px)}


def write(name: str, folder: Path, bounces: int | None = None) -> Path:
    """The named scene as a .blend in `folder` (the demo: a copy), its light-path total set
    to `bounces` when given."""
    folder = Path(folder)
    if name == "demo":
        bpy.ops.wm.open_mainfile(filepath=str(DEMO))
    elif name == "still_life":
        still_life()
    elif name == "environment":
        environment(folder)
    elif name == "million":
        million()
    elif name == "far_lights":
        far_lights()
    elif name == "backlit_street":
        backlit_street()
    else:
        raise ValueError(f"no agreement scene {name!r}")
    if bounces is not None:
        bpy.context.scene.cycles.max_bounces = bounces
    out = folder / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out), copy=True)
    return out
