"""Lenses with moving gaps, built for tests from a preset. The rear-focusing double Gauss:
its rear group (surfaces 7-11) moves forward to focus, the sensor fixed; the close position's
gaps are solved here by bisection on the paraxial image (independently of
core.variable_gaps), so the [focus] table is a self-consistent design. The 'zooming' double
Gauss: its central air space (surface 5) opens by 6 mm between two stated focal lengths (a
variable gap to exercise the zoom path, not a real zoom design)."""

from __future__ import annotations

import dataclasses
import math

from neurolens_addon.camera.lenses import PRESETS_DIR
from neurolens_addon.core.lensfile import dump_lens, load_lens
from neurolens_addon.core.paraxial import paraxial_image_z
from neurolens_addon.core.variable_gaps import VariableGaps

DGAUSS = PRESETS_DIR / "double_gauss_50mm_f2.toml"
CLOSE_MM = 2000.0
STOP_GAP, LAST_GAP = 5, 10          # 0-based: stop -> rear group, last surface -> sensor


def rear_focusing_double_gauss(close_mm: float = CLOSE_MM):
    """The double Gauss with a [focus] table: infinity and close_mm."""
    lens = load_lens(DGAUSS)
    t = [s.thickness_mm for s in lens.surfaces]

    def moved(delta):
        surfaces = list(lens.surfaces)
        for i, v in ((STOP_GAP, t[STOP_GAP] - delta), (LAST_GAP, t[LAST_GAP] + delta)):
            surfaces[i] = dataclasses.replace(surfaces[i], thickness_mm=v)
        return lens.with_surfaces(surfaces)
    lo, hi = 0.0, t[STOP_GAP] - 0.1
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if (paraxial_image_z(moved(mid), close_mm) > 0) == \
                (paraxial_image_z(moved(lo), close_mm) > 0):
            lo = mid
        else:
            hi = mid
    if not 0.01 < lo < t[STOP_GAP] - 0.11:
        raise ValueError(f"the rear group cannot focus {close_mm} mm")
    delta = 0.5 * (lo + hi)
    table = VariableGaps((math.inf, close_mm), (STOP_GAP, LAST_GAP),
                         ((t[STOP_GAP], t[STOP_GAP] - delta), (t[LAST_GAP], t[LAST_GAP] + delta)))
    return dataclasses.replace(lens, name=lens.name + ", rear focusing", focus_gaps=table)


def write(path) -> str:
    """The rear-focusing double Gauss as a lens file at `path`; its path as a string."""
    from pathlib import Path
    Path(path).write_text(dump_lens(rear_focusing_double_gauss()))
    return str(path)


ZOOM_RANGE_MM = (50.0, 60.0)


def zooming_double_gauss():
    lens = load_lens(DGAUSS)
    t = lens.surfaces[4].thickness_mm
    table = VariableGaps(ZOOM_RANGE_MM, (4,), ((t, t + 6.0),))
    return dataclasses.replace(lens, name=lens.name + ", zooming", zoom_gaps=table)


def write_zoom(path) -> str:
    from pathlib import Path
    Path(path).write_text(dump_lens(zooming_double_gauss()))
    return str(path)
