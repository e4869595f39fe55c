"""The path tracer's parts against analytic results, and its strategies against each other.

Pure: dielectric Fresnel and refraction (Snell, energy), every light's two strategies (a light
sample and a ray that meets the light give the same radiance over density), the world's and
the emissive meshes' sampling densities. Rendered (the real engine): the world lights a
Lambertian plane as a L; multiple importance sampling changes the noise, not the image (one
bounce against light samples alone, for every kind of light and surface); glass passes
(1 - R) / (1 + R); alpha passes 1 - alpha; a transmission limit of 1 stops light in glass;
Russian roulette keeps the mean; a Principled BSDF's distribution (Multiscatter GGX or GGX)
is read.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.engine import dielectric
from neurolens_addon.engine.emitters import Emitters
from neurolens_addon.engine.lights import Light, World
from neurolens_addon.engine.textures import Texture

RNG = np.random.default_rng(5)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# -- glass

@pytest.mark.parametrize("ior", [1.33, 1.5, 1.9])
def test_01_fresnel_matches_the_normal_incidence_formula_stokes_and_total_reflection(ior):
    assert dielectric.fresnel(np.array([1.0]), np.array([ior]))[0] == pytest.approx(
        ((ior - 1) / (ior + 1)) ** 2, rel=1e-9)
    # Stokes: the same interface seen from either side reflects the same share
    ti = np.radians(np.linspace(0, 40, 9))
    tt = np.arcsin(np.sin(ti) / ior)
    np.testing.assert_allclose(dielectric.fresnel(np.cos(ti), np.full(9, ior)),
                               dielectric.fresnel(np.cos(tt), np.full(9, 1 / ior)), rtol=1e-9)
    critical = math.asin(1 / ior)
    beyond = np.cos(np.array([critical + 0.01, 1.2]))
    np.testing.assert_array_equal(dielectric.fresnel(beyond, np.full(2, 1 / ior)), 1.0)


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0])
def test_02_smooth_glass_refracts_by_snell_and_splits_light_by_fresnel(theta):
    n = 40000
    ior = 1.5
    t = math.radians(theta)
    wo = np.tile([math.sin(t), 0.0, math.cos(t)], (n, 1))
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    wi, w, refr, ok = dielectric.sample(nrm, wo, np.full(n, ior), np.zeros(n), *RNG.random((3, n)))
    assert ok.all()
    np.testing.assert_allclose(w, 1.0, atol=2e-3)
    f = dielectric.fresnel(np.array([math.cos(t)]), np.array([ior]))[0]
    assert refr.mean() == pytest.approx(1 - f, abs=0.01)
    sin_t = np.hypot(wi[refr, 0], wi[refr, 1])
    np.testing.assert_allclose(sin_t * ior, math.sin(t), atol=2e-3)
    assert (wi[refr, 2] < 0).all() and (wi[~refr, 2] > 0).all()


def test_03_rough_glass_loses_only_what_single_scattering_loses():
    n = 200000
    wo = np.tile(unit([0.3, 0.0, 1.0]), (n, 1))
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    _, w, _, ok = dielectric.sample(nrm, wo, np.full(n, 1.5), np.full(n, 0.4),
                                    *RNG.random((3, n)))
    assert 0.9 < w.mean() <= 1.01


# -- lights: a light sample and a ray meeting the light agree

LIGHTS = {
    "square": dict(kind="AREA", shape="SQUARE", size_x=0.5),
    "rectangle": dict(kind="AREA", shape="RECTANGLE", size_x=0.6, size_y=0.2),
    "disk": dict(kind="AREA", shape="DISK", size_x=0.4),
    "ellipse": dict(kind="AREA", shape="ELLIPSE", size_x=0.4, size_y=0.8),
    "sphere": dict(kind="POINT", radius=0.1),
    "spot": dict(kind="SPOT", radius=0.05, cos_half=math.cos(0.6), smooth=0.05),
    "sun": dict(kind="SUN", cos_sun=math.cos(0.05)),
}


def make_light(spec):
    return Light(colour=np.array([100.0, 80.0, 60.0]), position=np.array([0.1, -0.2, 2.0]),
                 axis_x=np.array([1.0, 0.0, 0.1]), axis_y=np.array([0.0, 1.2, 0.0]),
                 forward=unit([0.05, 0.0, -1.0]), **spec)


@pytest.mark.parametrize("name", list(LIGHTS))
def test_04_a_light_sample_and_a_ray_that_meets_the_light_agree(name):
    light = make_light(LIGHTS[name])
    n = 2000
    p = RNG.uniform(-0.5, 0.5, (n, 3)) * [1, 1, 0.2]
    wi, dist, li, pdf = light.sample(p, *RNG.random((2, n)))
    live = (pdf > 0) & (np.abs(li).max(axis=1) > 0)
    assert live.mean() > 0.5
    t, rad, pdf_hit = light.hit(p[live], wi[live], np.ones(live.sum(), dtype=bool))
    assert np.isfinite(t).all()
    if light.kind != "SUN":
        np.testing.assert_allclose(t, dist[live], rtol=1e-6)
    np.testing.assert_allclose(pdf_hit, pdf[live], rtol=1e-6)
    # Li / p of the sample is the radiance the ray meets over the same density
    np.testing.assert_allclose(li[live], rad / pdf_hit[:, None], rtol=1e-6)


def test_05_an_area_light_gives_the_irradiance_of_a_coaxial_disk():
    # a disk of radiance L and radius R at height h: E = pi L R^2 / (h^2 + R^2) on its axis
    light = Light(kind="AREA", shape="DISK", size_x=1.0, colour=np.array([10.0, 10.0, 10.0]),
                  position=np.array([0.0, 0.0, 1.0]), axis_x=np.array([1.0, 0.0, 0.0]),
                  axis_y=np.array([0.0, 1.0, 0.0]), forward=np.array([0.0, 0.0, -1.0]))
    n = 400000
    wi, _, li, _ = light.sample(np.zeros((n, 3)), *RNG.random((2, n)))
    e = (li[:, 0] * wi[:, 2]).mean()
    radiance = 10.0 / (math.pi * light.area)
    assert e == pytest.approx(math.pi * radiance * 0.25 / (1 + 0.25), rel=0.01)


def test_06_the_world_is_sampled_by_its_own_density_and_integrates_right():
    h, w = 32, 64
    px = np.full((h, w, 3), 0.1, np.float32)
    px[24:26, 10:12] = 500.0                           # a small bright sun in the sky
    world = World(texture=Texture(px, "Closest"), strength=2.0)
    n = 200000
    wi, li, pdf = world.sample(n, *RNG.random((2, n)))
    np.testing.assert_allclose(pdf, world.pdf(wi), rtol=1e-6)
    np.testing.assert_allclose(li, world.radiance(wi) / pdf[:, None], rtol=1e-5)
    # E[Li / p] = the integral of the radiance over the sphere, by quadrature on the texels
    elev = np.pi * ((np.arange(h) + 0.5) / h - 0.5)
    solid = (2 * np.pi / w) * (np.pi / h) * np.cos(elev)
    exact = 2.0 * float((px[..., 0] * solid[:, None]).sum())
    assert li[:, 0].mean() == pytest.approx(exact, rel=0.01)
    # the bright texels draw most samples: far fewer wasted than uniform sampling would
    assert (world.radiance(wi)[:, 0] > 100).mean() > 0.5


def test_07_emissive_triangles_are_sampled_by_power_with_the_density_a_hit_computes():
    corners = np.array([[[0, 0, 1], [1, 0, 1], [0, 1, 1]],
                        [[0, 0, 2], [2, 0, 2], [0, 2, 2]]], dtype=np.float64)
    emission = np.array([[4.0, 4.0, 4.0], [1.0, 1.0, 1.0]])
    em = Emitters(corners, emission)
    n = 100000
    p = np.zeros((n, 3))
    wi, dist, li, pdf = em.sample(p, *RNG.random((2, n)))
    q = p + wi * dist[:, None]
    upper = q[:, 2] > 1.5
    # power: 0.5 x 4 against 2 x 1: half the samples on each
    assert upper.mean() == pytest.approx(0.5, abs=0.01)
    e = np.where(upper[:, None], emission[1], emission[0])
    cos_l = np.abs(wi[:, 2])
    np.testing.assert_allclose(pdf, em.area_density(e) * dist ** 2 / cos_l, rtol=1e-9)
    np.testing.assert_allclose(li, e / pdf[:, None], rtol=1e-9)


# -- rendered through the real engine

bpy = pytest.importorskip("bpy")
from testdata import engine_scenes as scenes  # noqa: E402


def mean_rgb(ch):
    return np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1).mean(axis=(0, 1))


def diffuse(name, colour):
    m = bpy.data.materials.new(name)
    nodes = m.node_tree.nodes
    for node in list(nodes):
        if node.type != "OUTPUT_MATERIAL":
            nodes.remove(node)
    d = nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*colour, 1.0)
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    m.node_tree.links.new(d.outputs[0], out.inputs["Surface"])
    return m


def plane(z, material, size=6.0):
    bpy.ops.mesh.primitive_plane_add(size=size, location=(0.0, 0.0, z))
    bpy.context.object.data.materials.append(material)
    return bpy.context.object


def world_environment(pixels):
    """The world as an equirectangular float image (H, W, 3), row 0 at the bottom."""
    h, w = pixels.shape[:2]
    img = bpy.data.images.new("env", w, h, float_buffer=True)
    rgba = np.concatenate([pixels, np.ones((h, w, 1))], axis=2).astype(np.float32)
    img.pixels.foreach_set(rgba.ravel())
    tree = bpy.context.scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = img
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])


@pytest.mark.parametrize("environment", [False, True])
def test_08_the_world_lights_a_lambertian_plane_as_albedo_times_radiance(tmp_path, environment):
    """No bounce: the world's light samples alone give a L (a flat grey world L = 0.5; an
    environment bright (1) above the horizon and black below, with a small 200x sun above)."""
    settings = dict(bounces=0, dispersion=False)
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.0, diffuse("d", (0.6, 0.6, 0.6)))
    if environment:
        env = np.zeros((32, 64, 3))
        env[16:] = 1.0
        env[28, 20] = 200.0                     # sun: its light adds a cos-weighted share
        world_environment(env)
        elev = np.pi * ((28 + 0.5) / 32 - 0.5)
        solid = (2 * np.pi / 64) * (np.pi / 32) * np.cos(elev)
        expected = 0.6 * (1.0 + 199.0 * solid * np.sin(elev) / np.pi)
    else:
        bpy.context.scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (
            0.5, 0.5, 0.5, 1.0)
        expected = 0.3
    lit = mean_rgb(scenes.render(tmp_path / "lit.exr", 24, 24, 32, **settings))
    # the same camera on a plane that emits the expected radiance
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.0, scenes.material("e", (0, 0, 0), emission=(1, 1, 1), strength=expected))
    ref = mean_rgb(scenes.render(tmp_path / "ref.exr", 24, 24, 32, **settings))
    np.testing.assert_allclose(lit / ref, 1.0, atol=0.03)


def lights_and_plane(metallic, roughness):
    """A plane under an area disk, a point light with a radius, a sun with an angle and an
    emissive quad out of view."""
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.0, scenes.material("p", (0.7, 0.6, 0.5), metallic=metallic, roughness=roughness))
    bpy.ops.object.light_add(type="AREA", location=(0.6, 0.0, -1.0),
                             rotation=(0.0, math.radians(30), 0.0))
    area = bpy.context.object.data
    area.shape, area.size, area.energy = "DISK", 0.8, 60.0
    bpy.ops.object.light_add(type="POINT", location=(-0.5, 0.4, -1.2))
    bpy.context.object.data.energy, bpy.context.object.data.shadow_soft_size = 30.0, 0.2
    bpy.ops.object.light_add(type="SUN", rotation=(math.radians(20), 0.0, 0.0))
    bpy.context.object.data.energy, bpy.context.object.data.angle = 1.0, math.radians(10)
    bpy.ops.mesh.primitive_plane_add(size=0.5, location=(0.0, -0.9, -1.4),
                                     rotation=(math.radians(-60), 0.0, 0.0))
    bpy.context.object.data.materials.append(
        scenes.material("quad", (0, 0, 0), emission=(1, 1, 1), strength=8.0))


@pytest.mark.parametrize("metallic,roughness", [(0.0, 1.0), (1.0, 0.3)])
def test_09_multiple_importance_sampling_changes_the_noise_not_the_image(tmp_path, metallic,
                                                                         roughness):
    """Light samples alone (no bounce) against light samples and bounce rays weighed by the
    power heuristic (one bounce: what the bounce rays meet is only the lights): same means."""
    lights_and_plane(metallic, roughness)
    # no clamping: Clamp Indirect would cut bright lights met by bounce rays only
    alone = mean_rgb(scenes.render(tmp_path / "a.exr", 24, 24, 64, bounces=0,
                                   clamp_indirect=0.0))
    mixed = mean_rgb(scenes.render(tmp_path / "m.exr", 24, 24, 64, bounces=1,
                                   clamp_indirect=0.0))
    assert alone.min() > 0.02
    np.testing.assert_allclose(mixed / alone, 1.0, atol=0.03)


def glass_slab(material=None, transmission_bounces=12):
    """An emissive plane behind a slab 0.1 thick of material() (None: no slab)."""
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.6, scenes.material("e", (0, 0, 0), emission=(1, 1, 1), strength=1.0))
    bpy.context.scene.cycles.transmission_bounces = transmission_bounces
    if material is not None:
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, -2.0))
        slab = bpy.context.object
        slab.scale = (6.0, 6.0, 0.1)
        slab.data.materials.append(material())


def glass_material(kind):
    if kind == "principled":
        m = scenes.material("glass", (1, 1, 1), roughness=0.0)
        b = m.node_tree.nodes["Principled BSDF"]
        b.inputs["Transmission Weight"].default_value = 1.0
        b.inputs["IOR"].default_value = 1.5
        return m
    m = bpy.data.materials.new("glass")
    nodes = m.node_tree.nodes
    for node in list(nodes):
        if node.type != "OUTPUT_MATERIAL":
            nodes.remove(node)
    g = nodes.new("ShaderNodeBsdfGlass")
    g.inputs["Roughness"].default_value = 0.0
    g.inputs["IOR"].default_value = 1.5
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    m.node_tree.links.new(g.outputs[0], out.inputs["Surface"])
    return m


@pytest.mark.parametrize("kind", ["principled", "glass"])
def test_10_a_glass_slab_passes_one_minus_r_over_one_plus_r(tmp_path, kind):
    """Smooth glass of index 1.5 at (near) normal incidence: R = 0.04 a face, and with the
    light bouncing inside, (1 - R) / (1 + R) = 0.923 passes; with a transmission limit of 1
    the light that enters the slab never leaves it."""
    settings = dict(bounces=8, dispersion=False)
    glass_slab()
    bare = mean_rgb(scenes.render(tmp_path / "b.exr", 16, 16, 32, **settings))
    glass_slab(lambda: glass_material(kind))
    through = mean_rgb(scenes.render(tmp_path / "g.exr", 16, 16, 32, **settings))
    np.testing.assert_allclose(through / bare, 0.96 / 1.04, atol=0.012)
    glass_slab(lambda: glass_material(kind), transmission_bounces=1)
    stopped = mean_rgb(scenes.render(tmp_path / "s.exr", 16, 16, 32, **settings))
    assert (stopped / bare).max() < 0.01


def test_11_alpha_passes_one_minus_alpha(tmp_path):
    settings = dict(bounces=2, dispersion=False)
    glass_slab()
    bare = mean_rgb(scenes.render(tmp_path / "b.exr", 16, 16, 64, **settings))
    m = scenes.material("veil", (0.0, 0.0, 0.0))
    m.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.25
    plane(-2.0, m)
    veiled = mean_rgb(scenes.render(tmp_path / "v.exr", 16, 16, 64, **settings))
    np.testing.assert_allclose(veiled / bare, 0.75, atol=0.02)


def test_12_russian_roulette_keeps_the_mean(tmp_path):
    """Light trapped between two white planes, eight bounces: with roulette from the first
    bounce on, and without it (min light bounces 8), the same mean; roulette ends paths
    early (fewer ray casts; with Cycles' q = sqrt(throughput) paths live long at albedo
    0.8)."""
    from neurolens_addon.blender.render_engine import LAST
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.0, diffuse("floor", (0.8, 0.8, 0.8)), size=20.0)
    top = plane(0.5, diffuse("ceiling", (0.8, 0.8, 0.8)), size=20.0)
    top.rotation_euler = (math.pi, 0.0, 0.0)
    bpy.ops.object.light_add(type="POINT", location=(0.0, 0.0, -1.0))
    bpy.context.object.data.energy, bpy.context.object.data.shadow_soft_size = 50.0, 0.1
    c = bpy.context.scene.cycles
    c.diffuse_bounces = 8
    means, casts = [], []
    for min_bounces in (0, 8):
        c.min_light_bounces = min_bounces
        means.append(mean_rgb(scenes.render(tmp_path / f"r{min_bounces}.exr", 16, 16, 64,
                                            bounces=8, dispersion=False)))
        casts.append(LAST["stats"].casts)
    np.testing.assert_allclose(means[0] / means[1], 1.0, atol=0.03)
    assert casts[0] < 0.9 * casts[1]


def test_13_worker_threads_do_not_change_the_image(tmp_path):
    """Bundles shaded by two threads reach the film in order: the same image, bit for bit,
    as one thread (the random numbers belong to pixel and sample, not to a thread)."""
    lights_and_plane(0.0, 0.5)
    one = scenes.render(tmp_path / "one.exr", 24, 24, 8, bounces=2, workers=1,
                        max_bundle_rays=1024)
    two = scenes.render(tmp_path / "two.exr", 24, 24, 8, bounces=2, workers=2,
                        max_bundle_rays=1024)
    for k in one:
        np.testing.assert_array_equal(one[k], two[k], err_msg=k)


def test_14_one_colour_ray_a_sample_estimates_the_same_colour(tmp_path):
    """One lens ray a sample at a wavelength drawn across the sensor, weighted 3 s / sum s,
    and three rays (R, G, B) estimate the same image; the single ray carries colour noise."""
    scenes.lit_wall([(1.0, 1.0, 1.0)])
    three = scenes.render(tmp_path / "3.exr", 24, 16, 32, colour_rays="3")
    one = scenes.render(tmp_path / "1.exr", 24, 16, 32, colour_rays="1")
    np.testing.assert_allclose(mean_rgb(one) / mean_rgb(three), 1.0, atol=0.02)
    chroma = lambda ch: np.std(ch["Combined.R"] - ch["Combined.G"])  # noqa: E731
    assert chroma(one) > 3 * chroma(three)


def test_15_what_the_scene_uses_and_the_engine_does_not_render_is_said_once(tmp_path):
    """Motion blur, hair (a Curves object and a hair particle system) and a volume object:
    one note each, naming the objects; a plain scene gets none of them."""
    from neurolens_addon.blender.render_engine import LAST
    lights_and_plane(0.0, 0.5)
    scenes.render(tmp_path / "plain.exr", 8, 8, 1)
    assert not any("NEUROLENS engine (" in n or "motion blur" in n
                   for n in LAST["stats"].notes)
    bpy.context.scene.render.use_motion_blur = True
    bpy.ops.object.curves_empty_hair_add()
    bpy.ops.mesh.primitive_cube_add(size=0.2, location=(0.3, 0.0, -1.5))
    furry = bpy.context.object
    furry.modifiers.new("hair", "PARTICLE_SYSTEM")
    furry.particle_systems[0].settings.type = "HAIR"
    bpy.ops.object.volume_add(location=(0.0, 0.0, -1.5))
    scenes.render(tmp_path / "busy.exr", 8, 8, 1)
    notes = LAST["stats"].notes
    assert sum("motion blur" in n for n in notes) == 1
    hair = [n for n in notes if n.startswith("hair")]
    assert len(hair) == 1 and furry.name in hair[0]
    assert sum(n.startswith("volume objects") for n in notes) == 1


def test_16_a_zoom_animation_renders_each_frame_at_its_focal_length(tmp_path):
    """The engine resolves the lens every frame: frame 2 of a keyframed 50 -> 60 mm zoom
    renders as a still camera at 60 mm does, and differs from frame 1."""
    from testdata.focusing_lenses import write_zoom
    scenes.reset()
    plane(-2.0, scenes.material("e", (0, 0, 0), emission=(1, 1, 1)), size=0.1)
    cam = scenes.camera(focus=2.0, model="exact")
    cam.data["neurolens_lens"] = write_zoom(tmp_path / "zoom.toml")
    sc = bpy.context.scene
    for frame, f in ((1, 50.0), (2, 60.0)):
        cam.data.lens = f
        cam.data.keyframe_insert("lens", frame=frame)
    frames = {}
    for frame in (1, 2):
        sc.frame_set(frame)
        frames[frame] = mean_rgb(scenes.render(tmp_path / f"a{frame}.exr", 24, 24, 4,
                                               dispersion=False))
    cam.data.animation_data_clear()
    cam.data.lens = 60.0
    sc.frame_set(1)
    still = mean_rgb(scenes.render(tmp_path / "still.exr", 24, 24, 4, dispersion=False))
    np.testing.assert_allclose(frames[2], still, rtol=1e-6)
    assert abs(frames[2][1] / frames[1][1] - 1.0) > 0.05          # the plane fills more


def test_17_a_lobe_at_its_bounce_limit_leaves_its_light_to_the_light_samples(tmp_path):
    """Diffuse bounces 0 (total 4): the world still lights a Lambertian plane fully, a L,
    because a lobe that cannot continue is no sampling strategy to share the light with."""
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    plane(-2.0, diffuse("d", (0.6, 0.6, 0.6)))
    bpy.context.scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (
        0.5, 0.5, 0.5, 1.0)
    bpy.context.scene.cycles.diffuse_bounces = 0
    limited = mean_rgb(scenes.render(tmp_path / "l.exr", 24, 24, 32, bounces=4,
                                     dispersion=False))
    bpy.context.scene.cycles.diffuse_bounces = 4
    direct = mean_rgb(scenes.render(tmp_path / "d.exr", 24, 24, 32, bounces=0,
                                    dispersion=False))
    np.testing.assert_allclose(limited / direct, 1.0, atol=0.03)


def test_18_mixing_with_transparent_keeps_the_surface_and_alpha_scales_emission():
    from neurolens_addon.engine.shader_nodes import material_params
    m = scenes.material("veil", (0.8, 0.8, 0.8))
    nodes, links = m.node_tree.nodes, m.node_tree.links
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    principled = nodes["Principled BSDF"]
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.5
    links.new(principled.outputs[0], mix.inputs[1])
    links.new(nodes.new("ShaderNodeBsdfTransparent").outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])
    p = material_params(m, [])
    assert p["alpha"] == pytest.approx(0.5)
    assert p["base"] == pytest.approx((0.8, 0.8, 0.8))      # not darkened by the mix
    glow = scenes.material("glow", (0, 0, 0), emission=(1, 1, 1), strength=4.0)
    glow.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.25
    assert material_params(glow, [])["emission"] == pytest.approx((1.0, 1.0, 1.0))


def test_19_past_the_transparent_limit_a_surface_counts_at_its_opacity(tmp_path):
    """An emissive veil (1 x alpha 0.25) before an emissive plane (1): eight transparent
    bounces see 0.25 + 0.75 = 1, none sees the veil alone, 0.25."""
    settings = dict(bounces=2, dispersion=False)
    glass_slab()
    bare = mean_rgb(scenes.render(tmp_path / "b.exr", 16, 16, 64, **settings))
    veil = scenes.material("veil", (0.0, 0.0, 0.0), emission=(1, 1, 1), strength=1.0)
    veil.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.25
    plane(-2.0, veil)
    seen = mean_rgb(scenes.render(tmp_path / "v.exr", 16, 16, 64, **settings))
    np.testing.assert_allclose(seen / bare, 1.0, atol=0.02)
    bpy.context.scene.cycles.transparent_max_bounces = 0
    alone = mean_rgb(scenes.render(tmp_path / "a.exr", 16, 16, 64, **settings))
    np.testing.assert_allclose(alone / bare, 0.25, atol=0.01)


def test_20_a_light_hidden_from_diffuse_and_glossy_rays_lights_nothing(tmp_path):
    lights_and_plane(0.0, 1.0)
    for ob in bpy.context.scene.objects:
        if ob.type == "MESH" and ob.data.materials and ob.data.materials[0].name == "quad":
            bpy.data.objects.remove(ob)
    lit = mean_rgb(scenes.render(tmp_path / "lit.exr", 16, 16, 16, bounces=1))
    for ob in bpy.context.scene.objects:
        if ob.type == "LIGHT":
            ob.visible_diffuse = ob.visible_glossy = False
    dark = mean_rgb(scenes.render(tmp_path / "dark.exr", 16, 16, 16, bounces=1))
    assert lit.min() > 0.02 and dark.max() == 0.0


def test_21_a_glass_bsdf_tints_its_reflection_principled_glass_does_not():
    from neurolens_addon.engine.shader_nodes import material_params
    assert material_params(glass_material("glass"), [])["tint_reflection"] == 1.0
    scenes.reset()
    assert material_params(glass_material("principled"), [])["tint_reflection"] == 0.0


def test_22_a_principled_bsdf_set_to_plain_ggx_loses_what_single_scattering_loses():
    """Principled's distribution is read as Cycles shades it: Multiscatter GGX (the default)
    compensates the light the microfacets shadow (bsdf.py, multiscatter 1), GGX does not (0)."""
    from neurolens_addon.engine.shader_nodes import material_params
    scenes.reset()
    m = scenes.material("rough", (0.5, 0.5, 0.5), roughness=0.8)
    assert material_params(m, [])["multiscatter"] == 1.0
    m.node_tree.nodes["Principled BSDF"].distribution = "GGX"
    assert material_params(m, [])["multiscatter"] == 0.0
