"""Writing a `Lens` as our TOML format (docs/lens-format.md), with `scale` 1.

Per [[surface]] table: `kind` where a table without it would read as another kind, then the
kind's required keys, the keys every surface has (thickness, material, semi_diameter), the
kind's optional keys, and `stop = true` for the stop. `loads_lens` reads the text back into an
equal `Lens`.
"""

from __future__ import annotations

from ..lensfields import toml_float, toml_string
from ..prescription import Lens
from .checks import is_named_model
from .gap_tables import write_gap_table


def dump_lens(lens: Lens) -> str:
    """TOML text of `lens` in our format (scale 1) that `loads_lens` reads back equal."""
    out = ["# NeuroLens lens prescription (format: docs/lens-format.md)",
           "# lens space: mm, +z to the scene, design image plane at z = 0",
           f"name = {toml_string(lens.name)}",
           f"source = {toml_string(lens.source)}",
           f"focal_length_mm = {toml_float(lens.focal_length_mm)}",
           f"f_number = {toml_float(lens.f_number)}"]
    if lens.field_of_view_deg is not None:
        out.append(f"field_of_view_deg = {toml_float(lens.field_of_view_deg)}")
    if lens.back_focus_mm is not None:
        out.append(f"back_focus_mm = {toml_float(lens.back_focus_mm)}")
    if lens.notes:
        out.append(f"notes = {toml_string(lens.notes)}")
    for s in lens.surfaces:
        out += ["", "[[surface]]"]
        shape = s.shape
        if not shape.implied:
            out.append(f"kind = {toml_string(shape.kind)}")
        items = shape.toml_items()
        out += [f"{k} = {v}" for k, v in items if k in shape.required_keys]
        out.append(f"thickness = {toml_float(s.thickness_mm)}")
        m = s.material
        if m.is_air:
            out.append('material = "air"')
        elif m.nd is not None:
            parts = [f"nd = {toml_float(m.nd)}"]
            if is_named_model(m):
                parts.insert(0, f"name = {toml_string(m.name)}")
            if m.vd is not None:
                parts.append(f"vd = {toml_float(m.vd)}")
            out.append("material = { " + ", ".join(parts) + " }")
        else:
            out.append(f"material = {toml_string(m.name)}")
        out.append(f"semi_diameter = {toml_float(s.semi_diameter_mm)}")
        out += [f"{k} = {v}" for k, v in items if k not in shape.required_keys]
        if s.stop:
            out.append("stop = true")
    for kind, table in (("focus", lens.focus_gaps), ("zoom", lens.zoom_gaps)):
        if table is not None:
            out += write_gap_table(kind, table)
    return "\n".join(out) + "\n"
