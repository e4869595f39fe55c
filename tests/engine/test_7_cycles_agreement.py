"""The engine and Cycles (with the project's exact OSL camera) estimate the same image.

Three scenes (testdata/agreement_scenes.py): the demo scene (one bounce), a glass and metal
still life under an area light, and an environment-lit scene with small bright texels that
defocus into bokeh; each with its own lens, focus and f-number, the light paths its own in
both engines, both denoised, rendered by the command line at 160x90 and 128 samples: the
image means within 3 % and SSIM >= 0.95 (measured: docs/bench/agreement.md has the 256-sample
figures; at 64 samples the demo's directly seen emissive sphere, 88 % of its image's mean,
leaves the means 2 to 4 % apart from seed to seed). A street against a sun 6 degrees high
(test_05) agrees in its raw estimates, region by region.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow          # renders in both renderers

bpy = pytest.importorskip("bpy")

from testdata import agreement_scenes  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _render(blend, engine, out, camera, spp=128, res="160x90"):
    lens, focus, fstop = camera
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(blend), "--lens",
                        lens, "--model", "exact", "--focus", str(focus), "--fstop", str(fstop),
                        "--samples", str(spp), "--resolution", res, "--engine", engine,
                        "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    from testdata.engine_scenes import read_exr
    ch = read_exr(out)
    return np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1)


def _ssim(a, b, sigma=1.5):
    """SSIM of two luminance images with a Gaussian window (data range 1)."""
    def blur(x):
        r = int(3 * sigma)
        k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
        k /= k.sum()
        x = np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode="edge"), k, "valid"),
                                0, x)
        return np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode="edge"), k,
                                                         "valid"), 1, x)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ma, mb = blur(a), blur(b)
    va, vb, cov = blur(a * a) - ma * ma, blur(b * b) - mb * mb, blur(a * b) - ma * mb
    return float((((2 * ma * mb + c1) * (2 * cov + c2))
                  / ((ma * ma + mb * mb + c1) * (va + vb + c2))).mean())


@pytest.mark.parametrize("name", ["demo", "still_life", "environment"])
def test_01_the_engine_and_cycles_render_alike(tmp_path, name):
    blend = agreement_scenes.write(name, tmp_path, bounces=1 if name == "demo" else None)
    camera = agreement_scenes.CAMERAS[name]
    cyc = _render(blend, "cycles", tmp_path / "cycles.exr", camera)
    eng = _render(blend, "neurolens", tmp_path / "engine.exr", camera)
    lum = lambda x: np.clip(x @ np.array([0.2126, 0.7152, 0.0722]), 0.0, 1.0)  # noqa: E731
    assert abs(eng.mean() / cyc.mean() - 1.0) < 0.03, (eng.mean(), cyc.mean())
    assert _ssim(lum(cyc), lum(eng)) >= 0.95


def test_02_a_zoom_renders_the_same_stop_in_both_renderers(tmp_path):
    """The RF 24-70 at 48 mm (between its tabulated 44.86 and 67.89 mm), wide open (f/2.91: its
    iris opens as it zooms), focused at 0.5 m: a light 40 m away is the same defocus disc in
    Cycles and in the engine (RMS radius within 4 %), the disc the exact trace predicts
    through the derived camera's stop (within 5 %; Cycles once recomputed the stop from the
    wide end's f-number, and its discs at the long end were 1.3 x smaller). Dispersion off
    here; test_03 renders it on."""
    blend = agreement_scenes.write("far_lights", tmp_path)
    args = ["--model", "exact", "--focal-length", "48", "--no-dispersion", "--samples", "64",
            "--resolution", "200x80", "--no-denoise", "--quiet"]
    discs = {engine: agreement_scenes.middle_light_rms_px(
        _cli_rgb(blend, engine, tmp_path / f"{engine}.exr", *args), 48.0)
        for engine in ("cycles", "neurolens")}
    predicted = agreement_scenes.far_light_prediction(48.0, 200, 80)
    assert predicted["f_number"] == pytest.approx(2.91, rel=0.005)
    assert discs["neurolens"] == pytest.approx(predicted["rms_radius_px"], rel=0.05), discs
    assert discs["cycles"] == pytest.approx(discs["neurolens"], rel=0.04), discs


def _cli_rgb(blend, engine, out, *args):
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(blend), *args,
                        "--engine", engine, "--out", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    from testdata.engine_scenes import read_exr
    ch = read_exr(out)
    return np.stack([ch[f"Combined.{k}"] for k in "RGB"], -1).astype(np.float64)


def test_03_with_dispersion_a_far_light_is_the_same_disc_and_colour_in_both_renderers(
        tmp_path):
    """Dispersion on, both renderers' raw estimates (--no-denoise): the double Gauss at f/2.8
    focused at 0.5 m, the far lights' discs. Each channel's RMS radius of the middle light
    within 3 % (Cycles at 256 samples) and each channel's light over the frame within 3 %
    (Cycles at 2048 samples: one wavelength per camera ray leaves about 2 % of colour noise in
    these sums at 256; the engine's three colour rays a sample leave none). Measured: radii
    5.13 / 5.19 / 5.19 px (engine, 256 samples), 5.20 / 5.22 / 5.12 (Cycles, 256), sums within
    0.8 %. It failed while --no-denoise left Cycles' own denoiser on (the scene's default):
    OIDN smeared the colour noise of one wavelength a ray outwards: discs 5-8 % wider at 128
    and 256 samples, and bluer (it lost 7 % of the red light, 1 % of the blue at 128;
    docs/measurements.md)."""
    blend = agreement_scenes.write("far_lights", tmp_path)
    common = ["--lens", "double_gauss_50mm_f2", "--model", "exact", "--dispersion",
              "--no-denoise", "--resolution", "200x80", "--quiet"]
    eng = _cli_rgb(blend, "neurolens", tmp_path / "engine.exr", *common, "--samples", "256")
    cyc = _cli_rgb(blend, "cycles", tmp_path / "cycles.exr", *common, "--samples", "256")
    from testdata.light_shape import spread_px
    w = eng.shape[1] // 3
    disc = {name: [float(np.hypot(*spread_px(img[:, w:2 * w, c]))) for c in range(3)]
            for name, img in (("engine", eng), ("cycles", cyc))}
    assert min(disc["engine"]) > 3.0, disc
    np.testing.assert_allclose(disc["cycles"], disc["engine"], rtol=0.03, err_msg=str(disc))
    long = _cli_rgb(blend, "cycles", tmp_path / "cycles_long.exr", *common, "--samples", "2048")
    light = {"engine": eng.reshape(-1, 3).sum(0), "cycles": long.reshape(-1, 3).sum(0)}
    np.testing.assert_allclose(light["cycles"], light["engine"], rtol=0.03, err_msg=str(light))


def test_04_lens_shift_moves_the_frame_alike_in_both_renderers(tmp_path):
    """Blender's lens shift (0.25 of the frame's width): the far lights move to the left by
    about a quarter of the frame in both renderers, and their light's centroid agrees within
    2 pixels (Cycles shifts the raster position its camera shader receives; the engine its
    film: core.film)."""
    import bpy
    blend = agreement_scenes.write("far_lights", tmp_path)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    bpy.context.scene.camera.data.shift_x = 0.25
    shifted = tmp_path / "shifted.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(shifted), copy=True)
    args = ["--model", "exact", "--focal-length", "48", "--no-dispersion", "--samples", "32",
            "--resolution", "200x80", "--no-denoise", "--quiet"]
    centre = {}
    for engine in ("cycles", "neurolens"):
        cols = _cli_rgb(shifted, engine, tmp_path / f"{engine}.exr", *args)[..., 1].sum(0)
        centre[engine] = float((cols * np.arange(cols.size)).sum() / cols.sum())
    assert 30.0 < centre["neurolens"] < 75.0, centre          # from 100 towards 50
    assert centre["cycles"] == pytest.approx(centre["neurolens"], abs=2.0), centre


def test_05_a_street_against_a_low_sun_renders_alike(tmp_path):
    """The backlit street (agreement_scenes.backlit_street: a dark ground of roughness 1 and a
    wall of roughness 0.5 lit at grazing angles, the sun in front of the camera), 160x90 at 64
    samples, the raw estimates (--no-denoise: each renderer's denoiser moves a dark noisy
    frame's mean by 1-2 % its own way), no dispersion (not what is compared): the frame, the
    sunlit ground and the sunlit wall each within 3 % of Cycles'. Measured: 1.002, 0.999 and
    1.003; with the uncorrelated masking-shadowing G1(wo) G1(wi), Schlick's Fresnel and no
    multiple scattering (the engine before issue 29) 0.83, 0.51 and 0.95
    (docs/measurements.md)."""
    blend = agreement_scenes.write("backlit_street", tmp_path)
    lens, focus, fstop = agreement_scenes.CAMERAS["backlit_street"]
    args = ["--lens", lens, "--model", "exact", "--focus", str(focus), "--fstop", str(fstop),
            "--no-dispersion", "--no-denoise", "--samples", "64", "--resolution", "160x90",
            "--quiet"]
    img = {engine: _cli_rgb(blend, engine, tmp_path / f"{engine}.exr", *args)
           for engine in ("cycles", "neurolens")}
    h, w = img["cycles"].shape[:2]
    ratios = {}
    for name, ((r0, r1), (c0, c1)) in agreement_scenes.STREET_REGIONS.items():
        region = np.s_[int(r0 * h):int(r1 * h), int(c0 * w):int(c1 * w)]
        ratios[name] = float(img["neurolens"][region].mean() / img["cycles"][region].mean())
    assert all(abs(r - 1.0) < 0.03 for r in ratios.values()), ratios
