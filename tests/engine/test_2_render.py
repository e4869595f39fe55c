"""Headless renders of small scenes through the real NEUROLENS engine (bpy module,
bpy.ops.render.render, Blender's multilayer EXR writer, onnxruntime for the learned lens),
read back with the OpenEXR package. Rows of the read-back images run top to bottom."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from testdata import engine_scenes as scenes
from testdata.light_shape import spread_px
from testdata.starburst import far_light, spike_count

pytestmark = pytest.mark.slow          # engine renders

bpy = scenes.bpy

from neurolens_addon.core.aperture import stop_radius_for_f_number  # noqa: E402
from neurolens_addon.core.focus import focus_sensor_z  # noqa: E402
from neurolens_addon.core.lensfile import load_lens  # noqa: E402
from neurolens_addon.core.paraxial import paraxial_data  # noqa: E402
from neurolens_addon.core.rays import Rays  # noqa: E402
from neurolens_addon.core.trace import trace  # noqa: E402
from neurolens_addon.camera.lenses import PRESETS_DIR as PRESET_LENSES  # noqa: E402
from neurolens_addon.blender.render_engine import LAST, NeuroLensEngineMixin  # noqa: E402

LENS = load_lens(PRESET_LENSES / "double_gauss_50mm_f2.toml")
D_LINE = 587.5618


def luminance(ch):
    return 0.2126 * ch["Combined.R"] + 0.7152 * ch["Combined.G"] + 0.0722 * ch["Combined.B"]


def object_spot(point_mm, focus_mm, f_number, n=20000):
    """Exact core: where the rays from a camera-space object point (mm, camera looking down -Z)
    land on the sensor focused at focus_mm, as image-space film points (p, q) in mm (the film
    readout's inversion applied), for the valid rays through the entrance pupil."""
    R = stop_radius_for_f_number(LENS.stop_radius_mm, LENS.f_number, f_number)
    zs = focus_sensor_z(LENS, focus_mm, stop_radius=R)
    pd = paraxial_data(LENS)
    reach = 0.5 * pd.entrance_pupil.diameter_mm * R / LENS.stop_radius_mm * 1.3
    rng = np.random.default_rng(0)
    r = reach * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    x, y, zc = point_mm
    obj = np.array([x, y, zs - zc])                          # lens z = sensor_z - camera Z
    aim = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, pd.entrance_pupil.z_mm)])
    d = aim - obj[:, None]
    d /= np.linalg.norm(d, axis=0)
    o = np.repeat(obj[:, None], n, axis=1)
    res = trace(LENS, Rays(o, d, np.full(n, D_LINE)), from_sensor=False, stop_radius=R,
                sensor_z=zs)
    return -res.rays.o[0, res.valid], -res.rays.o[1, res.valid]


def pixel_of(p, q, width, height, film_w):
    """Image-space film point (mm) -> (column, row from the top) in pixel-centre units."""
    film_h = film_w * height / width
    return (p / film_w + 0.5) * width - 0.5, (0.5 - q / film_h) * height - 0.5


def centroid(img, around, half=4):
    r0, c0 = around
    win = img[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1]
    rr, cc = np.mgrid[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1]
    w = np.maximum(win, 0)
    return (cc * w).sum() / w.sum(), (rr * w).sum() / w.sum()


# ---------------------------------------------------------------- images land where they should

@pytest.mark.parametrize("model", ["exact", "learned"])
def test_09_centred_emitter_lands_in_the_centre_pixel(tmp_path, model):
    """A small emitter on the optical axis, in focus, lands in the centre pixel of an odd-sized
    frame, its light centred on it to a fifth of a pixel (exact and learned lens)."""
    scenes.reset()
    scenes.emitter_sphere((0.0, 0.0, -2.0))
    scenes.camera(focus=2.0, fstop=2.8, sensor_width=4.0, model=model)
    ch = scenes.render(tmp_path / "c.exr", 33, 33, 16)
    img = luminance(ch)
    assert np.unravel_index(np.argmax(img), img.shape) == (16, 16)
    cx, cy = centroid(img, (16, 16))
    assert abs(cx - 16) < 0.2 and abs(cy - 16) < 0.2


def test_10_off_axis_emitter_lands_where_the_exact_lens_images_it(tmp_path):
    """An emitter up and to the right of the axis appears up and to the right (the readout
    undoes the lens's inversion) at the image point the exact core traces for it, within a
    third of a pixel: lens space, camera space, world space and focus all agree."""
    scenes.reset()
    point = (0.12, 0.07, -2.0)
    scenes.emitter_sphere(point, radius=0.004, strength=80.0)
    scenes.camera(focus=2.0, fstop=2.8, sensor_width=12.0, model="exact")
    w, h = 61, 41
    ch = scenes.render(tmp_path / "o.exr", w, h, 16, dispersion=False)
    img = luminance(ch)
    p, q = object_spot(tuple(1000.0 * c for c in point), 2000.0, 2.8)
    col, row = pixel_of(p.mean(), q.mean(), w, h, 12.0)
    assert col > 35 and row < 15                     # right of and above the centre (30, 20)
    peak = np.unravel_index(np.argmax(img), img.shape)
    cx, cy = centroid(img, peak)
    assert abs(cx - col) < 0.33 and abs(cy - row) < 0.33


# ---------------------------------------------------------------- depth of field

def _edge_blur_scale(profile, cols, spot_px, e0):
    """Least-squares fit of a blurred edge: lo + amp * ESF(x; e, s), ESF the box-integrated CDF
    of the predicted spot's x spread scaled by s; returns the best s (coarse grid then fine)."""
    xs = np.sort(spot_px)
    sub = (np.arange(8) + 0.5) / 8 - 0.5

    def err(s, e):
        t = cols[:, None] + sub[None, :]
        m = (np.searchsorted(xs, (t - e) / s) / xs.size).mean(axis=1)
        a = np.stack([np.ones_like(m), m], axis=1)
        coef = np.linalg.lstsq(a, profile, rcond=None)[0]
        return ((a @ coef - profile) ** 2).sum()

    best = min(((err(s, e), s, e) for s in np.arange(0.05, 1.61, 0.05)
                for e in np.arange(e0 - 2, e0 + 2.01, 0.25)))
    _, s0, e0 = best
    best = min(((err(s, e), s, e) for s in np.arange(max(0.01, s0 - 0.05), s0 + 0.051, 0.01)
                for e in np.arange(e0 - 0.3, e0 + 0.31, 0.05)))
    return best[1]


def test_11_focused_checkerboard_is_sharp_and_defocused_blurs_as_the_lens_predicts(tmp_path):
    """A checkerboard 0.6 m away, focused at 0.6 m, has sharp edges; focused at 1.0 m its edges
    spread exactly as the lens predicts: the exact core's spot of an on-axis point at 0.6 m on
    the sensor focused at 1.0 m (x spread of the valid rays through the entrance pupil),
    fitted to each vertical edge of the render, needs a scale of 1 within 10 %; the focused
    render's edges need less than 15 % of it."""
    w, h, film_w = 128, 64, 8.0
    px = film_w / w
    scenes.reset()
    scenes.checker_plane(-0.6, 0.16, 8)
    cam = scenes.camera(focus=1.0, fstop=2.0, sensor_width=film_w, model="exact")
    settings = dict(dispersion=False, bounces=0)
    blurred = luminance(scenes.render(tmp_path / "b.exr", w, h, 48, **settings))
    cam.data.dof.focus_distance = 0.6
    sharp = luminance(scenes.render(tmp_path / "s.exr", w, h, 48, **settings))
    spot_x, _ = object_spot((0.0, 0.0, -600.0), 1000.0, 2.0)
    spot_x = (spot_x - spot_x.mean()) / px
    assert 3.0 < spot_x.std() < 6.0                          # a real, measurable defocus
    band = slice(8, 24)                                      # middle of a row of squares
    for img, lo, hi in ((blurred, 0.9, 1.1), (sharp, 0.0, 0.15)):
        prof = img[band].mean(axis=0)
        for edge in (32, 64, 96):
            cols = np.arange(edge - 14, edge + 14).astype(float)
            s = _edge_blur_scale(prof[edge - 14:edge + 14], cols, spot_x, float(edge) - 0.5)
            assert lo <= s <= hi, (edge, s)


# ---------------------------------------------------------------- exact vs learned

def test_12_exact_and_learned_lens_give_matching_images(tmp_path):
    """The same scene and samples through the exact and the learned double Gauss: PSNR above
    40 dB, mean difference below 5 % of the mean, vignetting within 0.05 on average. (The
    shipped model passes 2-4 % of off-axis rays that the exact lens clips at the first and
    last rims, so the learned image is slightly brighter off axis.) Only the learned lens
    reports a Lens Uncertainty."""
    out = {}
    for model in ("exact", "learned"):
        scenes.reset()
        scenes.checker_plane(-1.3, 1.2, 12)
        scenes.emitter_sphere((0.15, 0.08, -1.0), radius=0.01, strength=20.0)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.12, location=(-0.1, -0.05, -1.0))
        bpy.ops.object.light_add(type="POINT", location=(0.5, 0.5, 0.0))
        bpy.context.object.data.energy = 100.0
        scenes.camera(focus=1.0, fstop=2.0, sensor_width=24.0, model=model)
        out[model] = scenes.render(tmp_path / f"{model}.exr", 64, 48, 16)
    a, b = luminance(out["exact"]), luminance(out["learned"])
    psnr = 10 * np.log10(a.max() ** 2 / ((a - b) ** 2).mean())
    assert psnr > 40.0
    assert np.abs(a - b).mean() < 0.05 * a.mean()
    va, vb = out["exact"]["Vignetting.X"], out["learned"]["Vignetting.X"]
    assert abs(va.mean() - vb.mean()) < 0.05
    assert out["exact"]["Lens Uncertainty.X"].max() == 0.0
    assert out["learned"]["Lens Uncertainty.X"].mean() > 0.0


# ---------------------------------------------------------------- passes and output

def test_13_exr_holds_every_pass_with_sensible_values(tmp_path):
    """The multilayer EXR has Combined (RGBA), Depth, Normal, Vignetting and Lens Uncertainty:
    depth is the distance along the view axis to a plane 1.5 m away (from the sensor plane),
    the normal its world normal, vignetting a fraction in (0, 1], uncertainty positive where
    the learned lens ran; a PNG of the same render comes from Blender's writer too."""
    scenes.reset()
    bpy.ops.mesh.primitive_plane_add(size=4.0, location=(0.0, 0.0, -1.5))
    bpy.ops.object.light_add(type="SUN", location=(0, 0, 1))
    scenes.camera(focus=1.5, fstop=4.0, sensor_width=12.0, model="learned")
    ch = scenes.render(tmp_path / "p.exr", 40, 30, 4)
    need = {"Combined.R", "Combined.G", "Combined.B", "Combined.A", "Depth.Z", "Normal.X",
            "Normal.Y", "Normal.Z", "Vignetting.X", "Lens Uncertainty.X"}
    assert need <= set(ch)
    for name in need:
        assert np.isfinite(ch[name]).all()
    assert ch["Depth.Z"][15, 20] == pytest.approx(1.5, rel=0.005)
    np.testing.assert_allclose(ch["Normal.Z"][10:20, 10:30], 1.0, atol=1e-3)
    v = ch["Vignetting.X"]
    assert (v > 0).all() and 0.3 < v.mean() < 1.05
    assert (ch["Lens Uncertainty.X"] > 0).mean() > 0.95
    assert ch["Combined.G"][15, 20] > 0.05 and (ch["Combined.A"] == 1.0).all()
    img = bpy.data.images["Render Result"]
    s = bpy.context.scene.render.image_settings
    s.media_type, s.file_format = "IMAGE", "PNG"
    img.save_render(filepath=str(tmp_path / "p.png"), scene=bpy.context.scene)
    assert (tmp_path / "p.png").stat().st_size > 100


# ---------------------------------------------------------------- cancelling, memory

class _EscAfter(NeuroLensEngineMixin, bpy.types.RenderEngine):
    """The real engine (its mixin), with Esc pressed after a number of its test_break polls."""

    bl_idname = "NEUROLENS_TEST_ESC"
    bl_label = "NeuroLens (test: Esc)"
    polls = 0
    limit = 30
    pressed_at = None

    def should_stop(self):
        cls = type(self)
        cls.polls += 1
        if cls.polls > cls.limit:
            if cls.pressed_at is None:
                cls.pressed_at = time.perf_counter()
            return True
        return super().should_stop()


@pytest.fixture
def esc_engine():
    """Registered once and left registered (Blender keeps the last render's engine type)."""
    scenes.reset()
    if not hasattr(bpy.types, _EscAfter.__name__):
        bpy.utils.register_class(_EscAfter)
    _EscAfter.polls, _EscAfter.pressed_at = 0, None
    return _EscAfter


def test_14_cancelling_stops_within_a_second_and_leaves_a_valid_partial_result(tmp_path,
                                                                                  esc_engine):
    """Esc mid-render (test_break polled between bundles and between chunks of ray casts):
    the render returns within a second, and the written EXR is a valid partial image: every
    pass present and finite, finished tiles rendered (light, vignetting > 0), the rest empty."""
    scene = bpy.context.scene
    scenes.checker_plane(-1.0, 2.0, 10, emissive=True)
    scenes.camera(focus=1.0, fstop=2.0, sensor_width=24.0, model="learned")
    scene.render.engine = esc_engine.bl_idname
    ch = scenes.render(tmp_path / "x.exr", 320, 240, 64, tile_size=64)
    done = time.perf_counter()
    st = LAST["stats"]
    assert st is not None and st.cancelled
    assert esc_engine.pressed_at is not None and done - esc_engine.pressed_at < 1.0
    assert 0 < st.samples_done < st.samples_total
    for name, arr in ch.items():
        assert np.isfinite(arr).all(), name
    rendered = ch["Vignetting.X"] > 0
    assert 0.0 < rendered.mean() < 1.0
    assert luminance(ch)[rendered].mean() > 0.1
    assert (luminance(ch)[~rendered] == 0).all()


def test_15_bundles_stay_within_the_memory_bound_in_a_real_render(tmp_path):
    """Instrumented counters of a real render: no bundle builds more camera samples, and no
    ray-cast batch (primary, shadow, bounce) holds more rays, than the bundle bound; every
    pixel still gets all its samples."""
    scenes.reset()
    scenes.checker_plane(-1.0, 2.0, 10, emissive=False)
    bpy.ops.object.light_add(type="POINT", location=(0.3, 0.3, 0.0))
    scenes.camera(focus=1.0, fstop=2.0, sensor_width=24.0, model="learned")
    scenes.render(tmp_path / "m.exr", 48, 32, 16, tile_size=16, max_bundle_rays=1024,
                  bounces=1)
    st = LAST["stats"]
    assert st.samples_done == 48 * 32 * 16
    assert 0 < st.max_bundle_rays <= 1024
    assert 0 < st.max_cast_batch <= 1024
    assert st.bundles >= 48 * 32 * 16 // 1024


def test_16_lens_setup_errors_are_clear_and_clamps_match_the_panel(tmp_path):
    """A camera without a lens, or a lens that does not exist, ends the render with a message
    saying so; a focus nearer than the lens can reach and an f-number wider than it opens are
    clamped with a message, as the panel and Cycles clamp them, and the render goes on."""
    from neurolens_addon.blender.camera_reader import lens_setup
    from neurolens_addon.core.errors import LensError
    scenes.reset()
    cam = scenes.camera(focus=1.0, model="exact")
    scene = bpy.context.scene
    del cam.data["neurolens_lens"]
    with pytest.raises(LensError, match="names no lens"):
        lens_setup(cam, scene)
    with pytest.raises(RuntimeError, match="names no lens"):
        scenes.render(tmp_path / "e.exr", 8, 8, 1)
    cam.data["neurolens_lens"] = "no_such_lens"
    with pytest.raises(LensError, match="not found"):
        lens_setup(cam, scene)
    cam.data["neurolens_lens"] = "double_gauss_50mm_f2"
    cam.data.dof.focus_distance = 0.05
    near = lens_setup(cam, scene)
    assert near.focus_mm > 50.0 and any("focuses no closer" in t for _l, t in near.messages)
    scenes.render(tmp_path / "near.exr", 8, 8, 1)
    assert LAST["stats"].samples_done == 64
    cam.data.dof.focus_distance = 1.0
    cam.data.dof.aperture_fstop = 1.0
    cfg = lens_setup(cam, scene)
    assert cfg.f_number == LENS.f_number and cfg.messages          # clamped, with a note
    assert math.isclose(cfg.stop_radius_mm, LENS.stop_radius_mm)


def test_21_renders_one_after_another_share_no_lens_state(tmp_path):
    """One scene rendered through lens A, then lens B, then A again (same seed): the two A
    renders are identical and B differs, so nothing of one lens leaks into the next render."""
    scenes.reset()
    scenes.checker_plane(-1.3, 1.2, 12)
    scenes.emitter_sphere((0.15, 0.08, -1.0), radius=0.01, strength=20.0)
    cam = scenes.camera(focus=1.0, fstop=4.0, sensor_width=24.0, model="learned")
    imgs = []
    for k, lens in enumerate(("double_gauss_50mm_f2", "tessar_f4_5", "double_gauss_50mm_f2")):
        cam.data["neurolens_lens"] = lens
        imgs.append(luminance(scenes.render(tmp_path / f"r{k}.exr", 48, 32, 4, seed=3)))
    np.testing.assert_array_equal(imgs[0], imgs[2])
    assert np.abs(imgs[0] - imgs[1]).mean() > 0.05 * imgs[0].mean()


def test_22_what_the_engine_does_not_shade_is_said_once_per_render(tmp_path):
    """Sheen, clear coat and a volume are not shaded: the render names each material and what
    is left out, once; glass (transmission, now shaded) and a plain material get no note."""
    scenes.reset()
    scenes.camera(focus=2.0, model="exact")
    coated = scenes.material("coated")
    bsdf = coated.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Transmission Weight"].default_value = 1.0
    bsdf.inputs["Coat Weight"].default_value = 0.5
    bsdf.inputs["Sheen Weight"].default_value = 0.5
    nodes = coated.node_tree.nodes
    out = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    coated.node_tree.links.new(nodes.new("ShaderNodeVolumePrincipled").outputs[0],
                               out.inputs["Volume"])
    plain = scenes.material("plain")
    for mat, x in ((coated, -0.3), (plain, 0.3)):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.2, location=(x, 0.0, -2.0))
        bpy.context.object.data.materials.append(mat)
    scenes.render(tmp_path / "g.exr", 16, 16, 1)
    notes = LAST["stats"].notes
    said = [n for n in notes if "material 'coated'" in n]
    assert any("sheen" in n for n in said)
    assert any("clear coat" in n for n in said) and any("volume" in n for n in said)
    assert not any("transmission" in n or "glass" in n for n in said)
    assert len(said) == len(set(said)) == 3
    assert not any("material 'plain'" in n for n in notes)


def _relative_illumination(lens, sensor_z, radii, n=160):
    """E(r) / E(0) for a uniform scene, computed independently of the engine's pupil sampler:
    a uniform grid of aim points on the rear vertex plane, each passing ray weighted
    cos^4(theta) / dz^2 (the irradiance of a Lambertian scene of radiance 1)."""
    from neurolens_addon.core.rays import Rays
    from neurolens_addon.core.trace import trace
    rear = lens.surfaces[-1]
    z_rear = float(lens.vertex_z[-1])
    half = 1.6 * rear.semi_diameter_mm
    g = (np.arange(n) + 0.5) / n * 2 * half - half
    ax, ay = (a.ravel() for a in np.meshgrid(g, g))
    out = []
    for r in radii:
        o = np.stack([np.full(ax.size, r), np.zeros(ax.size), np.full(ax.size, sensor_z)])
        d = np.stack([ax - r, ay, np.full(ax.size, z_rear - sensor_z)])
        length = np.linalg.norm(d, axis=0)
        res = trace(lens, Rays(o, d / length, np.full(ax.size, 587.5618)), from_sensor=True)
        cos = (z_rear - sensor_z) / length
        out.append(float((res.valid * cos ** 4).sum()))
    return np.array(out) / out[0]


def test_23_vignetting_pass_is_the_lens_relative_illumination(tmp_path):
    """Under a uniform white world (no geometry) the Vignetting pass is the lens's relative
    illumination: 1 at the centre, falling off as an independent trace of the rear aperture
    predicts (cos^4 and the clipped pupil), smooth (no rings), and equal to Combined."""
    from neurolens_addon.core.focus import focus_sensor_z
    scenes.reset()
    bpy.context.scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = \
        (1, 1, 1, 1)
    scenes.camera(focus=2.0, fstop=2.0, sensor_width=36.0, model="exact")
    ch = scenes.render(tmp_path / "v.exr", 41, 41, 32, dispersion=False)
    v = ch["Vignetting.X"]
    np.testing.assert_allclose(ch["Combined.G"], v, rtol=1e-5, atol=1e-6)
    pixels = np.array([20, 26, 32, 38])                        # centre row, outwards
    radii = ((pixels + 0.5) / 41 - 0.5) * 36.0
    ring = np.array([np.mean([v[20, 20 + k], v[20, 20 - k], v[20 + k, 20], v[20 - k, 20]])
                     for k in pixels - 20])
    expected = _relative_illumination(LENS, focus_sensor_z(LENS, 2000.0), radii)
    assert ring[0] == pytest.approx(1.0, abs=0.03)
    np.testing.assert_allclose(ring, expected, rtol=0.04)
    assert expected[-1] < 0.8                                  # the lens does fall off there
    # no rings: the mean over every annulus of pixels follows the prediction
    c = ((np.arange(41) + 0.5) / 41 - 0.5) * 36.0
    r = np.hypot(*np.meshgrid(c, c))
    edges = np.linspace(0.0, 17.0, 9)
    idx = np.digitize(r, edges) - 1
    bins = [k for k in range(8) if (idx == k).sum() >= 8]
    means = np.array([v[idx == k].mean() for k in bins])
    centres = np.array([r[idx == k].mean() for k in bins])
    np.testing.assert_allclose(means, _relative_illumination(
        LENS, focus_sensor_z(LENS, 2000.0), np.concatenate([[0.0], centres]))[1:], rtol=0.04)


def test_24_clamp_direct_limits_what_a_sample_brings_from_its_first_hit(tmp_path):
    """A very bright emitter seen directly: unclamped its pixels go far above 1; with Clamp
    Direct 0.5 no pixel's r+g+b exceeds 0.5 (each sample is limited, so their mean is)."""
    scenes.reset()
    scenes.emitter_sphere((0.0, 0.0, -2.0), radius=0.02, strength=5000.0)
    scenes.camera(focus=2.0, fstop=2.8, sensor_width=4.0, model="exact")
    free = scenes.render(tmp_path / "free.exr", 17, 17, 8, clamp_direct=0.0)
    capped = scenes.render(tmp_path / "capped.exr", 17, 17, 8, clamp_direct=0.5)
    total = lambda ch: ch["Combined.R"] + ch["Combined.G"] + ch["Combined.B"]  # noqa: E731
    assert total(free).max() > 10.0
    assert 0.1 < total(capped).max() <= 0.5 * (1 + 1e-5)


@pytest.mark.parametrize("colours", [[(1.0, 1.0, 1.0)], [(1.0, 0.2, 0.2), (0.2, 0.2, 1.0)]])
def test_25_dispersion_adds_no_colour_noise_and_no_negative_pixel(colours, tmp_path):
    """With Dispersion on (three rays a sample, one per channel, non-negative responses) a
    wall renders with no negative pixel at 1 and 8 samples; under white light its R - G noise
    is under 10 % of its luminance noise (it was twice it with signed colour-matching weights),
    under red and blue lights within 1.5x of Dispersion off; the mean colour is unchanged."""
    scenes.lit_wall(colours)
    c = slice(8, 40)
    for spp in (1, 8):
        on = scenes.render(tmp_path / f"on{spp}.exr", 48, 48, spp, dispersion=True)
        rgb = np.stack([on[f"Combined.{k}"] for k in "RGB"])
        assert rgb.min() >= 0.0, (spp, rgb.min())
    off = scenes.render(tmp_path / "off.exr", 48, 48, 8, dispersion=False)
    rg_on = (on["Combined.R"] - on["Combined.G"])[c, c]
    rg_off = (off["Combined.R"] - off["Combined.G"])[c, c]
    for k in "RGB":
        ratio = on[f"Combined.{k}"][c, c].mean() / off[f"Combined.{k}"][c, c].mean()
        assert abs(ratio - 1.0) < 0.02, (k, ratio)
    if len(colours) == 1:
        assert rg_on.std() < 0.1 * on["Combined.G"][c, c].std(), rg_on.std()
    else:
        assert rg_on.std() < 1.5 * rg_off.std(), (rg_on.std(), rg_off.std())


# ---------------------------------------------------------------- diffraction

def _star(tmp_path, blades: int, diffraction: bool):
    """A small bright ball on black, in focus through the double Gauss at f/16 with a bladed
    stop (63 px over 1.6 mm of film): the luminance image."""
    scenes.reset()
    scenes.emitter_sphere((0.0, 0.0, -2.0), radius=0.0006, strength=2e4)
    cam = scenes.camera(focus=2.0, fstop=16.0, sensor_width=1.6)
    cam.data.dof.aperture_blades = blades
    cam.data["neurolens_diffraction"] = int(diffraction)
    ch = scenes.render(tmp_path / f"star{blades}{diffraction}.exr", 63, 63, 16)
    return luminance(ch)


@pytest.mark.parametrize("blades,spikes", [(6, 6), (5, 10)])
def test_40_diffraction_gives_a_star_the_spikes_of_its_blades(tmp_path, blades, spikes):
    """With Diffraction on, a point-like light renders as a starburst: `spikes` rays (N for an
    even blade count, 2N for an odd one) around it where the render without diffraction is
    dark, and the frame's light is the same within 1 % (diffraction only moves it); the
    render reports the convolution's time."""
    off = _star(tmp_path, blades, False)
    on = _star(tmp_path, blades, True)
    assert spike_count(on) == spikes
    assert far_light(off) < 1e-3 * off.sum() < 0.1 * far_light(on)
    assert on.sum() == pytest.approx(off.sum(), rel=0.01)
    assert LAST["stats"].seconds.get("diffraction", 0.0) > 0.0


# ---------------------------------------------------------------- ghosts

def _ghost_camera(ghosts: bool, share: float = 0.5, coating: str = "bare", **kw):
    cam = scenes.camera(**kw)
    cam.data["neurolens_ghosts"] = int(ghosts)
    cam.data["neurolens_coating"] = coating
    cam.data["neurolens_ghost_share"] = share
    return cam


def test_41_ghosts_take_their_light_from_the_image(tmp_path):
    """Under a uniformly bright sky the frame with ghosts on (uncoated glass, eight ghosts,
    half the samples on them) holds the light of the frame without, within 2 %: the ghosts'
    light is taken from the image (the image path keeps 1 / (1 + sum E_g))."""
    totals = {}
    for on in (False, True):
        scene = scenes.reset()
        scene.world.color = (1.0, 1.0, 1.0)
        if scene.world.node_tree is not None and "Background" in scene.world.node_tree.nodes:
            scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (1, 1, 1, 1)
        _ghost_camera(on, focus=2.0, fstop=2.8, sensor_width=36.0)
        ch = scenes.render(tmp_path / f"sky{on}.exr", 48, 32, 64)
        img = luminance(ch)
        assert img[14:18, 22:26].mean() == pytest.approx(1.0, abs=0.1)     # the sky reads 1
        totals[on] = float(img.sum())
        if on:
            config = LAST["config"]
    assert len(config.derived.ghost_set) == 8
    assert sum(e for _g, e in config.derived.ghost_set) > 0.01          # bare glass: a few per cent
    assert totals[True] == pytest.approx(totals[False], rel=0.02)


def test_42_a_bright_light_casts_ghosts_and_its_image_dims(tmp_path):
    """A bright ball on black: with ghosts on, light lands away from its image where the frame
    without ghosts is dark, and the ball's own image keeps 1 / (1 + sum E_g) of its light
    (within 5 %)."""
    imgs = {}
    for on in (False, True):
        scenes.reset()
        scenes.emitter_sphere((0.2, 0.1, -2.0), radius=0.05, strength=200.0)
        _ghost_camera(on, focus=2.0, fstop=2.8, sensor_width=36.0)
        imgs[on] = luminance(scenes.render(tmp_path / f"ball{on}.exr", 64, 48, 64))
        if on:
            config = LAST["config"]
    off, on = imgs[False], imgs[True]
    ball = off > 1e-3 * off.max()
    grown = ball.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            grown |= np.roll(ball, shift, axis=axis)
    assert off[~grown].sum() == 0.0
    assert on[~grown].sum() > 1e-4 * off.sum()
    kappa = 1.0 / (1.0 + sum(e for _g, e in config.derived.ghost_set))
    assert on[ball].sum() / off[ball].sum() == pytest.approx(kappa, rel=0.05)


# ---------------------------------------------------------------- anamorphic lenses

def test_43_an_anamorphic_lens_renders_desqueezed(tmp_path):
    """A lens with a front pair of cylinders (a Galilean attachment powered in x: squeeze
    S = f_y / f_x = 1.30) renders through the engine's exact lens (its pupil sampled over the
    rear element: the radial pupil grids assume rotational symmetry) with the film desqueezed:
    a round ball far away comes out round (second moments in x and y within 5 %), where the
    squeezed film would show it 1 / S as wide."""
    from neurolens_addon.core.lensfile import dump_lens
    from neurolens_addon.core.paraxial import squeeze
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    lens = cylinder_attachment_lens()
    assert squeeze(lens) > 1.25
    path = tmp_path / "anamorphic.toml"
    path.write_text(dump_lens(lens))
    scenes.reset()
    scenes.emitter_sphere((0.0, 0.0, -30.0), radius=0.5, strength=5.0)
    scenes.camera(focus=30.0, fstop=4.0, sensor_width=12.0, lens=str(path))
    img = luminance(scenes.render(tmp_path / "ana.exr", 96, 96, 64))
    assert LAST["config"].squeeze == pytest.approx(squeeze(lens))
    sx, sy = spread_px(img)
    assert 2.0 < sx < 10.0
    assert sx / sy == pytest.approx(1.0, abs=0.05)


def test_44_the_anamorphic_presets_render_vertical_oval_bokeh(tmp_path):
    """Focused at 1 m, a small light 20 m away renders through each anamorphic preset (the
    exact lens, its attachment refocused by the focus table) as a vertical oval in the
    desqueezed frame, height over width above 1.3 (1.51 traced exactly for a point,
    tests/core/test_anamorphic_presets.py; the light's own size rounds it a little), while the
    same prime alone renders it round within 10 %."""
    ratios = {}
    for stem in ("anamorphic_2x_60mm_f1_9", "anamorphic_attachment_speed_panchro_50mm_f2",
                 "cinema_speed_panchro_50mm_f2"):
        scenes.reset()
        scenes.emitter_sphere((0.0, 0.0, -20.0), radius=0.05, strength=400.0)
        scenes.camera(focus=1.0, fstop=2.0, sensor_width=8.0, lens=stem)
        sx, sy = spread_px(luminance(scenes.render(tmp_path / f"{stem}.exr", 96, 96, 64)))
        assert sx > 1.0
        ratios[stem] = sy / sx
    assert ratios["anamorphic_2x_60mm_f1_9"] > 1.3
    assert ratios["anamorphic_attachment_speed_panchro_50mm_f2"] > 1.3
    assert ratios["cinema_speed_panchro_50mm_f2"] == pytest.approx(1.0, abs=0.1)
