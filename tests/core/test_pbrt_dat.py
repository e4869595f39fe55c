"""Lens files in pbrt's RealisticCamera .dat layout (radius, thickness, index, aperture
diameter per row): import, first-order data, errors naming the line, fuzzing."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import (
    dump_lens, load_lens, load_pbrt_dat, loads_lens, loads_pbrt_dat,
)
from neurolens_addon.core.prescription import Lens, Material

# A double-Gauss-like lens in pbrt's layout (radius thickness index aperture_diameter; mm).
DGAUSS_DAT = """\
# A made-up double Gauss in pbrt RealisticCamera layout
# radius   thickness   index   aperture
 30.0      4.0         1.67    25.0
 90.0      0.2         1       25.0
 19.5      4.0         1.67    23.0
 42.0      3.3         1.70    23.0
 12.8      5.7         1       18.0
 0         4.5         0       17.0    # aperture stop
-14.5      1.2         1.60    17.0
 41.0      6.0         1.66    20.0
-20.5      0.2         1       20.0
 400.0     3.2         1.72    20.0
-40.0      0           1       20.0
"""


def test_01_pbrt_double_gauss_import(tmp_path):
    """pbrt import: 11 surfaces, one flat stop, positive f, last thickness = paraxial BFD."""
    p = tmp_path / "dgauss.50mm.dat"
    p.write_text(DGAUSS_DAT)
    lens = load_lens(p)
    assert len(lens.surfaces) == 11
    assert lens.stop_index == 5 and math.isinf(lens.surfaces[5].radius_mm)
    assert sum(s.stop for s in lens.surfaces) == 1
    assert 30.0 < lens.focal_length_mm < 80.0
    assert 1.0 < lens.f_number < 4.0
    assert lens.surfaces[-1].thickness_mm > 0
    assert lens.surfaces[0].material == Material.from_abbe(1.67, None)
    assert lens.surfaces[0].material.vd is None and lens.surfaces[1].material.is_air
    assert lens.surfaces[5].semi_diameter_mm == 8.5
    assert lens.name == "dgauss.50mm" and lens.source == "pbrt .dat file dgauss.50mm.dat"
    assert "dispersion" in lens.notes and "made-up double Gauss" in lens.notes
    assert loads_lens(dump_lens(lens)) == lens
    assert load_pbrt_dat(p) == lens


def test_02_pbrt_paraxial_matches_thick_lens_formula():
    """The importer's efl, bfd and f-number agree with the thick-lens formulas."""
    n, r1, r2, d, stop_sd = 1.5, 50.0, -80.0, 5.0, 4.0
    text = f"0 2 1 {2 * stop_sd}\n{r1} {d} {n} 30\n{r2} 99 1 30\n"
    lens = loads_pbrt_dat(text, path="singlet.dat")
    phi = (n - 1) * (1 / r1 - 1 / r2 + (n - 1) * d / (n * r1 * r2))
    f = 1 / phi
    bfd = f * (1 - (n - 1) * d / (n * r1))
    assert lens.focal_length_mm == pytest.approx(f, rel=1e-12)
    assert lens.surfaces[-1].thickness_mm == pytest.approx(bfd, rel=1e-12)
    # a front stop is its own entrance pupil
    assert lens.f_number == pytest.approx(f / (2 * stop_sd), rel=1e-12)


PBRT_BAD = [
    ("three columns", "0 2 1 8\n50 5 1.5\n-80 1 1 30\n", "line 2", None),
    ("not a number", "0 2 1 8\n50 5 glass 30\n-80 1 1 30\n", "line 2", "index"),
    ("nan token", "0 2 1 8\n50 nan 1.5 30\n-80 1 1 30\n", "line 2", "thickness"),
    ("no stop", "50 5 1.5 30\n-80 1 1 30\n", "radius 0", "stop"),
    ("zero diameter", "0 2 1 8\n50 5 1.5 0\n-80 1 1 30\n", "line 2", "aperture_diameter"),
    ("index below 1", "0 2 1 8\n50 5 0.5 30\n-80 1 1 30\n", "line 2", "index"),
    ("glass stop", "0 2 1.5 8\n50 5 1.5 30\n-80 1 1 30\n", "line 1", "index"),
    ("last in glass", "0 2 1 8\n50 5 1.5 30\n-80 1 1.5 30\n", "line 3", "index"),
    ("zero thickness", "0 2 1 8\n50 0 1.5 30\n-80 1 1 30\n", "line 2", "thickness"),
    ("diverging", "0 2 1 8\n-50 5 1.5 30\n80 1 1 30\n", "diverging", "radius"),
    ("sd beyond sphere", "0 2 1 8\n10 5 1.5 30\n-80 1 1 30\n", "line 2", "aperture_diameter"),
    ("empty", "# only a comment\n\n", "no surface rows", "surface"),
]


@pytest.mark.parametrize("text,needle,field", [b[1:] for b in PBRT_BAD],
                         ids=[b[0] for b in PBRT_BAD])
def test_03_pbrt_errors_name_the_line(tmp_path, text, needle, field):
    """Malformed pbrt files raise LensError naming the file, the line and the column."""
    p = tmp_path / "bad_lens.dat"
    p.write_text(text)
    with pytest.raises(LensError) as info:
        load_lens(p)
    msg = str(info.value)
    assert "bad_lens.dat" in msg and needle in msg
    if field is not None:
        assert f"field '{field}'" in msg


def test_04_pbrt_several_radius_zero_rows():
    """Several radius-0 rows: the one limiting the axial beam is the stop, the rest clip."""
    text = "0 2 1 20\n50 5 1.5 30\n-80 1 1 30\n0 3 1 6\n"
    lens = loads_pbrt_dat(text, path="two_apertures.dat")
    assert lens.stop_index == 3 and math.isinf(lens.surfaces[0].radius_mm)
    assert not lens.surfaces[0].stop and "limits the axial beam" in lens.notes


# ---- fuzz ----------------------------------------------------------------------------------
@settings(max_examples=150, deadline=None)
@given(rows=st.lists(st.lists(st.one_of(
    st.sampled_from(["0", "1", "1.5", "-20", "20", "0.5", "nan", "inf", "x", "#", "1e400"]),
    st.floats(-100, 100).map(repr)), min_size=0, max_size=5), max_size=8))
def test_05_fuzz_pbrt_returns_lens_or_lens_error(rows):
    """Random pbrt rows: a Lens or a LensError, nothing else."""
    text = "\n".join(" ".join(r) for r in rows)
    try:
        lens = loads_pbrt_dat(text, path="fuzz.dat")
    except LensError as exc:
        assert "fuzz.dat" in str(exc)
        return
    assert isinstance(lens, Lens) and lens.focal_length_mm > 0
