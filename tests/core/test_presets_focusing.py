"""Presets that focus by moving groups reproduce their patents' tabulated close-focus states,
and breathe as the patent says, not as the same lens focused as a unit would.

The magnifications are the patents' own (cited in each preset's `source` and `notes`): at the
tabulated distance the moved groups put the paraxial image on the design plane (the sensor
stays) with the patent's magnification, and the focal length changes with focus (breathing)."""

import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.paraxial import paraxial_data, paraxial_image_z, paraxial_magnification
from neurolens_addon.core.variable_gaps import focus_position, lens_at

PRESETS = Path(__file__).resolve().parents[2] / "presets" / "lenses"

# (preset, tabulated focus position, the patent's magnification at it, unit focusing differs)
PATENT_STATES = [
    ("tele_300mm_f2_8_if", 1, -0.1413, False),     # US 5,745,306 ex. 1
    ("tele_135mm_f2_if", 1, -0.19, True),          # JP 2018-049102 ex. 1
    ("aspheric_24mm_f1_4", 1, -0.172, False),      # WO 2019/073744 ex. 1
    ("macro_100mm_f2_8", 1, -0.5, True),           # US 7,864,451 ex. 1
    ("macro_100mm_f2_8", 2, -1.0, True),
    ("macro_180mm_f3_5", 1, -0.1, False),          # JP H9-211319 ex. 1
    ("macro_180mm_f3_5", 2, -0.5, True),
    ("macro_180mm_f3_5", 3, -1.0, True),
]


def unit_focused_magnification(lens, distance_mm):
    """The magnification were the lens at infinity focused on `distance_mm` by moving it as a
    whole (the sensor plane at the paraxial image); NaN when it cannot reach that distance."""
    z = 0.0
    for _ in range(500):
        z_new = paraxial_image_z(lens, distance_mm, z)
        if abs(z_new - z) < 1e-10:
            return paraxial_magnification(lens, distance_mm, z_new)
        z = z_new
    return math.nan


@pytest.mark.parametrize("stem,k,beta,unit_differs", PATENT_STATES,
                         ids=[f"{s}-{k}" for s, k, _, _ in PATENT_STATES])
def test_tabulated_focus_states_match_the_patent(stem, k, beta, unit_differs):
    lens = load_lens(PRESETS / f"{stem}.toml")
    distance = lens.focus_gaps.positions[k]
    # Blender's float32 distance names the tabulated state itself; a distance just off it is
    # solved (the patent prints distances rounded) and lands next to it
    blender = float(np.float32(distance / 1000.0)) * 1000.0
    assert focus_position(lens, blender) == k
    assert focus_position(lens, distance * (1.0 + 1e-5)) == pytest.approx(k, abs=5e-3)
    moved = lens_at(lens, focus=k)
    assert abs(paraxial_image_z(moved, distance)) < 1e-3 * lens.focal_length_mm
    got = paraxial_magnification(moved, distance)
    assert got == pytest.approx(beta, rel=0.01)
    unit = unit_focused_magnification(lens, distance)
    if unit_differs:                    # breathing the unit-focused lens would not have
        assert not abs(unit / got - 1.0) < 0.03
    efl_near, efl_inf = paraxial_data(moved).efl_mm, paraxial_data(lens).efl_mm
    assert efl_near != pytest.approx(efl_inf, rel=1e-4)      # the focal length moves with focus
