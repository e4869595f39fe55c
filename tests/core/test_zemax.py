"""Zemax sequential .zmx files: every preset round-trips (TOML -> zmx -> TOML identical), a
file written the way OpticStudio writes one (UTF-16, curvatures, model glasses, centimetres,
an even asphere) imports to the prescription it holds, and bad files give one-line errors
naming the file, the surface and the field. The system lines: ENPD is the entrance pupil the
stop gives, GCAT, fields and wavelengths are written and read back alike, GCAT picks the
maker of a glass name, a legacy glass name is read as its successor with a note."""

from __future__ import annotations

import math
import re

import numpy as np

import pytest

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import dump_lens, dump_zmx, load_lens, loads_lens, loads_zmx
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


# --- system lines: ENPD, GCAT, fields, wavelengths -------------------------------------------

ROUND = [p for p in PRESETS if not load_lens(p).anamorphic]


def _lines(text):
    """An independent reading of a .zmx text's system lines: {KEY: [tokens, ...]}."""
    out = {}
    for raw in text.splitlines():
        tok = raw.split()
        if tok and not raw[:1].isspace():
            out.setdefault(tok[0], []).append(tok[1:])
    return out


def test_12_enpd_is_the_entrance_pupil_the_stop_gives():
    """ENPD is the paraxial entrance pupil diameter of the stop, not f / N: the double Gauss
    states F/2 but its stop gives F/2.03, and other tools must read the latter; our own
    f-number still comes back from the NOTE lines."""
    for path in ROUND:
        lens = load_lens(path)
        text = dump_zmx(lens)
        (enpd,), = _lines(text)["ENPD"]
        ep = paraxial_data(lens).entrance_pupil.diameter_mm
        assert float(enpd) == pytest.approx(ep, rel=1e-12), path.stem
    lens = load_lens(PRESETS_DIR / "double_gauss_50mm_f2.toml")
    (enpd,), = _lines(dump_zmx(lens))["ENPD"]
    assert lens.f_number == 2.0
    assert paraxial_data(lens).efl_mm / float(enpd) == pytest.approx(2.03, abs=0.005)
    assert loads_zmx(dump_zmx(lens)).f_number == 2.0
    # a file without our notes: the f-number is the stop's, and ENPD agrees with it (no note)
    back = loads_zmx(_without_our_notes(dump_zmx(lens)))
    assert back.f_number == pytest.approx(2.03, abs=0.005)
    assert "ENPD" not in back.notes


@pytest.mark.parametrize("path", ROUND, ids=lambda p: p.stem)
def test_13_gcat_fields_and_wavelengths_agree_with_an_independent_reading(path):
    """GCAT lists the makers of the lens's catalogue glasses (none: no GCAT), WAVM the F, d
    and C lines with d primary, YFLN 0, 0.7 and 1 times the half field (the stated field of
    view, else a full-frame diagonal at the focal length); loads_zmx_system reads the same."""
    from neurolens_addon.core.field import FULL_FRAME_HALF_DIAGONAL_MM
    from neurolens_addon.core.glass import default_catalog
    from neurolens_addon.core.lensfile.zemax import loads_zmx_system
    lens = load_lens(path)
    text = dump_zmx(lens)
    rows = _lines(text)
    got = loads_zmx_system(text)

    cat = default_catalog()
    makers = {cat.get(s.material.name).manufacturer.upper() for s in lens.surfaces
              if s.material.is_catalog}
    gcat = tuple(rows["GCAT"][0]) if "GCAT" in rows else ()
    assert set(gcat) == makers and len(gcat) == len(makers)
    assert got.catalogs == gcat

    ftyp = rows["FTYP"][0]
    n_fields, n_waves = int(ftyp[2]), int(ftyp[3])
    assert ftyp[0] == "0" and got.field_type == 0
    waves = {int(t[0]): float(t[1]) for t in rows["WAVM"]}
    assert [waves[i] for i in range(1, n_waves + 1)] == [0.4861327, 0.5875618, 0.6562725]
    (primary,), = rows["PWAV"]
    assert waves[int(primary)] == 0.5875618
    assert got.wavelengths_um == (0.4861327, 0.5875618, 0.6562725)
    assert got.primary == int(primary) and got.weights == (1.0, 1.0, 1.0)

    ys = [float(v) for v in rows["YFLN"][0][:n_fields]]
    xs = [float(v) for v in rows["XFLN"][0][:n_fields]]
    assert got.fields_y == tuple(ys) and got.fields_x == tuple(xs) and not any(xs)
    half = (lens.field_of_view_deg / 2 if lens.field_of_view_deg else
            math.degrees(math.atan(FULL_FRAME_HALF_DIAGONAL_MM / paraxial_data(lens).efl_mm)))
    assert ys == pytest.approx([0.0, 0.7 * half, half], rel=1e-11)
    # without our notes the fields give the field of view back
    back = loads_zmx(_without_our_notes(text))
    assert back.field_of_view_deg == pytest.approx(2 * half, rel=1e-11)


def _doublet(front, back):
    """A cemented doublet (glasses `front`, `back`) with the stop in front, built in code."""
    s = (Surface(radius_mm=60.0, thickness_mm=6.0, material=front, semi_diameter_mm=12.0,
                 stop=True),
         Surface(radius_mm=-40.0, thickness_mm=3.0, material=back, semi_diameter_mm=12.0),
         Surface(radius_mm=-150.0, thickness_mm=95.0, material=Material.air(),
                 semi_diameter_mm=12.0))
    return Lens(name="doublet", source="test", focal_length_mm=100.0, f_number=4.0, surfaces=s)


def test_14_gcat_picks_the_maker_of_a_name_two_makers_list():
    """Schott and CDGM both list F2 (n_d 1.62004 and 1.61293): GCAT's order decides, and where
    both are listed the GLAS line's n_d; the writer orders GCAT so that each name finds its own
    maker first, so a lens with CDGM's F2 round-trips, and so does one with both F2s."""
    cdgm = _doublet(Material("N-BK7"), Material("CDGM F2"))
    text = dump_zmx(cdgm)
    assert _lines(text)["GCAT"] == [["CDGM", "SCHOTT"]]
    assert "  GLAS F2 0 0 1.612929" in text
    assert loads_zmx(text) == cdgm
    assert loads_zmx(_without_our_notes(text)).surfaces == cdgm.surfaces
    both = _doublet(Material("F2"), Material("CDGM F2"))
    assert loads_zmx(dump_zmx(both)).surfaces == both.surfaces
    assert loads_lens(dump_lens(cdgm)).surfaces == cdgm.surfaces   # the TOML keeps it too

    base, _ = _foreign(glass_line="  GLAS F2 0 0 0 0 0 0 0 0 0 0")
    for gcat, maker in (("SCHOTT", "Schott"), ("CDGM", "CDGM"), ("CDGM SCHOTT", "CDGM"),
                        ("MISC", "Schott")):
        lens = loads_zmx(base.replace("GCAT SCHOTT", f"GCAT {gcat}"))
        name = lens.surfaces[0].material.name
        assert name == ("CDGM F2" if maker == "CDGM" else "F2"), gcat
    by_nd = base.replace("GCAT SCHOTT", "GCAT SCHOTT CDGM").replace("F2 0 0 0 0", "F2 0 0 1.6129 0")
    assert loads_zmx(by_nd).surfaces[0].material == Material("CDGM F2")


def test_15_a_legacy_name_is_read_as_its_successor_and_said_as_the_toml_reader_does():
    text, _ = _foreign(glass_line="  GLAS SK16 0 0 1.62041 60.32 0 0 0 0 0 0")
    got = loads_zmx(text, path="old.zmx")
    assert got.surfaces[0].material == Material("N-SK16")
    said = "glass SK16 (surface 1) is read as N-SK16"
    assert said in got.notes
    toml = dump_lens(got).replace('material = "N-SK16"', 'material = "SK16"', 1)
    assert said in loads_lens(toml).notes
    # a name in none of the file's catalogues is still ours, said; a wrong n_d is said
    other = loads_zmx(text.replace("GCAT SCHOTT", "GCAT HOYA"), path="old.zmx")
    assert other.surfaces[0].material == Material("N-SK16")
    assert "glass SK16 (surface 1) is in none of the file's catalogues (HOYA)" in other.notes
    off = loads_zmx(text.replace("1.62041 60.32", "1.7 60.32"), path="old.zmx")
    assert "the file's n_d 1.7 is not the catalogue's 1.62041" in off.notes


@pytest.mark.parametrize("line,match", [
    ("GCAT", "GCAT names no glass catalogue"),
    # (characters that print as nothing are shown as "?"; control characters refuse the file)
    ("GCAT SCHOTT LZOS \u200b\u00ad", r"catalogue\(s\) LZOS, \?\? \(GCAT\) are not among ours"),
    ("ENPD 30", r"ENPD 30 mm\) is not the one its stop gives \(24.8051 mm"),
    ("FTYP 1 0 2 3\nYFLN 0 10", None),                  # object heights: no field of view
    ("FTYP 0 0 2 3\nYFLN 0 10 30", "field of view 20 deg"),
])
def test_16_system_lines_accepted_with_a_note(line, match):
    text, _ = _foreign()
    text = text.replace("GCAT SCHOTT\n", "").replace("ENPD 24.8\n", "")
    lens = loads_zmx(text.replace("SURF 0", line + "\nSURF 0", 1), path="s.zmx")
    if match is None:
        assert lens.field_of_view_deg is None and "field of view" not in lens.notes
    else:
        assert re.search(match, lens.notes), lens.notes


@pytest.mark.parametrize("line,match", [
    ("ENPD -2", r"field 'ENPD': line \d+: ENPD: expected a diameter > 0"),
    ("ENPD x", r"field 'ENPD': line \d+: ENPD: expected a finite number, got 'x'"),
    ("WAVM 1 abc 1", r"field 'WAVM': line \d+: WAVM: expected a finite number, got 'abc'"),
    ("WAVM 0 0.55 1", r"field 'WAVM': line \d+: WAVM 0: expected an index >= 1"),
    ("WAVL 0.5 -1", r"field 'WAVL'.*wavelengths > 0"),
    ("PWAV 4", r"field 'PWAV': line \d+: PWAV 4: the file has wavelengths 1 to 1"),
    ("FTYP 0 0 x 3", r"field 'FTYP': line \d+: FTYP: expected an integer, got 'x'"),
    ("FTYP 7", r"field 'FTYP'.*field type 7"),
    ("YFLN 0 1e999", r"field 'YFLN': line \d+: YFLN: expected a finite number"),
    ("GCAT SCHOTT LZOS \u0001\u0002", r"bad.zmx: line \d+: control character U\+0001 inside"),
])
def test_17_bad_system_lines_give_one_line_errors_naming_file_line_and_keyword(line, match):
    text, _ = _foreign()
    text = text.replace("ENPD 24.8\n", "")
    if line.startswith("WAVL"):                         # (WAVM records win over WAVL)
        text = text.replace("WAVM 1 0.5876 1\n", "")
    with pytest.raises(LensError, match=match) as err:
        loads_zmx(text.replace("SURF 0", line + "\nSURF 0", 1), path="bad.zmx")
    assert "\n" not in str(err.value) and str(err.value).startswith("bad.zmx")
