"""The shipped library: at least 40 cited lenses, of every kind a user looks for."""

from pathlib import Path

import pytest

from neurolens_addon.camera.lens_kinds import lens_kind
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data

LENSES = [load_lens(p) for p in
          sorted((Path(__file__).resolve().parents[2] / "presets" / "lenses").glob("*.toml"))]
CITATION = ("US ", "JP ", "WO ", "DE ", "GB ", "Patent", "p. ", "catalogue", "OPTI")


def _count(pred):
    return sum(1 for lens in LENSES if pred(lens))


def test_forty_lenses_each_cited():
    assert len(LENSES) >= 40
    uncited = [lens.name for lens in LENSES if not any(c in lens.source for c in CITATION)]
    assert not uncited


@pytest.mark.parametrize("what,at_least,pred", [
    ("zooms", 3, lambda l: lens_kind(l) == "Zoom"),
    ("zooms with wide, middle and tele positions", 1,
     lambda l: l.zoom_gaps is not None and l.zoom_gaps.count >= 3),
    ("fisheyes", 3, lambda l: lens_kind(l) == "Fisheye"),
    ("macros", 1, lambda l: lens_kind(l) == "Macro"),
    ("ultra-wide rectilinears (<= 21 mm)", 3,
     lambda l: lens_kind(l) == "Wide angle" and l.focal_length_mm <= 21.5),
    ("long telephotos with internal focusing (>= 200 mm)", 2,
     lambda l: l.focus_gaps is not None and l.focal_length_mm >= 200.0),
    ("modern aspheric primes at f/1.2-1.8", 3,
     lambda l: l.zoom_gaps is None and any(s.is_aspheric for s in l.surfaces)
     and l.f_number <= 1.8),
    ("lenses that state their back focus", 20, lambda l: l.back_focus_mm is not None),
])
def test_every_kind_is_there(what, at_least, pred):
    assert _count(pred) >= at_least, what


def test_no_two_presets_are_the_same_design():
    """Distinct prescriptions (a copy under two names would waste a picker slot)."""
    hashes = [lens.content_hash() for lens in LENSES]
    assert len(set(hashes)) == len(hashes)
    assert all(paraxial_data(lens).efl_mm > 0 for lens in LENSES)
