"""core.stmap: ST-maps of a lens's distortion, checked against chief rays solved here
independently (in two dimensions, at any azimuth) and against each other as a compositor
samples them; the command line writes them as EXR whole or not at all."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.focus import focus_sensor_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.stmap import (INVALID, MapFrame, chief_ray_table, lens_at_setting,
                                        needed_overscan, st_map)
from testdata.chief_rays import distort_error_px, round_trip_px

ROOT = Path(__file__).resolve().parents[2]
LENSES = ROOT / "presets" / "lenses"
FRAME = MapFrame(1920, 1280, 36.0)


def _lens(stem):
    return load_lens(LENSES / f"{stem}.toml")


@pytest.mark.parametrize("stem", ["double_gauss_50mm_f2", "wide_20mm_f2_8", "tessar_f4_5",
                                  "ultrawide_14mm_f2_8"])
def test_01_the_distort_map_is_the_chief_ray_within_a_tenth_of_a_pixel(stem):
    """At 1920 pixels across a full-frame sensor: for 300 pixels anywhere on the lens's image,
    the pinhole point the distort map samples is where the chief ray, solved here in two
    dimensions at the pixel's own azimuth, points (f_p tan(theta) along its azimuth), within
    0.1 px (the issue's target). With the sensor on the paraxial focal plane, the pinhole's
    focal length is the paraxial focal length (1e-5); at the exact focus it differs by the
    defocus over the exit pupil's distance."""
    lens = _lens(stem)
    par = paraxial_data(lens)
    on_focal_plane = chief_ray_table(lens, par.rear_focal_z_mm, 5.0)
    assert on_focal_plane.f_p_mm == pytest.approx(par.efl_mm, rel=1e-5)
    z = focus_sensor_z(lens, math.inf)
    table = chief_ray_table(lens, z, FRAME.film_radius_mm)
    assert table.f_p_mm == pytest.approx(par.efl_mm, rel=0.02)
    rgba = st_map(table, FRAME, "distort")
    err, checked = distort_error_px(table, FRAME, rgba)
    assert checked == 300 and err < 0.1, err


@pytest.mark.parametrize("stem", ["double_gauss_50mm_f2", "wide_20mm_f2_8", "fisheye_f4"])
def test_02_sampled_as_a_compositor_does_the_maps_invert_each_other(stem):
    """Every pixel of the undistorted (pinhole) image, through the undistort map to the lens's
    image and back through the distort map sampled bilinearly there (as an STMap node reads
    it), lands within 0.05 px of itself (the issue's target), over the whole image the lens
    covers (overscan 1.1)."""
    lens = _lens(stem)
    frame = MapFrame(480, 320, 36.0 if stem != "fisheye_f4" else 24.0, 1.1)
    z = focus_sensor_z(lens, math.inf)
    table = chief_ray_table(lens, z, frame.film_radius_mm)
    und, dis = st_map(table, frame, "undistort"), st_map(table, frame, "distort")
    err, share = round_trip_px(frame, und, dis)
    assert share > 0.5 and err < 0.05, err


def test_03_what_the_lens_does_not_image_is_marked_never_nan():
    """A circular fisheye on a full-frame sensor: the frame's corners lie beyond its image
    circle; there the distort map holds R = G = INVALID (outside [0, 1]) and A = 0, elsewhere
    A = 1; no value is NaN; and no overscan lets a pinhole image hold the corners (inf)."""
    lens = _lens("fisheye_8mm_f2_8_circular")
    z = focus_sensor_z(lens, math.inf)
    table = chief_ray_table(lens, z, FRAME.film_radius_mm)
    rgba = st_map(table, FRAME, "distort")
    assert np.isfinite(rgba).all()
    off = rgba[..., 2] == 0
    assert off[0, 0] and off[-1, -1] and not off[FRAME.height_px // 2, FRAME.width_px // 2]
    assert (rgba[off][:, :2] == INVALID).all()
    # a pixel the lens images far off axis samples the pinhole image beyond its edge: outside
    # [0, 1] too, told apart by A
    assert (np.abs(rgba[~off][:, :2]) < 1e6).all() and (rgba[~off][:, :2] < 0).any()
    assert needed_overscan(table, FRAME) == math.inf


def test_04_barrel_distortion_needs_overscan_and_a_longer_focus_breathes():
    """The 14 mm ultrawide's border pixels sample beyond the sensor in the pinhole image
    (overscan > 1, what the undistorted CG must be rendered with); focused at 0.5 m its
    pinhole focal length differs from infinity's (breathing): the map follows the focus."""
    lens = _lens("ultrawide_14mm_f2_8")
    inf = lens_at_setting(lens, film_radius_mm=FRAME.film_radius_mm)
    near = lens_at_setting(lens, focus_mm=500.0, film_radius_mm=FRAME.film_radius_mm)
    assert needed_overscan(inf[2], FRAME) > 1.01
    assert abs(near[2].f_p_mm / inf[2].f_p_mm - 1.0) > 0.005
    assert near[1] != inf[1]


def test_05_an_anamorphic_lens_is_refused_in_one_line():
    """An anamorphic lens's mapping is not radial: refused with a LensError naming it."""
    lens = _lens("anamorphic_2x_60mm_f1_9")
    with pytest.raises(LensError, match="lenses of revolution"):
        chief_ray_table(lens, focus_sensor_z(lens, math.inf), 20.0)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "neurolens_addon.core", "stmap", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_06_the_command_writes_the_map_and_its_lens_data(tmp_path):
    """`python -m neurolens_addon.core stmap`: an EXR of R, G, A at the plate's size (distort)
    or the overscanned size (undistort), the same values as st_map, the lens data in its
    header; the overscan the frame needs is printed."""
    from neurolens_addon.core.exr import read_exr
    out = tmp_path / "dg.exr"
    p = _cli(LENSES / "double_gauss_50mm_f2.toml", "--resolution", "192x128", "--sensor-width",
             36, "--focus", 3, "--overscan", 1.1, "--direction", "undistort", "--out", out)
    assert p.returncode == 0, p.stderr
    assert "needs overscan" in p.stdout
    chans, header = read_exr(out)
    assert sorted(chans) == ["A", "G", "R"] and chans["R"].shape == (141, 211)
    lens, z, table = lens_at_setting(_lens("double_gauss_50mm_f2"), focus_mm=3000.0,
                                     film_radius_mm=MapFrame(192, 128, 36.0, 1.1).film_radius_mm)
    want = st_map(table, MapFrame(192, 128, 36.0, 1.1), "undistort")
    np.testing.assert_allclose(chans["R"], want[..., 0], atol=1e-6)
    np.testing.assert_allclose(chans["G"], want[..., 1], atol=1e-6)
    assert header["neurolens/direction"] == "undistort"
    assert header["neurolens/pinhole_focal_length_mm"] == pytest.approx(table.f_p_mm, rel=1e-6)


@pytest.mark.parametrize("args, says", [
    (["--resolution", "19x"], "--resolution"), (["--overscan", "0.5"], "overscan 0.5"),
    (["--sensor-width", "-3"], "sensor width"), (["--wavelength", "nan"], "wavelength"),
    (["--zoom", "35"], "does not zoom")])
def test_07_bad_settings_are_one_line_and_leave_the_old_map(tmp_path, args, says):
    """A setting that is no setting: exit 2, one line saying which, the old file kept."""
    out = tmp_path / "m.exr"
    out.write_bytes(b"old")
    base = {"--resolution": "64x32", "--sensor-width": "36", "--overscan": "1",
            "--wavelength": "587.6"}
    base.update(dict(zip(args[::2], args[1::2])))
    flat = [v for kv in base.items() for v in kv]
    p = _cli(LENSES / "double_gauss_50mm_f2.toml", *flat, "--direction", "distort", "--out",
             out)
    assert p.returncode == 2
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and says in lines[0], p.stderr
    assert out.read_bytes() == b"old"


def _distort_samples(table, seed):
    """(x, y (mm on the lens's image), rho (mm on the pinhole's)) of 400 random pixels of the
    distort map: each pixel and the pinhole radius the map samples for it."""
    rgba = st_map(table, FRAME, "distort")
    rng = np.random.default_rng(seed)
    i, j = rng.integers(0, FRAME.width_px, 400), rng.integers(0, FRAME.height_px, 400)
    x = ((i + 0.5) / FRAME.width_px - 0.5) * FRAME.sensor_width_mm
    y = ((j + 0.5) / FRAME.height_px - 0.5) * FRAME.sensor_height_mm
    w, h = FRAME.pinhole_mm
    return x, y, np.hypot((rgba[j, i, 0] - 0.5) * w, (rgba[j, i, 1] - 0.5) * h)


@pytest.mark.parametrize("stem, most_px", [("double_gauss_50mm_f2", 0.01),
                                           ("wide_20mm_f2_8", 1.0), ("fisheye_f4", None)])
def test_08_the_fitted_brown_conrady_coefficients_hold_the_map_within_their_residual(stem,
                                                                                    most_px):
    """OpenCV's Brown-Conrady model with the fitted k1, k2, k3 puts each of 400 random pixels
    of the lens's image where the distort map's pinhole point says, within the residual the
    fit states (+ 0.01 px); the double Gauss's is under 0.01 px, the 20 mm's under 1 px; a
    fisheye is beyond the model (a residual of hundreds of pixels) and within the
    Kannala-Brandt model's (under 0.1 px)."""
    from neurolens_addon.core.distortion_fit import brown_conrady_radius, fitted_models
    lens = _lens(stem)
    _l, _z, table = lens_at_setting(lens, film_radius_mm=FRAME.film_radius_mm)
    fits = fitted_models(table, FRAME)
    bc, kb = fits["brown_conrady"], fits["kannala_brandt"]
    pixel = FRAME.sensor_width_mm / FRAME.width_px
    assert bc["fx_px"] == pytest.approx(table.f_p_mm / pixel)
    if most_px is None:
        assert bc["max_residual_px"] > 100.0 and kb["max_residual_px"] < 0.1
        return
    assert bc["max_residual_px"] < most_px
    x, y, rho = _distort_samples(table, 8)
    r_model = brown_conrady_radius(bc, rho / table.f_p_mm, table.f_p_mm)
    err = np.abs(r_model - np.hypot(x, y)) / pixel
    assert err.max() <= bc["max_residual_px"] + 0.01, (err.max(), bc["max_residual_px"])


@pytest.mark.parametrize("stem, most_px", [("double_gauss_50mm_f2", 0.1),
                                           ("wide_20mm_f2_8", 3.0)])
def test_08b_the_fitted_3de_radial_coefficients_undistort_within_their_residual(stem,
                                                                                most_px):
    """3DE's Radial - Standard, Degree 4 with the fitted c2, c4 takes each of 400 random
    pixels of the lens's image to the pinhole point the distort map samples there, within the
    residual the fit states (+ 0.01 px; in the undistorted image's pixels), itself under
    0.1 px for the double Gauss and 3 px for the 20 mm (two coefficients: Brown-Conrady's
    three hold the 20 mm to 0.35 px); on the 20 mm, barrel distortion,
    the undistorted radius is larger (c2 > 0 or c4 > 0 where it matters)."""
    from neurolens_addon.core.distortion_fit import fitted_models, tde4_undistorted_radius
    lens = _lens(stem)
    _l, _z, table = lens_at_setting(lens, film_radius_mm=FRAME.film_radius_mm)
    tde = fitted_models(table, FRAME)["tde4_radial_standard_degree_4"]
    assert tde["max_residual_px"] < most_px
    assert tde["filmback_half_diagonal_mm"] == pytest.approx(0.5 * math.hypot(36.0, 24.0))
    x, y, rho = _distort_samples(table, 9)
    err = np.abs(tde4_undistorted_radius(tde, np.hypot(x, y)) - rho)
    err /= FRAME.sensor_width_mm / FRAME.width_px
    assert err.max() <= tde["max_residual_px"] + 0.01, (err.max(), tde["max_residual_px"])
    if stem == "wide_20mm_f2_8":
        corner = np.array([0.5 * math.hypot(36.0, 24.0)])
        assert tde4_undistorted_radius(tde, corner)[0] > corner[0]


def test_09_the_command_writes_the_lens_data_beside_the_map(tmp_path):
    """The JSON sidecar beside the map: the focal lengths, focus, entrance pupil from the
    sensor, sensor and both fitted models with their residuals; the header the OpenCV
    coefficients."""
    import json
    from neurolens_addon.core.exr import read_exr
    out = tmp_path / "w.exr"
    p = _cli(LENSES / "wide_20mm_f2_8.toml", "--resolution", "96x64", "--sensor-width", 36,
             "--focus", 2, "--direction", "distort", "--out", out)
    assert p.returncode == 0, p.stderr
    meta = json.loads((tmp_path / "w.exr.json").read_text())
    assert meta["focus_distance_mm"] == 2000.0 and meta["resolution_px"] == [96, 64]
    assert 0.0 < meta["entrance_pupil_from_sensor_mm"] < 200.0
    assert set(meta["distortion"]) == {"brown_conrady", "kannala_brandt",
                                       "tde4_radial_standard_degree_4"}
    _chans, header = read_exr(out)
    assert header["neurolens/opencv_k1"] == pytest.approx(
        meta["distortion"]["brown_conrady"]["k1"], rel=1e-6)
