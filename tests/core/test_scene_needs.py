"""core.scene_needs: the error budget and the input-space region a scene's render settings ask
for (pure; no bpy)."""

import math

import pytest

from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.scene_needs import RenderNeeds, SceneNeedsError, training_region
from pathlib import Path

PRESETS = Path(__file__).resolve().parents[2] / "presets" / "lenses"


def needs(**kw):
    base = dict(resolution_x=1920, resolution_y=1080, sensor_width_mm=36.0,
                sensor_height_mm=24.0)
    return RenderNeeds(**{**base, **kw})


def test_01_doubling_the_resolution_halves_the_budget():
    """The allowed error is a fraction of a pixel: twice the pixels, half the budget, for
    every sensor fit and for the resolution percentage as for the resolution."""
    for fit in ("AUTO", "HORIZONTAL", "VERTICAL"):
        a = needs(sensor_fit=fit)
        b = needs(sensor_fit=fit, resolution_x=3840, resolution_y=2160)
        c = needs(sensor_fit=fit, resolution_percentage=200.0)
        assert b.error_budget_um() == pytest.approx(a.error_budget_um() / 2, rel=1e-12)
        assert c.error_budget_um() == pytest.approx(b.error_budget_um(), rel=1e-12)


def test_02_pixel_pitch_follows_blenders_sensor_fit():
    """AUTO spans the larger image side with the sensor width; HORIZONTAL the width; VERTICAL
    the height with the sensor height."""
    assert needs().pixel_pitch_mm() == pytest.approx(36.0 / 1920)
    assert needs(resolution_x=1000, resolution_y=2000).pixel_pitch_mm() == pytest.approx(36.0 / 2000)
    assert needs(sensor_fit="HORIZONTAL", resolution_x=1000,
                 resolution_y=2000).pixel_pitch_mm() == pytest.approx(36.0 / 1000)
    assert needs(sensor_fit="VERTICAL").pixel_pitch_mm() == pytest.approx(24.0 / 1080)
    assert needs(pixel_fraction=0.25).error_budget_um() == pytest.approx(1000 * 0.25 * 36 / 1920)


def test_03_render_region_gives_the_film_radii():
    """The whole frame is a disc to its corner; a centred region a smaller disc; an
    off-centre region a ring that misses the axis."""
    full = needs()
    w, h = 36.0, 36.0 * 1080 / 1920
    assert full.film_radii_mm() == pytest.approx((0.0, math.hypot(w / 2, h / 2)))
    centre = needs(border=(0.4, 0.4, 0.6, 0.6))
    assert centre.film_radii_mm() == pytest.approx((0.0, math.hypot(0.1 * w, 0.1 * h)))
    corner = needs(border=(0.75, 0.75, 1.0, 1.0))
    r0, r1 = corner.film_radii_mm()
    assert r0 == pytest.approx(math.hypot(0.25 * w, 0.25 * h))
    assert r1 == pytest.approx(math.hypot(w / 2, h / 2))


def test_04_region_follows_aperture_focus_and_spectrum():
    """The training region's stop is the widest f-number's (never wider than the lens), its
    sensor range brackets the focus distances used, and without dispersion it is one line."""
    lens = load_lens(PRESETS / "double_gauss_50mm_f2.toml")
    r8 = training_region(lens, needs(f_numbers=(8.0, 11.0), focus_distances_m=(2.0, 5.0)))
    r2 = training_region(lens, needs(f_numbers=(2.0,), focus_distances_m=(2.0,)))
    r1 = training_region(lens, needs(f_numbers=(1.0,), focus_distances_m=(2.0,)))
    assert r8.stop_radius_mm == pytest.approx(lens.stop_radius_mm * 2.0 / 8.0 * 1.02, rel=1e-6)
    assert r1.stop_radius_mm == r2.stop_radius_mm == pytest.approx(lens.stop_radius_mm)
    assert r8.sensor_z_range[0] < r2.sensor_z_range[0] < r2.sensor_z_range[1]
    nd = training_region(lens, needs(dispersion=False))
    assert nd.wavelength_range_nm[0] == nd.wavelength_range_nm[1] and not nd.dispersion
    with pytest.raises(SceneNeedsError, match="nearer than the lens's closest focus"):
        training_region(lens, needs(focus_distances_m=(0.01,)))


def test_05_region_key_changes_with_lens_and_region_only():
    """The cache key is stable for equal inputs and changes with the prescription, the region
    and the trainer settings."""
    lens = load_lens(PRESETS / "double_gauss_50mm_f2.toml")
    other = load_lens(PRESETS / "double_gauss_f1_35.toml")
    r = training_region(lens, needs(f_numbers=(4.0,)))
    assert r.key(lens, {"a": 1}) == training_region(lens, needs(f_numbers=(4.0,))).key(lens, {"a": 1})
    assert r.key(lens, {"a": 1}) != r.key(other, {"a": 1})
    assert r.key(lens, {"a": 1}) != r.key(lens, {"a": 2})
    assert r.key(lens, {"a": 1}) != training_region(lens, needs(f_numbers=(5.6,))).key(lens, {"a": 1})


@pytest.mark.parametrize("kw, pattern", [
    (dict(resolution_x=0), "resolution_x must be a positive integer"),
    (dict(sensor_width_mm=float("nan")), "sensor_width_mm must be a positive number"),
    (dict(sensor_fit="DIAGONAL"), "sensor_fit must be one of"),
    (dict(border=(0.5, 0.0, 0.5, 1.0)), "border must satisfy"),
    (dict(f_numbers=(-2.0,)), "f-number must be a positive number"),
    (dict(focus_distances_m=(float("inf"),)), "focus distance must be a positive number"),
])
def test_06_settings_that_describe_no_image_are_refused(kw, pattern):
    """Bad render settings raise SceneNeedsError naming the setting."""
    with pytest.raises(SceneNeedsError, match=pattern):
        needs(**kw)


def test_07_region_stops_at_the_image_circle():
    """A fisheye on Blender's default camera (36 mm, 16:9): the region's film radius is the
    lens's image circle (no light reaches the corners beyond it); the double Gauss, whose
    circle is larger, keeps the film's radius grown by the margin."""
    from neurolens_addon.core.field import image_circle_radius_mm
    full = needs(f_numbers=(4.0,), focus_distances_m=(3.0,))
    film = full.film_radii_mm()[1]
    fish = load_lens(PRESETS / "fisheye_f4.toml")
    r = training_region(fish, full)
    circle = max(image_circle_radius_mm(fish, z) for z in r.sensor_z_range)
    assert r.film_radius_mm == pytest.approx(circle) and circle < film
    dg = load_lens(PRESETS / "double_gauss_50mm_f2.toml")
    assert training_region(dg, full).film_radius_mm == pytest.approx(1.02 * film)
