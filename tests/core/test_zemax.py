"""Zemax sequential .zmx files: every preset round-trips (TOML -> zmx -> TOML identical), a
file written the way OpticStudio writes one (UTF-16, curvatures, model glasses, centimetres,
an even asphere) imports to the prescription it holds, and bad files give one-line errors
naming the file, the surface and the field."""

from __future__ import annotations

import math

import numpy as np

import pytest

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import dump_lens, dump_zmx, load_lens, loads_zmx
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.camera.lenses import PRESETS_DIR

PRESETS = sorted(PRESETS_DIR.glob("*.toml"))


@pytest.mark.parametrize("path", PRESETS, ids=lambda p: p.stem)
def test_01_every_preset_round_trips_through_zmx(path, tmp_path):
    """Every preset of revolution round-trips; an anamorphic one is refused, naming its first
    surface without rotational symmetry (the writer has STANDARD and EVENASPH only)."""
    lens = load_lens(path)
    if lens.anamorphic:
        first = next(i for i, s in enumerate(lens.surfaces) if not s.shape.rotationally_symmetric)
        with pytest.raises(LensError, match=f"surface {first + 1}, field 'kind'.*revolution only"):
            dump_zmx(lens)
        return
    out = tmp_path / f"{path.stem}.zmx"
    out.write_text(dump_zmx(lens))
    back = load_lens(out)
    assert back == lens
    assert dump_lens(back) == dump_lens(lens)


def _foreign(unit="MM", scale=1.0, glass_line=None, extra="", stop=True, kind="STANDARD",
             curv_digits=10):
    """The double Gauss preset written as OpticStudio would: curvatures to `curv_digits`
    digits, model glasses (or `glass_line` on the first element), no NeuroLens notes."""
    lens = load_lens(PRESETS_DIR / "double_gauss_50mm_f2.toml")
    rows = ["VERS 190500 80 123457", "MODE SEQ", "NAME Tronnier double Gauss",
            f"UNIT {unit} X W X CM MR CPMR", "ENPD 24.8", "GCAT SCHOTT", "WAVM 1 0.5876 1",
            "SURF 0", "  TYPE STANDARD", "  CURV 0.0 0 0 0 0 \"\"", "  DISZ INFINITY"]
    for i, s in enumerate(lens.surfaces, 1):
        rows.append(f"SURF {i}")
        rows.append(f"  TYPE {kind if i == 1 else 'STANDARD'}")
        c = 0.0 if math.isinf(s.radius_mm) else 1.0 / (s.radius_mm / scale)
        rows.append(f"  CURV {c:.{curv_digits}E} 0 0 0 0 \"\"")
        if s.stop and stop:
            rows.append("  STOP")
        rows.append(f"  DISZ {s.thickness_mm / scale!r}")
        m = s.material
        if not m.is_air:
            rows.append(glass_line if (glass_line and i == 1) else
                        f"  GLAS ___BLANK 1 0 {m.nd} {m.vd} 0 0 0 0 0 0")
        rows.append(f"  DIAM {s.semi_diameter_mm / scale!r} 1 0 0 1 \"\"")
        rows.append("  COAT NONE")
    rows += [f"SURF {len(lens.surfaces) + 1}", "  TYPE STANDARD", "  DISZ 0", "  DIAM 21.6"]
    return "\ufeff" + "\n".join(rows) + "\n" + extra, lens


@pytest.mark.parametrize("unit,scale", [("MM", 1.0), ("CM", 10.0), ("IN", 25.4)])
def test_02_an_opticstudio_file_imports_to_the_prescription_it_holds(tmp_path, unit, scale):
    text, lens = _foreign(unit, scale)
    p = tmp_path / "dgauss.zmx"
    p.write_bytes(text.encode("utf-16"))               # OpticStudio's own encoding
    got = load_lens(p)
    assert got.name == "Tronnier double Gauss"
    assert len(got.surfaces) == len(lens.surfaces) and got.stop_index == lens.stop_index
    for a, b in zip(got.surfaces, lens.surfaces):
        assert a.radius_mm == pytest.approx(b.radius_mm, rel=1e-9)
        assert a.thickness_mm == pytest.approx(b.thickness_mm, rel=1e-12)
        assert a.semi_diameter_mm == pytest.approx(b.semi_diameter_mm, rel=1e-12)
        assert a.material == b.material
    # no NeuroLens notes: focal length and f-number from the paraxial trace, and said so
    p_ref = paraxial_data(lens)
    assert got.focal_length_mm == pytest.approx(p_ref.efl_mm, rel=1e-9)
    assert got.f_number == pytest.approx(p_ref.f_number, rel=1e-9)
    assert got.focal_length_mm == pytest.approx(50.36, rel=0.01)  # the patent's, scaled
    assert "paraxial trace" in got.notes


def test_03_catalogue_glasses_and_unknown_ones():
    text, _ = _foreign(glass_line="  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0")
    assert loads_zmx(text).surfaces[0].material == Material("N-BK7")
    text, _ = _foreign(glass_line="  GLAS NOTAGLASS 0 0 1.7 40.0 0 0 0 0 0 0")
    got = loads_zmx(text, path="x.zmx")
    assert got.surfaces[0].material == Material("NOTAGLASS", nd=1.7, vd=40.0)
    assert "NOTAGLASS" in got.notes and "not in the catalogue" in got.notes
    assert loads_zmx(dump_zmx(got)).surfaces[0].material == got.surfaces[0].material
    text, _ = _foreign(glass_line="  GLAS NOTAGLASS 0 0 0 0 0 0 0 0 0 0")
    with pytest.raises(LensError, match=r"x\.zmx.*surface 1.*GLAS.*'NOTAGLASS'"):
        loads_zmx(text, path="x.zmx")


def test_04_an_even_asphere_reads_its_terms_in_mm():
    text, lens = _foreign("CM", 10.0, kind="EVENASPH")
    text = text.replace("  TYPE EVENASPH\n", "  TYPE EVENASPH\n  CONI -0.5\n"
                        "  PARM 1 0\n  PARM 2 2.0E-3\n  PARM 3 -1.0E-5\n", 1)
    s = loads_zmx(text).surfaces[0]
    assert s.conic == -0.5
    # r in cm: a4 cm^-3 -> mm^-3 is / 10^3, a6 cm^-5 -> mm^-5 is / 10^5
    assert dict(s.aspheric) == pytest.approx({4: 2.0e-6, 6: -1.0e-10})


@pytest.mark.parametrize("change,match", [
    (lambda t: t.replace("  TYPE STANDARD\n  CURV", "  TYPE TOROIDAL\n  CURV", 2),
     r"surface 1.*kind.*TOROIDAL is not supported"),
    (lambda t: t.replace("GLAS ___BLANK 1 0 1.67 47.1", "GLAS MIRROR 0 0 0 0", 1),
     r"surface 1.*GLAS.*mirrors are not supported"),
    (lambda t: t.replace("  STOP\n", ""), r"no aperture stop"),
    (lambda t: t.replace("UNIT MM", "UNIT FURLONG"), r"lens unit 'FURLONG'"),
    (lambda t: t.replace("  DISZ 3.76", "  DISZ 3.7.6", 1), r"surface 1.*DISZ.*'3\.7\.6'"),
    (lambda t: t.split("SURF 1\n")[0], r"no lens surfaces"),
])
def test_05_bad_files_give_one_line_errors_naming_file_surface_and_field(change, match):
    text, _ = _foreign()
    with pytest.raises(LensError, match=match) as err:
        loads_zmx(change(text), path="bad.zmx")
    assert "\n" not in str(err.value) and "bad.zmx" in str(err.value)


def test_06_export_refuses_what_zemax_cannot_hold():
    s = Surface(radius_mm=40.0, thickness_mm=5.0, material=Material.from_abbe(1.5, 60.0),
                semi_diameter_mm=10.0, aspheric=((4, 1e-6), (18, 1e-30)), stop=True)
    back = Surface(radius_mm=-40.0, thickness_mm=38.0, material=Material.air(),
                   semi_diameter_mm=10.0)
    lens = Lens(name="x", source="test", focal_length_mm=40.0, f_number=2.0,
                surfaces=(s, back))
    with pytest.raises(ValueError, match=r"r\^16"):
        dump_zmx(lens)


def test_07_several_configurations_are_read_as_the_first_with_a_note():
    text, _ = _foreign(extra="MNUM 3 1\n")
    assert "3 configurations" in loads_zmx(text).notes


def test_08_the_convert_command_writes_zmx_and_toml(tmp_path, capsys):
    from neurolens_addon.core.cli import main
    src = PRESETS_DIR / "tessar_f4_5.toml"
    zmx, toml = tmp_path / "t.zmx", tmp_path / "t.toml"
    assert main(["convert", str(src), "--out", str(zmx)]) == 0
    assert main(["convert", str(zmx), "--out", str(toml)]) == 0
    assert load_lens(toml) == load_lens(src)
    assert main(["convert", str(src), "--out", str(tmp_path / "t.txt")]) == 2
    assert "must end in .toml or .zmx" in capsys.readouterr().err


def test_09_focus_and_zoom_tables_round_trip(tmp_path):
    from testdata.focusing_lenses import rear_focusing_double_gauss, zooming_double_gauss
    for lens in (rear_focusing_double_gauss(), zooming_double_gauss()):
        back = loads_zmx(dump_zmx(lens))
        assert back == lens
        assert back.focus_gaps == lens.focus_gaps and back.zoom_gaps == lens.zoom_gaps


def _without_our_notes(text):
    """The file as another tool would write it: no neurolens NOTE lines or radius comments."""
    return "\n".join(line for line in text.splitlines() if "neurolens" not in line) + "\n"


def test_10_configurations_read_as_focus_or_zoom_tables_without_our_notes():
    """THIC records alone give the tables back: focus positions from the object distance per
    configuration plus the lens's length (the sensor fixed), zoom positions from each
    configuration's paraxial focal length; the surfaces hold the first position."""
    from testdata.focusing_lenses import rear_focusing_double_gauss, zooming_double_gauss
    from neurolens_addon.core.paraxial import paraxial_data
    from neurolens_addon.core.variable_gaps import lens_at
    focusing = rear_focusing_double_gauss()
    text = _without_our_notes(dump_zmx(focusing))
    assert "MNUM 2 1" in text and "THIC 0 2" in text
    back = loads_zmx(text)
    assert back.zoom_gaps is None and back.focus_gaps is not None
    assert back.focus_gaps.surfaces == focusing.focus_gaps.surfaces
    np.testing.assert_allclose(back.focus_gaps.thickness_mm, focusing.focus_gaps.thickness_mm,
                               rtol=1e-12)
    assert math.isinf(back.focus_gaps.positions[0])
    assert back.focus_gaps.positions[1] == pytest.approx(focusing.focus_gaps.positions[1],
                                                         rel=1e-12)
    assert "2 configurations read as 2 focus distances" in back.notes

    zooming = zooming_double_gauss()
    back = loads_zmx(_without_our_notes(dump_zmx(zooming)))
    assert back.focus_gaps is None and back.zoom_gaps is not None
    np.testing.assert_allclose(back.zoom_gaps.thickness_mm, zooming.zoom_gaps.thickness_mm,
                               rtol=1e-12)
    efl = [paraxial_data(lens_at(zooming, zoom=k)).efl_mm for k in range(zooming.zoom_gaps.count)]
    np.testing.assert_allclose(back.zoom_gaps.positions, efl, rtol=1e-9)


def test_11_configurations_out_of_order_and_the_ones_not_read():
    """Configurations in any order are sorted (infinity first; focal lengths ascending); a file
    whose configurations change the object distance and the gaps together, or that has no
    configuration at infinity, is read as its active configuration with a note; bad records
    are one-line errors naming the line."""
    base, _ = _foreign()
    surf = "SURF 1"
    grid = ("MNUM 2 1\nTHIC 0 1 500 0 0 0 1 1 1 0 0 \"\" 0\nTHIC 0 2 1.0E+10 0 0 0 1 1 1 0 0 "
            "\"\" 0\nTHIC 2 1 6.0 0 0 0 1 1 1 0 0 \"\" 0\nTHIC 2 2 5.0 0 0 0 1 1 1 0 0 \"\" 0\n")
    lens = loads_zmx(base.replace(surf, grid + surf, 1))
    assert lens.focus_gaps is not None and math.isinf(lens.focus_gaps.positions[0])
    assert lens.surfaces[1].thickness_mm == 5.0          # the infinity configuration's gap
    assert lens.focus_gaps.thickness_mm[0] == (5.0, 6.0)
    near = grid.replace("1.0E+10", "900")
    lens = loads_zmx(base.replace(surf, near + surf, 1))
    assert lens.focus_gaps is None and "no configuration has its object at infinity" in lens.notes
    for bad, match in (("THIC 2 3 5.0", "configuration 3"), ("THIC 2 1 -1", "thickness > 0"),
                       ("THIC x 1 5", "integers")):
        text = base.replace(surf, "MNUM 2 1\n" + bad + "\n" + surf, 1)
        with pytest.raises(LensError, match=match):
            loads_zmx(text, path="lens.zmx")
