"""Small lenses built in code for the core tests (no files, no catalog glass)."""

import math

from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.prescription import Lens, Material, Surface

INF = math.inf


def singlet(radius=100.0, thickness=2.0, nd=1.5, vd=None, stop_radius=5.0, sd=20.0):
    """A bi-convex singlet with a stop 1 mm in front, sensor at its paraxial focus."""
    glass = Material.from_abbe(nd, vd)
    def build(last):
        return Lens("test singlet", "tests", 100.0, 10.0, (
            Surface(INF, 1.0, Material.air(), stop_radius, stop=True),
            Surface(radius, thickness, glass, sd),
            Surface(-radius, last, Material.air(), sd)))
    return build(paraxial_data(build(90.0)).bfd_mm)


# Smith, Modern Lens Design (1992) p. 312: double Gauss F/2 after US 2,673,491, scaled to 50 mm
# (radius, thickness, n_d, V_d, clear diameter); the stop is the radius-0 row.
_DGAUSS = [(29.475, 3.76, 1.670, 47.2, 25.2), (84.83, 0.12, 1, 0, 25.2),
           (19.275, 4.025, 1.670, 47.2, 23.0), (40.77, 3.275, 1.699, 30.1, 23.0),
           (12.75, 5.705, 1, 0, 18.0), (0, 4.5, 1, 0, 17.1), (-14.495, 1.18, 1.603, 38.0, 17.0),
           (40.77, 6.065, 1.658, 57.3, 20.0), (-20.385, 0.19, 1, 0, 20.0),
           (437.065, 3.22, 1.717, 48.0, 20.0), (-39.73, 40.0, 1, 0, 20.0)]


def double_gauss():
    def build(last):
        rows = []
        for i, (r, t, n, v, ap) in enumerate(_DGAUSS):
            mat = Material.air() if n == 1 else Material.from_abbe(n, v)
            rows.append(Surface(INF if r == 0 else r, last if i == len(_DGAUSS) - 1 else t, mat,
                                ap / 2.0, stop=(r == 0)))
        return Lens("test double Gauss", "Smith, Modern Lens Design p.312", 50.0, 2.0, tuple(rows))
    return build(paraxial_data(build(40.0)).bfd_mm)
