"""camera.lens_kinds: the picker's groups from a lens's own data."""

from __future__ import annotations

import dataclasses

import pytest

from neurolens_addon.camera.lens_kinds import full_frame_field_deg, lens_kind, picker_order
from neurolens_addon.camera.lenses import PRESETS_DIR, load_lens_entry

DG = load_lens_entry(PRESETS_DIR / "double_gauss_50mm_f2.toml").lens


@pytest.mark.parametrize("focal, kind", [(20.0, "Wide angle"), (37.4, "Wide angle"),
                                         (37.6, "Normal"), (68.0, "Normal"),
                                         (69.0, "Telephoto"), (300.0, "Telephoto")])
def test_kinds_follow_the_full_frame_field_of_the_focal_length(focal, kind):
    lens = dataclasses.replace(DG, focal_length_mm=focal, field_of_view_deg=None)
    assert lens_kind(lens) == kind


def test_a_50_mm_lens_sees_47_degrees_on_full_frame():
    assert full_frame_field_deg(dataclasses.replace(DG, focal_length_mm=50.0)) == \
        pytest.approx(46.8, abs=0.1)


def test_a_stated_wide_field_is_a_fisheye_and_a_zoom_table_a_zoom():
    from testdata.focusing_lenses import zooming_double_gauss
    assert lens_kind(dataclasses.replace(DG, field_of_view_deg=160.0)) == "Fisheye"
    assert lens_kind(zooming_double_gauss()) == "Zoom"
    assert picker_order(zooming_double_gauss()) < picker_order(DG)


def test_a_lens_whose_groups_focus_to_half_life_size_is_a_macro():
    """The 1:1 macro presets are Macro; a telephoto with internal focusing to 1:7 is not."""
    macro = load_lens_entry(PRESETS_DIR / "macro_100mm_f2_8.toml").lens
    tele = load_lens_entry(PRESETS_DIR / "tele_300mm_f2_8_if.toml").lens
    assert lens_kind(macro) == "Macro" and lens_kind(tele) == "Telephoto"
    assert picker_order(macro) < picker_order(DG)


def test_a_lens_with_cylinders_is_anamorphic_whatever_its_focal_length():
    """The anamorphic presets group together, before the spherical primes of their focal
    lengths; the test lens's cylinders make it Anamorphic though its 57 mm reads Normal."""
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    test_lens = cylinder_attachment_lens()
    assert lens_kind(test_lens) == "Anamorphic"
    assert lens_kind(dataclasses.replace(DG, focal_length_mm=test_lens.focal_length_mm)) == "Normal"
    for stem in ("anamorphic_2x_60mm_f1_9", "anamorphic_attachment_speed_panchro_50mm_f2"):
        lens = load_lens_entry(PRESETS_DIR / f"{stem}.toml").lens
        assert lens_kind(lens) == "Anamorphic" and picker_order(lens) < picker_order(DG)
