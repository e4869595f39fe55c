"""Importing pbrt-v3/v4 RealisticCamera lens files (`.dat`, docs/lens-format.md).

Rows `radius thickness index aperture_diameter` (mm, ASCII numbers; no control character in a
line: lensfile.tokens) front to back; radius 0 is an aperture
(flat), index 0 or 1 air, other indices index-only glasses (no dispersion). pbrt's last
thickness is a focus placeholder: it is replaced by the paraxial back focal distance of a y-nu
trace at n_d of the ray from infinity at height y_1 = 1,
    n'u' = n u - y (n' - n) c,      y_next = y + t n'u' / n',
    efl = -y_1 / (n'u')_last,       bfd = -y_last / (n'u')_last,
and f-number = efl / (2 r_EP) with the entrance-pupil radius r_EP = sd_stop y_1 / |y_stop|; of
several radius-0 rows, the one with the smallest sd / |y| limits the axial beam and is the stop.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..lensfields import Where
from ..prescription import Lens, Material, Surface
from .checks import check_lens
from .source import MAX_SURFACES, check_text, read_text
from .tokens import check_lines, shown, to_float

_PBRT_FIELDS = {"radius": "radius", "thickness": "thickness", "material": "index",
                "semi_diameter": "aperture_diameter"}
_PBRT_COLUMNS = ("radius", "thickness", "index", "aperture_diameter")


def _paraxial_marginal(surfaces) -> tuple[list[float], float]:
    """y-nu trace at n_d of the ray from infinity at height 1: heights at each surface, n'u'.

    Sign convention as the prescription: light travels towards the sensor, c > 0 when the
    centre of curvature is on the sensor side (each surface's paraxial curvature).
    """
    heights = []
    y, nu, n = 1.0, 0.0, 1.0
    for j, s in enumerate(surfaces):
        m = s.material
        n2 = 1.0 if m.is_air else float(m.nd)
        c = s.shape.paraxial_curvature
        heights.append(y)
        nu = nu - y * (n2 - n) * c
        if j < len(surfaces) - 1:
            y = y + s.thickness_mm * nu / n2
        n = n2
    return heights, nu


def load_pbrt_dat(path) -> Lens:
    """Import a pbrt-v3/v4 RealisticCamera lens file (see docs/lens-format.md)."""
    return loads_pbrt_dat(read_text(path), path=str(path))


def loads_pbrt_dat(text: str, path=None) -> Lens:
    """Parse the text of a pbrt `.dat` lens file; `path` names it in errors and the lens name."""
    where = Where(path, fields=_PBRT_FIELDS, line_word="is on line")
    check_text(text, where)
    check_lines(text, where)
    rows, lines, comments = [], [], []
    for lineno, raw in enumerate(text.splitlines(), 1):
        body, hash_, comment = raw.partition("#")
        if hash_ and comment.strip() and not rows:
            comments.append(comment.strip())
        tokens = body.split()
        if not tokens:
            continue
        if len(tokens) != 4:
            raise where.error(f"line {lineno}: expected 4 numbers (radius thickness index "
                              f"aperture_diameter, in mm), got {len(tokens)} values")
        values = []
        for col, tok in zip(_PBRT_COLUMNS, tokens):
            v = to_float(tok)
            if v is None or not math.isfinite(v):
                raise where.error(f"line {lineno}: expected a finite number for {col}, got "
                                  f"'{shown(tok)}'", surface=len(rows), field=col)
            values.append(v)
        rows.append(values)
        lines.append(lineno)
        if len(rows) > MAX_SURFACES:
            raise where.error(f"line {lineno}: more than {MAX_SURFACES} surfaces, refusing the "
                              "file", field="surface")
    if not rows:
        raise where.error("no surface rows: expected rows of 'radius thickness index "
                          "aperture_diameter' (mm), front to back", field="surface")
    where = Where(path, surface_lines=lines, fields=_PBRT_FIELDS, line_word="is on line")

    surfaces = []
    stop_rows = []
    for i, (radius, thickness, index, diameter) in enumerate(rows):
        if diameter <= 0.0:
            raise where.error(f"aperture_diameter must be > 0 mm, got {diameter:g}", surface=i,
                              field="semi_diameter")
        is_stop = radius == 0.0
        if index in (0.0, 1.0):
            material = Material.air()
        elif is_stop:
            raise where.error(f"an aperture stop (radius 0) must be in air: index 0 or 1, got "
                              f"{index:g}", surface=i, field="material")
        elif index < 1.0:
            raise where.error(f"index must be >= 1 (0 or 1 means air), got {index:g}",
                              surface=i, field="material")
        else:
            material = Material.from_abbe(index, None)
        if is_stop:
            stop_rows.append(i)
        surfaces.append(Surface(radius_mm=math.inf if is_stop else radius,
                                thickness_mm=thickness, material=material,
                                semi_diameter_mm=diameter / 2.0, stop=is_stop))
    if not stop_rows:
        raise where.error("no aperture stop: pbrt marks it with a row of radius 0",
                          field="stop")
    if not surfaces[-1].material.is_air:
        raise where.error("the last row must be followed by air (index 0 or 1)",
                          surface=len(surfaces) - 1, field="material")
    for i, s in enumerate(surfaces[:-1]):
        if not s.thickness_mm > 0.0:
            raise where.error(f"thickness must be > 0 mm (the axial distance to the next row), "
                              f"got {s.thickness_mm:g}", surface=i, field="thickness")

    heights, nu = _paraxial_marginal(surfaces)
    if not (math.isfinite(nu) and nu < 0.0):
        kind = "afocal" if nu == 0.0 else "diverging (negative focal length)"
        raise where.error(f"the lens is {kind} at n_d: it forms no real image of a distant "
                          "object", field="radius")
    efl = -1.0 / nu
    bfd = -heights[-1] / nu
    if not (math.isfinite(bfd) and bfd > 0.0):
        raise where.error(f"the paraxial image lies {-bfd:g} mm inside the last surface "
                          "(back focal distance <= 0)", surface=len(surfaces) - 1,
                          field="thickness")
    # The aperture stop is the radius-0 row that limits the axial bundle; any other radius-0
    # rows stay flat clipping apertures without stop = true.
    ratios = [surfaces[i].semi_diameter_mm / abs(heights[i]) if heights[i] != 0.0 else math.inf
              for i in stop_rows]
    stop = stop_rows[int(np.argmin(ratios))]
    if not math.isfinite(ratios[stop_rows.index(stop)]):
        raise where.error("the axial marginal ray crosses the stop at height 0", surface=stop,
                          field="radius")
    entrance_pupil_radius = ratios[stop_rows.index(stop)]
    f_number = efl / (2.0 * entrance_pupil_radius)
    surfaces = [replace(s, stop=(i == stop)) for i, s in enumerate(surfaces)]
    file_last = surfaces[-1].thickness_mm
    surfaces[-1] = replace(surfaces[-1], thickness_mm=bfd)

    file_name = Path(path).name if path is not None else "<text>"
    lens_name = Path(path).stem if path is not None else "pbrt lens"
    notes = [f"Imported from the pbrt RealisticCamera lens file {file_name}.",
             "pbrt gives one refractive index per medium and no dispersion: materials are "
             "index-only (n_d, no V_d), so there is no chromatic aberration.",
             f"Last thickness set to the paraxial back focal distance {bfd:.6g} mm (the file's "
             f"{file_last:g} is pbrt's focus placeholder); focal length {efl:.6g} mm and "
             f"f-number {f_number:.4g} (= efl / entrance-pupil diameter, object at infinity) "
             "from a paraxial marginal-ray trace at n_d."]
    if len(stop_rows) > 1:
        notes.append(f"Several radius-0 rows (lines {', '.join(str(lines[i]) for i in stop_rows)}"
                     f"); the one on line {lines[stop]} limits the axial beam and is the stop.")
    if comments:
        notes.append("File comments: " + " | ".join(comments))
    lens = Lens(name=lens_name, source=f"pbrt .dat file {file_name}", focal_length_mm=efl,
                f_number=f_number, surfaces=tuple(surfaces), field_of_view_deg=None,
                notes=" ".join(notes), path=None if path is None else str(path))
    check_lens(lens, where)
    return lens
