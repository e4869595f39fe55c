"""The kind of a lens, for grouping the lens picker: from the lens's own data.

    Zoom         a [zoom] table (core.variable_gaps)
    Anamorphic   a surface without rotational symmetry (a cylinder, toroid or biconic): the
                 frame is desqueezed, whatever the focal length
    Macro        a [focus] table whose closest focus images at half life size or more
                 (|paraxial magnification| >= 0.5, core.paraxial)
    Fisheye      a stated design field of view (`field_of_view_deg`) of 130 degrees or more
    then by the focal length's field on a full-frame diagonal (43.27 mm), 2 atan(21.63 / f),
    as photographers name lenses:
    Wide angle   60 degrees or more (f <= 37.5 mm)
    Normal       35 to 60 degrees (37.5 < f <= 68.6 mm)
    Telephoto    under 35 degrees
"""

from __future__ import annotations

import math

KINDS = ("Zoom", "Anamorphic", "Macro", "Fisheye", "Wide angle", "Normal", "Telephoto")
#: a lens that reaches this magnification at its closest focus is a macro lens
MACRO_MAGNIFICATION = 0.5
FULL_FRAME_HALF_DIAGONAL_MM = 21.63


def full_frame_field_deg(lens) -> float:
    """The diagonal field of view of the lens's focal length on a full-frame sensor."""
    return math.degrees(2.0 * math.atan(FULL_FRAME_HALF_DIAGONAL_MM / lens.focal_length_mm))


def is_macro(lens) -> bool:
    """Whether the lens's groups focus it to half life size or closer."""
    table = lens.focus_gaps
    if table is None:
        return False
    from ..core.paraxial import paraxial_magnification
    from ..core.variable_gaps import lens_at
    near = lens_at(lens, focus=float(table.count - 1))
    m = paraxial_magnification(near, table.positions[-1])
    return math.isfinite(m) and abs(m) >= MACRO_MAGNIFICATION


def lens_kind(lens) -> str:
    if lens.zoom_gaps is not None:
        return "Zoom"
    if lens.anamorphic:
        return "Anamorphic"
    if is_macro(lens):
        return "Macro"
    if lens.field_of_view_deg is not None and lens.field_of_view_deg >= 130.0:
        return "Fisheye"
    fov = full_frame_field_deg(lens)
    if fov >= 60.0:
        return "Wide angle"
    if fov >= 35.0:
        return "Normal"
    return "Telephoto"


def picker_order(lens) -> tuple:
    """Sort key of the picker: by kind, then focal length."""
    return (KINDS.index(lens_kind(lens)), float(lens.focal_length_mm))
