"""The panel's field of view and image circle, traced from the sensor as a render sees the lens:
a fisheye covers the height of a 36 x 24 frame and its image circle is the ~31.8 mm one its
renders show (the old front-side beams stopped at 89 degrees and said 22.3 mm)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.camera.field_of_view import _profile, field_of_view_deg, image_circle_mm
from neurolens_addon.camera.lenses import PRESETS_DIR, load_lens_entry
from neurolens_addon.core.focus import focus_sensor_z


def _entry(name):
    e = load_lens_entry(PRESETS_DIR / f"{name}.toml")
    return e, focus_sensor_z(e.lens, 3000.0)


def test_a_fisheye_covers_the_frame_height_with_its_real_image_circle():
    e, z = _entry("fisheye_f4")
    assert 29.0 < image_circle_mm(e, z) < 34.0
    vertical = field_of_view_deg(e, z, 12.0)
    assert vertical is not None and vertical > 120.0
    assert field_of_view_deg(e, z, 18.0) is None           # the width reaches past the circle


@pytest.mark.parametrize("name", ["double_gauss_50mm_f2", "wide_angle_f3_4", "telephoto_f5_6",
                                  "cooke_triplet_f4"])
def test_ordinary_lenses_are_close_to_their_thin_lens_but_not_equal(name):
    e, z = _entry(name)
    h = field_of_view_deg(e, z, 18.0)
    thin = 2.0 * math.degrees(math.atan(18.0 / e.efl_mm))
    assert h is not None and abs(h - thin) < 0.1 * thin and h != pytest.approx(thin, abs=1e-3)


@pytest.mark.parametrize("name", ["double_gauss_50mm_f2", "fisheye_f4", "petzval_f1_4"])
def test_field_angle_grows_and_illumination_falls_towards_the_circle(name):
    e, z = _entry(name)
    radii, angles, illumination = _profile(e, z)
    inside = radii <= 0.5 * image_circle_mm(e, z)
    assert np.all(np.diff(angles[inside]) > 0)
    assert illumination[0] == pytest.approx(1.0) and illumination[inside][-1] < 1.0


def test_a_lens_with_a_small_circle_leaves_full_frame_corners_dark():
    e, z = _entry("petzval_f1_4")
    assert field_of_view_deg(e, z, 21.63) is None
    assert image_circle_mm(e, z) < 2 * 21.63


def test_a_lens_ending_in_a_cover_glass_near_the_sensor_has_its_real_circle():
    """The Noct's last surface is a cover glass about 2 mm before the sensor: aimed at the exit
    pupil, its profile is lit at the centre and its circle covers full frame (it read 0 mm
    when the aim points lay on the rear vertex)."""
    e, z = _entry("noct_58mm_f0_95_aspheric")
    assert float(e.lens.vertex_z[-1]) - z < 2.5
    radii, angles, illumination = _profile(e, z)
    assert illumination[0] == pytest.approx(1.0)
    assert image_circle_mm(e, z) > 2 * 21.63
    h = field_of_view_deg(e, z, 18.0)
    thin = 2.0 * math.degrees(math.atan(18.0 / e.efl_mm))
    assert h is not None and abs(h - thin) < 0.1 * thin


def test_the_field_of_view_breathes_with_the_focusing_groups(tmp_path):
    """A rear-focusing lens: the field of view at its close-focus group position differs from
    the one at infinity on the same sensor plane (its focal length changed)."""
    from neurolens_addon.camera.field_of_view import field_of_view_deg
    from neurolens_addon.camera.lenses import load_lens_entry
    from testdata.focusing_lenses import write
    entry = load_lens_entry(write(tmp_path / "rear.toml"))
    far = field_of_view_deg(entry, 0.0, 10.0)
    near = field_of_view_deg(entry, 0.0, 10.0, focus_group=1.0)
    assert far is not None and near is not None and abs(near / far - 1.0) > 0.01


def _mean_field_deg(lens, sensor_z, x, y, n=100_000):
    """Full field angle of a film point (x, y): twice the angle of the irradiance-weighted mean
    direction of the rays that leave the lens from it (aimed over the rear element's disc:
    an independent sampler from the profile's)."""
    from neurolens_addon.core.pupil import disc_rays
    from neurolens_addon.core.trace import trace
    rng = np.random.default_rng(3)
    rays, w = disc_rays(lens, np.full(n, x), np.full(n, y), sensor_z, rng.random(n),
                        rng.random(n), np.full(n, 587.5618))
    res = trace(lens, rays)
    m = (res.rays.d * np.where(res.valid, w, 0.0)).sum(axis=1)
    return 2.0 * math.degrees(math.atan2(math.hypot(m[0], m[1]), m[2]))


def test_an_anamorphic_lens_field_of_view_is_read_on_its_own_film():
    """The 2x anamorphic on a 36 mm sensor at 16:9, focused at infinity: the panel's field is
    read on the lens's own film (the frame desqueezed by 1.92: 18.7 mm wide) along each
    meridian, 35.2 x 19.1 degrees, what the lens's rays from the frame's edges give (within
    1 %; paraxially 2 atan(e / f_x) = 33.1 and 2 atan(e / f_y) = 19.0: the attachment's
    distortion along x), not the 79 x 38 read off the desqueezed frame along one meridian;
    its corners are lit."""
    from neurolens_addon.camera import CameraSettings, resolve_camera
    from neurolens_addon.camera.field_of_view import frame_field_of_view
    from neurolens_addon.core.film import FilmSettings
    path = str(PRESETS_DIR / "anamorphic_2x_60mm_f1_9.toml")
    s = CameraSettings(camera="cam", lens_path=path, model="exact", f_number=2.8,
                       focus_distance_mm=math.inf,
                       film=FilmSettings(sensor_width=36.0, resolution_x=1920,
                                         resolution_y=1080))
    setup = resolve_camera(s)
    (h, v, d), circle = frame_field_of_view(setup)
    w_lens = 36.0 / setup.squeeze
    assert setup.derived.lens_film.width_mm == pytest.approx(w_lens)
    z = setup.sensor_z_mm
    assert h == pytest.approx(_mean_field_deg(setup.lens, z, 0.5 * w_lens, 0.0), rel=0.01)
    assert v == pytest.approx(_mean_field_deg(setup.lens, z, 0.0, 10.125), rel=0.01)
    assert 33.0 < h < 37.0 and 18.0 < v < 20.0
    assert d is not None and circle > math.hypot(w_lens, 20.25)
    # a lens of revolution reads the same in every direction: the frame itself
    dg = resolve_camera(CameraSettings(camera="cam", lens_path=str(
        PRESETS_DIR / "double_gauss_50mm_f2.toml"), model="exact", f_number=2.8,
        focus_distance_mm=math.inf, film=s.film))
    (h2, v2, _), _ = frame_field_of_view(dg)
    assert h2 == pytest.approx(field_of_view_deg(dg.entry, dg.sensor_z_mm, 18.0))
    assert v2 == pytest.approx(field_of_view_deg(dg.entry, dg.sensor_z_mm, 10.125))
