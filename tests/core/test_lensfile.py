"""Lens files: our TOML format (load, dump, validation); pbrt .dat import is test_pbrt_dat.py."""

import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import (
    MAX_FILE_BYTES, MAX_SURFACES, dump_lens, load_lens, loads_lens, validate_lens,
)
from neurolens_addon.core.prescription import Lens, Material, Surface
from testdata.lens_documents import base_doc, fuzz_documents, to_toml

INF = math.inf


def write(tmp_path, doc_or_text, name="lens.toml"):
    p = tmp_path / name
    p.write_text(doc_or_text if isinstance(doc_or_text, str) else to_toml(doc_or_text),
                 encoding="utf-8")
    return p


def sag(s, r):
    c = s.curvature
    z = c * r * r / (1 + np.sqrt(1 - (1 + s.conic) * c * c * r * r))
    return z + sum(a * r ** p for p, a in s.aspheric)


# ---- 1. the valid lens loads as written --------------------------------------------------------
def test_01_valid_lens_loads(tmp_path):
    """A valid file gives the Lens it describes: fields, materials, asphere, stop, path."""
    lens = load_lens(write(tmp_path, base_doc()))
    assert lens.name == "test doublet" and lens.f_number == 4.0
    assert lens.focal_length_mm == 50.0 and lens.field_of_view_deg == 30.0
    assert lens.notes == "a \"quoted\" note\nwith two lines"
    assert len(lens.surfaces) == 4 and lens.stop_index == 0
    assert math.isinf(lens.surfaces[0].radius_mm) and lens.surfaces[0].material.is_air
    assert lens.surfaces[1].material == Material.from_abbe(1.6, 55.0)
    assert lens.surfaces[3].conic == -1.0
    assert lens.surfaces[3].aspheric == ((4, 1e-6), (6, -2e-9))
    assert lens.path.endswith("lens.toml")
    assert lens.vertex_z[-1] == 40.0 and lens.front_vertex_z == 51.0


# ---- 2. round trip -------------------------------------------------------------------------
def test_02_round_trip_dump_load_equal(tmp_path):
    """dump_lens -> loads_lens gives an equal Lens (and dumping again gives the same text),
    the stated back focus included."""
    doc = base_doc()
    doc["back_focus_mm"] = 38.25
    lens = load_lens(write(tmp_path, doc))
    assert lens.back_focus_mm == 38.25
    text = dump_lens(lens)
    again = loads_lens(text)
    assert again == lens
    assert dump_lens(again) == text


finite = st.floats(min_value=1e-3, max_value=1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(radii=st.lists(st.one_of(st.just(INF), st.floats(200, 1e4), st.floats(-1e4, -200)),
                      min_size=1, max_size=6),
       data=st.data())
def test_03_round_trip_random_lenses(radii, data):
    """Random valid lenses (any floats, inline materials, aspheres, text) survive dump -> load."""
    n = len(radii)
    stop = data.draw(st.integers(0, n - 1))
    surfaces = []
    for i, r in enumerate(radii):
        nd = data.draw(st.floats(1.0, 2.2))
        vd = None if nd == 1.0 else data.draw(st.one_of(st.none(), st.floats(15, 95)))
        mat = Material.air() if i == n - 1 or data.draw(st.booleans()) else Material.from_abbe(
            nd, vd)
        terms = data.draw(st.dictionaries(st.sampled_from([4, 6, 8]),
                                          st.floats(-1e-12, 1e-12).filter(bool), max_size=2))
        asph = tuple(sorted(terms.items()))
        surfaces.append(Surface(r, data.draw(st.floats(5.0, 50.0)), mat,
                                data.draw(st.floats(0.5, 5.0)),
                                conic=data.draw(st.sampled_from([0.0, -1.0, -0.5, 2.5])),
                                aspheric=asph, stop=(i == stop)))
    lens = Lens(data.draw(st.text(min_size=1).filter(str.strip)),
                data.draw(st.text(min_size=1).filter(str.strip)), data.draw(finite),
                data.draw(finite), tuple(surfaces),
                data.draw(st.one_of(st.none(), st.floats(1, 180))), data.draw(st.text()))
    from neurolens_addon.core.paraxial import paraxial_data
    try:
        paraxial_data(lens)
    except LensError:
        assume(False)       # flat surfaces only, or powers that cancel: not a lens
    validate_lens(lens)
    assert loads_lens(dump_lens(lens)) == lens


# ---- 4. scale ------------------------------------------------------------------------------
def test_04_scale_multiplies_lengths(tmp_path):
    """scale multiplies radius, thickness, semi-diameter; a_n by s^(1-n); not f or conic."""
    base = load_lens(write(tmp_path, base_doc(), "a.toml"))
    doc = base_doc()
    doc["scale"] = 0.5
    half = load_lens(write(tmp_path, doc, "b.toml"))
    assert half.focal_length_mm == base.focal_length_mm and half.f_number == base.f_number
    for a, b in zip(base.surfaces, half.surfaces):
        assert b.radius_mm == a.radius_mm * 0.5
        assert b.thickness_mm == a.thickness_mm * 0.5
        assert b.semi_diameter_mm == a.semi_diameter_mm * 0.5
        assert b.conic == a.conic and b.material == a.material and b.stop == a.stop
        assert [p for p, _ in b.aspheric] == [p for p, _ in a.aspheric]
        for (p, ca), (_, cb) in zip(a.aspheric, b.aspheric):
            assert cb == pytest.approx(ca * 0.5 ** (1 - p), rel=1e-12)
    # the scaled surface is the original magnified: sag'(s r) = s sag(r)
    r = np.linspace(0, 10.0, 7)
    assert np.allclose(sag(half.surfaces[3], 0.5 * r), 0.5 * sag(base.surfaces[3], r),
                       rtol=1e-12, atol=1e-15)


# ---- 5. malformed files: each names the file, the surface and the field -------------------------
def _set(path, value):
    def mutate(doc):
        target = doc
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return mutate


def _del(path):
    def mutate(doc):
        target = doc
        for key in path[:-1]:
            target = target[key]
        del target[path[-1]]
    return mutate


S = "surface"
# (id, mutation, expected 1-based surface or None, expected field, extra text in the message)
MALFORMED = [
    ("missing name", _del(["name"]), None, "name", "missing"),
    ("missing source", _del(["source"]), None, "source", "missing"),
    ("empty source", _set(["source"], "  "), None, "source", "non-empty"),
    ("missing focal", _del(["focal_length_mm"]), None, "focal_length_mm", "missing"),
    ("missing f_number", _del(["f_number"]), None, "f_number", "missing"),
    ("missing surfaces", _del([S]), None, "surface", "missing"),
    ("name not a string", _set(["name"], 5), None, "name", "string"),
    ("focal string", _set(["focal_length_mm"], "50"), None, "focal_length_mm", "number"),
    ("focal bool", _set(["focal_length_mm"], True), None, "focal_length_mm", "boolean"),
    ("focal negative", _set(["focal_length_mm"], -50.0), None, "focal_length_mm", "> 0"),
    ("f_number zero", _set(["f_number"], 0), None, "f_number", "> 0"),
    ("f_number nan", _set(["f_number"], math.nan), None, "f_number", "finite"),
    ("f_number inf", _set(["f_number"], INF), None, "f_number", "finite"),
    ("fov negative", _set(["field_of_view_deg"], -3.0), None, "field_of_view_deg", "360"),
    ("back focus zero", _set(["back_focus_mm"], 0.0), None, "back_focus_mm", "> 0"),
    ("back focus string", _set(["back_focus_mm"], "36"), None, "back_focus_mm", "number"),
    ("scale zero", _set(["scale"], 0.0), None, "scale", "> 0"),
    ("scale bool", _set(["scale"], False), None, "scale", "boolean"),
    ("notes not string", _set(["notes"], ["x"]), None, "notes", "string"),
    ("unknown top key", _set(["focal_lenght_mm"], 1.0), None, "focal_lenght_mm", "did you mean"),
    ("surface list empty", _set([S], []), None, "surface", "no surfaces"),
    ("surface not array", _set([S], {"radius": 1.0}), None, "surface", "array"),
    ("surface entry not table", _set([S], [1, 2]), 1, "surface", "table"),
    ("unknown surface key", _set([S, 1, "radus"], 3.0), 2, "radus", "did you mean 'radius'"),
    ("missing radius", _del([S, 1, "radius"]), 2, "radius", "missing"),
    ("missing thickness", _del([S, 2, "thickness"]), 3, "thickness", "missing"),
    ("missing material", _del([S, 2, "material"]), 3, "material", "missing"),
    ("missing semi_diameter", _del([S, 3, "semi_diameter"]), 4, "semi_diameter", "missing"),
    ("radius zero", _set([S, 1, "radius"], 0.0), 2, "radius", "flat"),
    ("radius int zero", _set([S, 1, "radius"], 0), 2, "radius", "flat"),
    ("radius nan", _set([S, 1, "radius"], math.nan), 2, "radius", "finite"),
    ("radius word", _set([S, 1, "radius"], "curved"), 2, "radius", "flat"),
    ("radius bool", _set([S, 1, "radius"], True), 2, "radius", "boolean"),
    ("radius huge int", _set([S, 1, "radius"], 10 ** 400), 2, "radius", "too large"),
    ("thickness zero", _set([S, 1, "thickness"], 0.0), 2, "thickness", "> 0"),
    ("thickness negative", _set([S, 2, "thickness"], -1.0), 3, "thickness", "> 0"),
    ("last thickness zero", _set([S, 3, "thickness"], 0), 4, "thickness", "image plane"),
    ("thickness inf", _set([S, 1, "thickness"], INF), 2, "thickness", "finite"),
    ("thickness nan", _set([S, 1, "thickness"], math.nan), 2, "thickness", "finite"),
    ("thickness bool", _set([S, 1, "thickness"], True), 2, "thickness", "boolean"),
    ("thickness table", _set([S, 1, "thickness"], {"a": 1}), 2, "thickness", "table"),
    ("semi_diameter zero", _set([S, 2, "semi_diameter"], 0.0), 3, "semi_diameter", "> 0"),
    ("semi_diameter negative", _set([S, 0, "semi_diameter"], -6.0), 1, "semi_diameter", "> 0"),
    ("semi_diameter > |R|", _set([S, 2, "semi_diameter"], 26.0), 3, "semi_diameter",
     "larger than the surface allows"),
    ("conic too oblate", _set([S, 1, "conic"], 10.0), 2, "semi_diameter", "conic"),
    ("conic nan", _set([S, 1, "conic"], math.nan), 2, "conic", "finite"),
    ("conic string", _set([S, 1, "conic"], "0"), 2, "conic", "number"),
    ("aspheric odd term", _set([S, 3, "aspheric"], {"a3": 1e-6}), 4, "aspheric", "a4"),
    ("aspheric a22", _set([S, 3, "aspheric"], {"a22": 1e-6}), 4, "aspheric", "a20"),
    ("aspheric string", _set([S, 3, "aspheric"], {"a4": "x"}), 4, "aspheric", "number"),
    ("aspheric not table", _set([S, 3, "aspheric"], [1e-6]), 4, "aspheric", "table"),
    ("aspheric overflow", _set([S, 3, "aspheric"], {"a20": 1e300}), 4, "aspheric",
     "not finite"),
    ("material nd below 1", _set([S, 1, "material"], {"nd": 0.9, "vd": 50.0}), 2, "material",
     "nd"),
    ("material vd zero", _set([S, 1, "material"], {"nd": 1.5, "vd": 0.0}), 2, "material", "vd"),
    ("material vd negative", _set([S, 2, "material"], {"nd": 1.5, "vd": -5}), 3, "material",
     "vd"),
    ("material without nd", _set([S, 1, "material"], {"vd": 50.0}), 2, "material", "nd"),
    ("material unknown key", _set([S, 1, "material"], {"nd": 1.5, "n_d": 1.5}), 2, "material",
     "n_d"),
    ("material number", _set([S, 1, "material"], 1.5), 2, "material", "air"),
    ("material empty", _set([S, 1, "material"], ""), 2, "material", "empty"),
    ("material nd bool", _set([S, 1, "material"], {"nd": True}), 2, "material", "boolean"),
    ("no stop", _del([S, 0, "stop"]), None, "stop", "no aperture stop"),
    ("two stops", _set([S, 2, "stop"], True), 3, "stop", "more than one"),
    ("stop not bool", _set([S, 0, "stop"], 1), 1, "stop", "true or false"),
    ("last medium glass", _set([S, 3, "material"], {"nd": 1.5}), 4, "material", "air"),
    ("surfaces cross", _set([S, 1, "thickness"], 0.5), 2, "thickness", "surface 3"),
]


@pytest.mark.parametrize("mutate,surface,field,extra", [m[1:] for m in MALFORMED],
                         ids=[m[0] for m in MALFORMED])
def test_05_malformed_file_names_file_surface_field(tmp_path, mutate, surface, field, extra):
    """Every malformed case raises LensError naming the file, the surface number and the field."""
    doc = base_doc()
    mutate(doc)
    path = write(tmp_path, doc, "broken_lens.toml")
    with pytest.raises(LensError) as info:
        load_lens(path)
    msg = str(info.value)
    assert "broken_lens.toml" in msg
    assert f"field '{field}'" in msg and info.value.field == field
    assert info.value.surface == surface
    if surface is not None:
        assert re.search(rf"surface {surface}\b", msg)
    assert extra in msg


def test_06_errors_point_at_the_surface_line(tmp_path):
    """Surface errors also give the line where that [[surface]] table starts."""
    doc = base_doc()
    doc["surface"][2]["thickness"] = -1.0
    text = to_toml(doc)
    line = [i for i, l in enumerate(text.splitlines(), 1) if l == "[[surface]]"][2]
    with pytest.raises(LensError, match=rf"surface 3 starts at line {line}\b"):
        load_lens(write(tmp_path, text))


def test_07_invalid_toml_reports_the_line(tmp_path):
    """Invalid TOML is a LensError with the file and the line number of the syntax error."""
    text = to_toml(base_doc()).replace('"f_number" = 4.0', '"f_number" = = 4.0')
    line = [i for i, l in enumerate(text.splitlines(), 1) if "= = 4.0" in l][0]
    with pytest.raises(LensError, match=rf"broken\.toml.*line {line}\b"):
        load_lens(write(tmp_path, text, "broken.toml"))


def test_08_unreadable_and_undecodable_files(tmp_path):
    """A missing file, a directory and non-UTF-8 bytes each raise LensError naming the file."""
    with pytest.raises(LensError, match="nothere.toml.*cannot read"):
        load_lens(tmp_path / "nothere.toml")
    (tmp_path / "adir.toml").mkdir()
    with pytest.raises(LensError, match="adir.toml.*is a directory, not a regular file"):
        load_lens(tmp_path / "adir.toml")
    p = tmp_path / "latin1.toml"
    p.write_bytes(to_toml(base_doc()).encode("utf-8") + b'\nnotes2 = "caf\xe9"\n')
    with pytest.raises(LensError, match=r"latin1.toml.*not UTF-8.*0xe9"):
        load_lens(p)
    with pytest.raises(LensError, match="lens.txt.*extension"):
        load_lens(tmp_path / "lens.txt")


def test_09_oversize_file_refused_before_parsing(tmp_path):
    """A file over 1 MiB is refused for its size, not parsed (here it is not even TOML)."""
    p = tmp_path / "huge.toml"
    p.write_text("this is not TOML\n" + "x" * MAX_FILE_BYTES, encoding="utf-8")
    with pytest.raises(LensError, match=r"huge.toml.*1 MiB") as info:
        load_lens(p)
    assert "invalid TOML" not in str(info.value)
    with pytest.raises(LensError, match="1 MiB"):
        loads_lens("x" * (MAX_FILE_BYTES + 1))


def test_10_too_many_surfaces_refused_before_parsing(tmp_path):
    """More than 256 [[surface]] tables is refused before parsing (the TOML here is broken)."""
    text = "name = = broken\n" + "[[surface]]\nradius = 1\n" * (MAX_SURFACES + 1)
    with pytest.raises(LensError, match=r"many.toml.*257.*at most 256") as info:
        load_lens(write(tmp_path, text, "many.toml"))
    assert info.value.field == "surface"


def test_11_long_dotted_keys_refused_before_parsing():
    """Pathological dotted keys (quadratic in tomllib) are refused fast, with the line."""
    with pytest.raises(LensError, match="line 2.*dotted key"):
        loads_lens("name = 'x'\n" + "a." * 200_000 + "b = 1\n", path="dots.toml")


def test_12_unknown_glass_suggests_names(tmp_path):
    """An unknown catalog glass names surface and field and carries the catalog's suggestion."""
    pytest.importorskip("neurolens_addon.core.glass")
    doc = base_doc()
    doc["surface"][1]["material"] = "N-BK77"
    with pytest.raises(LensError) as info:
        load_lens(write(tmp_path, doc, "glassy.toml"))
    msg = str(info.value)
    assert "glassy.toml" in msg and "surface 2" in msg and "field 'material'" in msg
    assert "N-BK77" in msg and "N-BK7" in msg.split("N-BK77", 1)[1]


def test_13_catalog_glass_loads_with_catalog_spelling(tmp_path):
    """A catalog glass loads by name; a loose spelling becomes the catalog's spelling."""
    pytest.importorskip("neurolens_addon.core.glass")
    doc = base_doc()
    doc["surface"][1]["material"] = "n-bk7"
    lens = load_lens(write(tmp_path, doc))
    assert lens.surfaces[1].material == Material("N-BK7")
    assert lens.surfaces[1].material.is_catalog
    assert loads_lens(dump_lens(lens)) == lens


def test_14_flat_spellings_and_touching_surfaces():
    """radius "flat", inf and -inf are planes; surfaces that touch at the edge are allowed."""
    for flat in ('"flat"', '"FLAT"', "inf", "-inf"):
        text = to_toml(base_doc()).replace('"radius" = "flat"', f'"radius" = {flat}')
        assert math.isinf(loads_lens(text).surfaces[0].radius_mm)
    # thickness exactly the sag difference at the common edge: contact, no crossing
    doc = base_doc()
    s1, s2 = 30.0, -25.0
    edge = (s1 - math.sqrt(s1 * s1 - 100)) + (abs(s2) - math.sqrt(s2 * s2 - 100))
    doc["surface"][1]["thickness"] = edge
    loads_lens(to_toml(doc))
    doc["surface"][1]["thickness"] = edge - 1e-6
    with pytest.raises(LensError, match="surfaces 2 and 3 cross"):
        loads_lens(to_toml(doc))


def test_15_scale_errors_show_scaled_lengths():
    """A length error under a scale says the lengths shown are after the scale."""
    doc = base_doc()
    doc["scale"] = 2.0
    doc["surface"][1]["thickness"] = 0.5
    with pytest.raises(LensError, match="after scale = 2"):
        loads_lens(to_toml(doc), path="scaled.toml")


def test_16_validate_lens_on_code_built_lens():
    """validate_lens applies the same rules to a Lens built in code."""
    lens = loads_lens(to_toml(base_doc()))
    validate_lens(lens)
    bad = lens.with_surfaces([lens.surfaces[0], lens.surfaces[1],
                              Surface(-25.0, 0.0, lens.surfaces[2].material, 10.0),
                              lens.surfaces[3]])
    with pytest.raises(LensError, match="surface 3.*thickness"):
        validate_lens(bad)


# ---- fuzz ----------------------------------------------------------------------------------
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=fuzz_documents())
def test_21_fuzz_load_returns_lens_or_lens_error(text):
    """Random (mostly broken) documents: a Lens (that round-trips) or a LensError, nothing else."""
    try:
        lens = loads_lens(text, path="fuzz.toml")
    except LensError as exc:
        assert "fuzz.toml" in str(exc)
        return
    assert isinstance(lens, Lens)
    assert loads_lens(dump_lens(lens)) == lens
