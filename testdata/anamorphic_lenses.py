"""An anamorphic lens built for tests: a front Galilean pair of cylinders powered in x (a
negative, then a positive cylinder, nearly afocal) before a spherical singlet; squeeze
f_y / f_x = 1.30. Not a real design: it exercises the anamorphic paths. The same lens with its
two cylinders turned by different angles (a misassembled attachment) couples the meridians."""

from __future__ import annotations

import dataclasses
import math

from neurolens_addon.core.lensfile import dump_lens
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.core.surfaces import Cylinder


def cylinder_attachment_lens() -> Lens:
    inf = math.inf
    air, glass = Material.air(), Material.from_abbe(1.5168, 64.17)
    return Lens("Test anamorphic attachment", "tests", 57.0, 4.0, (
        Surface(shape=Cylinder.make(-25.0, "y"), thickness_mm=2.0, material=glass,
                semi_diameter_mm=9.0),
        Surface(inf, 10.0, air, 9.0), Surface(inf, 4.0, glass, 9.0),
        Surface(shape=Cylinder.make(-32.0, "y"), thickness_mm=6.0, material=air,
                semi_diameter_mm=9.0),
        Surface(inf, 3.0, air, 6.0, stop=True),
        Surface(60.0, 5.0, glass, 8.0), Surface(-60.0, 56.0, air, 8.0)))


def turned_attachment_lens(first_deg: float, second_deg: float) -> Lens:
    """cylinder_attachment_lens with its negative cylinder turned by first_deg and its
    positive one by second_deg about the axis."""
    lens = cylinder_attachment_lens()
    s = list(lens.surfaces)
    for i, deg in ((0, first_deg), (3, second_deg)):
        s[i] = dataclasses.replace(s[i], shape=dataclasses.replace(s[i].shape,
                                                                   rotation_deg=float(deg)))
    return lens.with_surfaces(tuple(s))


def write_attachment(path) -> str:
    from pathlib import Path
    Path(path).write_text(dump_lens(cylinder_attachment_lens()))
    return str(path)
