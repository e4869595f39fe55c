"""Glass dispersion: the shipped catalog, the (n_d, V_d) model, lookup, media and bad input."""

from __future__ import annotations

import warnings
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neurolens_addon.core.errors import GlassError
from neurolens_addon.core.glass import (
    AIR, AbbeGlass, Glass, GlassCatalog, WAVELENGTH_C_NM, WAVELENGTH_F_NM, WAVELENGTH_G_NM,
    default_catalog, load_catalog, medium_index, resolve_medium)
from neurolens_addon.core.prescription import WAVELENGTH_D_NM, Material

CATALOG = default_catalog()
NAMES = CATALOG.names()
VISIBLE = np.linspace(380.0, 780.0, 801)


def _abbe(medium) -> tuple[float, float]:
    nd, nf, nc = medium.index(np.array([WAVELENGTH_D_NM, WAVELENGTH_F_NM, WAVELENGTH_C_NM]))
    return float(nd), float((nd - 1.0) / (nf - nc))


# ---- the shipped catalog -----------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
def test_01_catalog_glass_reproduces_listed_nd_vd(name):
    """Every catalog glass's formula gives its listed n_d within 2e-5 and V_d within 0.1."""
    g = CATALOG.get(name)
    nd, vd = _abbe(g)
    assert abs(nd - g.nd) <= 2e-5
    assert abs(vd - g.vd) <= 0.1


@pytest.mark.parametrize("name", NAMES)
def test_02_catalog_glass_has_normal_dispersion(name):
    """Every catalog glass's index falls strictly and is convex across the visible part of the
    range its maker states the formula for."""
    g = CATALOG.get(name)
    lo, hi = g.wavelength_range_nm
    n = g.index(VISIBLE[(VISIBLE >= lo) & (VISIBLE <= hi)])    # where the maker states it
    assert n.size > 100
    assert np.all(np.isfinite(n))
    assert np.all(np.diff(n) < 0)
    assert np.all(np.diff(n, 2) > 0)
    assert 1.4 < n.min() and n.max() < 2.4


def test_03_catalog_size_makers_and_sources():
    """The catalogue holds the makers' catalogues: >= 150 glasses from each of Schott, Ohara,
    Hoya and CDGM (800 in all), each citing its catalogue version and source file."""
    assert len(CATALOG) >= 800
    counts = Counter(g.manufacturer for g in CATALOG)
    for maker in ("Schott", "Ohara", "Hoya", "CDGM"):
        assert counts[maker] >= 150, counts
    for g in CATALOG:
        assert "catalog" in g.source.lower() and ".yml" in g.source, g.name
        lo, hi = g.wavelength_range_nm
        assert 0 < lo <= 460.0 and hi > WAVELENGTH_C_NM, g.name


def test_04_nbk7_matches_schott_data_sheet():
    """N-BK7 gives the SCHOTT data-sheet indices n_F, n_C, n_g, n_e and n at 1060 nm."""
    wl = [486.1327, 656.2725, 435.8343, 546.0740, 1060.0]
    sheet = [1.52238, 1.51432, 1.52668, 1.51872, 1.50669]
    assert np.allclose(CATALOG.get("N-BK7").index(wl), sheet, atol=1e-5)


@pytest.mark.parametrize("group", [
    ("N-BK7", "BSC7", "H-K9L"),                      # 517642: Sellmeier vs HOYA power series
    ("S-FPL51", "FCD1", "H-FK61"),                   # 497816
    ("N-SF57", "S-TIH53", "FDS90", "H-ZF52"),        # 847238
    ("N-LAK8", "S-LAL8", "LAC8"),                    # 713538
])
def test_05_same_glass_code_agrees_across_makers(group):
    """Equivalent glasses of different makers (and formulas) agree within 3e-4 over 400-700 nm."""
    wl = np.linspace(400.0, 700.0, 301)
    ref = CATALOG.get(group[0]).index(wl)
    for name in group[1:]:
        assert np.abs(CATALOG.get(name).index(wl) - ref).max() < 3e-4, name


# ---- the (n_d, V_d) model ----------------------------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(nd=st.floats(1.35, 2.1), vd=st.floats(15.0, 100.0))
def test_06_abbe_glass_reproduces_nd_vd_exactly(nd, vd):
    """AbbeGlass gives n_d and V_d = (n_d - 1)/(n_F - n_C) to rounding error."""
    g = AbbeGlass(nd, vd)
    got_nd, got_vd = _abbe(g)
    assert got_nd == pytest.approx(nd, abs=1e-12)
    assert got_vd == pytest.approx(vd, rel=1e-9)


@settings(max_examples=200, deadline=None)
@given(nd=st.floats(1.35, 2.1), vd=st.floats(15.0, 100.0))
def test_07_abbe_glass_follows_normal_line_and_is_physical(nd, vd):
    """AbbeGlass has Schott's normal-line P_gF and a falling, convex index over 380-780 nm."""
    g = AbbeGlass(nd, vd)
    ng, nf, nc = g.index(np.array([WAVELENGTH_G_NM, WAVELENGTH_F_NM, WAVELENGTH_C_NM]))
    assert (ng - nf) / (nf - nc) == pytest.approx(0.6438 - 0.001682 * vd, abs=1e-9)
    n = g.index(VISIBLE)
    assert np.all(np.diff(n) < 0)
    assert np.all(np.diff(n, 2) > 0)


@pytest.mark.parametrize("name", ["N-BK7", "N-SF6", "N-LAK9"])
def test_08_abbe_glass_close_to_real_glass(name):
    """AbbeGlass from a real glass's (n_d, V_d) stays within 2e-3 of it over 400-700 nm."""
    real = CATALOG.get(name)
    model = AbbeGlass(real.nd, real.vd)
    wl = np.linspace(400.0, 700.0, 601)
    assert np.abs(model.index(wl) - real.index(wl)).max() < 2e-3


def test_09_abbe_glass_without_vd_is_constant():
    """AbbeGlass with vd None is non-dispersive: n = n_d everywhere."""
    g = AbbeGlass(1.7, None)
    assert np.all(g.index(VISIBLE) == 1.7)


def test_10_abbe_glass_rejects_unphysical_input():
    """AbbeGlass raises GlassError for n_d < 1, non-finite n_d or V_d <= 0."""
    for nd, vd in [(0.9, 50.0), (float("nan"), 50.0), (1.5, 0.0), (1.5, -3.0), (1.0, 40.0)]:
        with pytest.raises(GlassError):
            AbbeGlass(nd, vd)


# ---- lookup ------------------------------------------------------------------------------------

@pytest.mark.parametrize("query, expected", [
    ("N-BK7", "N-BK7"), ("nbk7", "N-BK7"), ("N BK7", "N-BK7"), ("n_bk7", "N-BK7"),
    ("BK7", "N-BK7"), ("Schott N-BK7", "N-BK7"), ("N-BK7 (SCHOTT)", "N-BK7"),
    ("S-BSL7", "S-BSL7"), ("sbsl7", "S-BSL7"), ("S BSL7", "S-BSL7"), ("OHARA S-BSL7", "S-BSL7"),
    ("s-lah66", "S-LAH66"), ("TAF1", "TAF1"), ("e-fd1", "E-FD1"), ("EFD1", "E-FD1"),
    ("fcd1", "FCD1"), ("H-K9L", "H-K9L"), ("hk9l", "H-K9L"), ("H-ZF52", "H-ZF52"),
    ("F2", "F2"), ("N-F2", "N-F2"), ("SK16", "N-SK16"),
])
def test_11_name_lookup_variants(query, expected):
    """Lookup ignores case, spaces, hyphens, maker names and unique maker prefixes."""
    assert query in CATALOG
    assert CATALOG.get(query).name == expected


def test_12_unknown_glass_error_suggests_near_name():
    """An unknown name raises GlassError naming the glass and suggesting close matches."""
    with pytest.raises(GlassError) as info:
        CATALOG.get("N-BK8")
    msg = str(info.value)
    assert "'N-BK8'" in msg and "N-BK7" in msg
    assert "N-BK8" not in CATALOG
    with pytest.raises(KeyError):        # GlassError is also a KeyError
        CATALOG.get("unobtainium")


def test_13_ambiguous_bare_name_is_an_error():
    """A bare name shared by two prefixed glasses raises GlassError listing both."""
    cat = GlassCatalog([Glass("N-XY1", "Schott", [1.0, 0.2, 1.0], [0.006, 0.02, 100.0]),
                        Glass("H-XY1", "CDGM", [1.0, 0.2, 1.0], [0.006, 0.02, 100.0])])
    assert cat.get("nxy1").name == "N-XY1"
    with pytest.raises(GlassError, match="ambiguous.*N-XY1.*H-XY1"):
        cat.get("XY1")
    assert "XY1" not in cat


def test_14_nearest_glass_in_nd_vd():
    """nearest() returns the catalog glass closest in (n_d, V_d/100)."""
    assert CATALOG.nearest(1.80518, 25.36).name == "N-SF6"
    assert CATALOG.nearest(1.4970, 81.5).nd == pytest.approx(1.497, abs=2e-4)
    g = CATALOG.nearest(1.62041, 60.3)
    assert abs(g.nd - 1.62041) < 1e-5 and abs(g.vd - 60.3) < 0.1


# ---- media of a prescription -------------------------------------------------------------------

def test_15_air_is_exactly_one():
    """Air has index exactly 1.0 with the shape of the wavelength array."""
    wl = np.full((3, 4), 550.0)
    n = medium_index(Material.air(), wl)
    assert n.shape == (3, 4) and n.dtype == np.float64 and np.all(n == 1.0)
    assert resolve_medium(Material("AIR")) is AIR


def test_16_resolve_medium_kinds():
    """resolve_medium: catalog name -> that Glass, (n_d, V_d) -> AbbeGlass, unknown -> error."""
    assert resolve_medium(Material("n-bk7")) is CATALOG.get("N-BK7")
    m = resolve_medium(Material.from_abbe(1.6204, 60.3))
    assert isinstance(m, AbbeGlass)
    assert resolve_medium(Material.from_abbe(1.6204, 60.3)) is m     # resolved once, cached
    assert np.all(medium_index(Material.from_abbe(1.55, None), [450.0, 650.0]) == 1.55)
    wl = np.linspace(400, 700, 7)
    assert np.array_equal(medium_index(Material("S-LAH66"), wl), CATALOG.get("S-LAH66").index(wl))
    with pytest.raises(GlassError, match="NOPE-1"):
        resolve_medium(Material("NOPE-1"))


MEDIA = [CATALOG.get("N-BK7"), CATALOG.get("BSC7"), AbbeGlass(1.6, 40.0), AbbeGlass(1.6, None),
         AIR]


@pytest.mark.parametrize("medium", MEDIA, ids=lambda m: m.name)
def test_17_vectorised_shapes_preserved(medium):
    """index() keeps any input shape (scalars -> 0-d) and always returns float64."""
    assert medium.index(550.0).shape == ()
    assert medium.index(550).dtype == np.float64
    for shape in [(0,), (5,), (2, 3), (2, 1, 4)]:
        wl = np.random.default_rng(0).uniform(400, 700, shape).astype(np.float32)
        n = medium.index(wl)
        assert n.shape == shape and n.dtype == np.float64
        assert np.allclose(n.ravel(), [float(medium.index(float(x))) for x in wl.ravel()])
    out = np.empty((2, 3))
    wl = np.full((2, 3), 500.0)
    assert medium.index(wl, out=out) is not None and np.array_equal(out, medium.index(wl))
    with pytest.raises(ValueError):
        medium.index(wl, out=np.empty(6))


@pytest.mark.parametrize("medium", MEDIA, ids=lambda m: m.name)
def test_18_bad_wavelength_gives_nan_not_exception(medium):
    """Non-finite or non-positive wavelengths give NaN (no warning); the rest compute normally."""
    wl = np.array([np.nan, 550.0, np.inf, -np.inf, 0.0, -500.0, 450.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        n = medium.index(wl)
    assert np.all(np.isnan(n[[0, 2, 3, 4, 5]]))
    assert n[1] == medium.index(550.0) and n[6] == medium.index(450.0)
    assert np.isnan(medium.index(float("nan")))


# ---- catalog files -----------------------------------------------------------------------------

GOOD_ENTRY = """
[[glass]]
name = "N-BK7"
manufacturer = "Schott"
B1 = 1.03961212
B2 = 0.231792344
B3 = 1.01046945
C1 = 0.00600069867
C2 = 0.0200179144
C3 = 103.560653
nd = 1.5168
vd = 64.17
wavelength_range_nm = [300, 2500]
source = "SCHOTT catalogue"
"""


@pytest.mark.parametrize("text, fragment", [
    (GOOD_ENTRY + GOOD_ENTRY.replace("N-BK7", "MYGLASS").replace("B2 = 0.231792344\n", ""),
     "'B2'"),
    (GOOD_ENTRY.replace("N-BK7", "MYGLASS").replace("nd = 1.5168", "nd = 1.5268"), "n_d"),
    (GOOD_ENTRY.replace("N-BK7", "MYGLASS").replace("B3 = 1.01046945", "B3 = 'x'"), "'B3'"),
    (GOOD_ENTRY.replace("N-BK7", "MYGLASS").replace("C1 =", "K1 ="), "'K1'"),
    (GOOD_ENTRY.replace("N-BK7", "MYGLASS").replace('source = "SCHOTT catalogue"', ""),
     "'source'"),
    (GOOD_ENTRY.replace("N-BK7", "MYGLASS") + GOOD_ENTRY.replace("N-BK7", "my-glass"),
     "twice"),
])
def test_19_malformed_catalog_names_file_and_entry(tmp_path, text, fragment):
    """A malformed catalog entry raises GlassError naming the file, the entry and the field."""
    path = tmp_path / "bad_catalog.toml"
    path.write_text(text)
    with pytest.raises(GlassError) as info:
        load_catalog(path)
    msg = str(info.value)
    assert "bad_catalog.toml" in msg
    assert "MYGLASS" in msg or "my-glass" in msg
    assert fragment in msg


def test_20_unreadable_catalog_files(tmp_path):
    """Invalid TOML, no [[glass]] tables or a missing file raise GlassError naming the file."""
    bad = tmp_path / "broken.toml"
    bad.write_text("[[glass]\nname = ")
    empty = tmp_path / "empty.toml"
    empty.write_text("title = 'no glasses'\n")
    for path in (bad, empty, tmp_path / "missing.toml"):
        with pytest.raises(GlassError, match=path.name):
            load_catalog(path)


def test_21_catalog_file_round_trip_and_schott_formula(tmp_path):
    """A user catalog loads (Sellmeier and Schott-formula entries) and default_catalog is cached."""
    hoya = CATALOG.get("BSC7")
    text = GOOD_ENTRY + "\n[[glass]]\nname = \"BSC7\"\nmanufacturer = \"Hoya\"\n" \
        "formula = \"schott\"\n" + "".join(f"A{i} = {a!r}\n" for i, a in enumerate(hoya.A)) + \
        "nd = 1.5168\nvd = 64.2\nsource = \"HOYA\"\n"
    path = tmp_path / "mine.toml"
    path.write_text(text)
    cat = load_catalog(path)
    assert sorted(cat.names()) == ["BSC7", "N-BK7"]
    assert np.array_equal(cat.get("bsc7").index(VISIBLE), hoya.index(VISIBLE))
    assert default_catalog() is default_catalog()


@pytest.mark.parametrize("nd,vd", [(1.05, 3.0), (1.2, 5.0), (1.01, 1.0), (1.92286, 18.9)])
def test_abbe_law_never_falls_below_vacuum(nd, vd):
    """Far outside the visible the (n_d, V_d) law's asymptote may lie below 1: the index is
    held at 1 there, n_d is still met exactly at the d line."""
    from neurolens_addon.core.glass import AbbeGlass
    g = AbbeGlass(nd, vd)
    lam = np.array([300.0, 587.5618, 2000.0, 5000.0, 1e5, 1e7])
    n = g.index(lam)
    assert np.all(n >= 1.0) and n[1] == pytest.approx(nd, abs=1e-12)


def test_21_a_name_two_makers_list_finds_the_preferred_maker_and_the_maker_picks(tmp_path):
    """Schott's and CDGM's F2 (the same glass type): the bare name finds Schott's (the first of
    MAKER_PRECEDENCE), 'CDGM F2' and 'F2 (CDGM)' find CDGM's; both count in the catalogue;
    a folder of catalogue files loads as one catalogue."""
    from neurolens_addon.core.glass import load_catalog
    entry = ('[[glass]]\nname = "F2"\nmanufacturer = "{m}"\nB1 = 1.34533359\nB2 = 0.209073176\n'
             'B3 = 0.937357162\nC1 = 0.00997743871\nC2 = 0.0470450767\nC3 = 111.886764\n'
             'nd = 1.62004\nvd = 36.37\nsource = "test"\n')
    (tmp_path / "cdgm.toml").write_text(entry.format(m="CDGM"))
    (tmp_path / "schott.toml").write_text(entry.format(m="Schott"))
    cat = load_catalog(tmp_path)
    assert len(cat) == 2
    assert cat.get("F2").manufacturer == "Schott"
    assert cat.get("CDGM F2").manufacturer == "CDGM"
    assert cat.get("F2 (CDGM)").manufacturer == "CDGM"
    (tmp_path / "more.toml").write_text(entry.format(m="Schott"))
    with pytest.raises(GlassError, match="listed twice"):
        load_catalog(tmp_path)


SINGLET = """
name = "t"
source = "test"
focal_length_mm = 50.0
f_number = 4.0
[[surface]]
radius = 30.0
thickness = 5.0
material = %s
semi_diameter = 8.0
stop = true
[[surface]]
radius = -200.0
thickness = 45.0
material = "air"
semi_diameter = 8.0
"""


def singlet(material: str):
    """A singlet lens whose glass is `material` (a TOML value), read by our TOML reader."""
    from neurolens_addon.core.lensfile import loads_lens
    return loads_lens(SINGLET % material)


def test_22_a_lens_names_a_glass_with_its_numbers_for_when_the_catalogue_lacks_it():
    """material = { name, nd, vd }: the catalogue's glass when it knows the name, else the
    numbers model it under its name, with a note; the writer keeps the name."""
    from neurolens_addon.core.lensfile import dump_lens, loads_lens
    known = singlet('{ name = "N-BK7", nd = 1.5168, vd = 64.17 }')
    assert known.surfaces[0].material == Material("N-BK7")
    assert "not in the catalogue" not in known.notes
    unknown = singlet('{ name = "XQ-99", nd = 1.5168, vd = 64.17 }')
    assert unknown.surfaces[0].material == Material("XQ-99", nd=1.5168, vd=64.17)
    assert "glass XQ-99 (surface 1) is not in the catalogue" in unknown.notes
    back = loads_lens(dump_lens(unknown))
    assert back.surfaces == unknown.surfaces


def test_23_a_legacy_name_is_read_as_its_successor_and_said():
    lens = singlet('"SK16"')
    assert lens.surfaces[0].material == Material("N-SK16")
    assert "glass SK16 (surface 1) is read as N-SK16" in lens.notes
    assert "is read as" not in singlet('"n_sk16"').notes


def test_24_a_maker_named_is_a_maker_meant():
    """'Hoya BK7' is not Schott's N-BK7: a maker's name looks in that maker's glasses only."""
    assert CATALOG.get("Schott BK7").name == "N-BK7"
    assert "Hoya BK7" not in CATALOG
    assert CATALOG.get("Hoya BSC7").manufacturer == "Hoya"


def test_25_a_maker_named_glass_stays_that_makers_in_a_lens():
    """'CDGM F2' in a lens is CDGM's F2 (n_d 1.6129), not Schott's F2 the bare name finds: the
    lens check keeps the maker in the name, and the TOML writer writes it back."""
    from neurolens_addon.core.glass import resolve_medium
    from neurolens_addon.core.lensfile import dump_lens, loads_lens
    for spelt in ('"CDGM F2"', '"cdgm f2"', '{ name = "CDGM F2", nd = 1.6129, vd = 36.0 }'):
        lens = singlet(spelt)
        assert lens.surfaces[0].material == Material("CDGM F2"), spelt
        assert resolve_medium(lens.surfaces[0].material).manufacturer == "CDGM"
        assert "is read as" not in lens.notes
        assert loads_lens(dump_lens(lens)).surfaces == lens.surfaces
    assert singlet('"F2"').surfaces[0].material == Material("F2")


def test_26_the_glass_model_figures_in_the_docs_are_the_catalogues():
    """docs/measurements.md's error figures of the (n_d, V_d) model are what
    scripts/glass_model_doc.py computes over the whole shipped catalogue now (run it after
    changing the catalogue or the model)."""
    from testdata.scripts import load_script
    doc = load_script("glass_model_doc")
    assert doc.main(["--check"]) == 0
    assert len(doc.errors()) == len(CATALOG)
