"""Anamorphic surfaces in the exact core: equal to the surfaces of revolution they reduce to,
per-meridian paraxial data against thick-lens formulas, exact rays against the paraxial foci,
and rays that never turn NaN."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import dump_lens, loads_lens
from neurolens_addon.core.paraxial import paraxial_data, squeeze
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.surfaces import Biconic, Cylinder, StandardSurface, Toroidal
from neurolens_addon.core.trace import trace

INF = math.inf
GLASS = Material.from_abbe(1.5168, 64.17)
D = 587.5618


def lens_of(*shapes_thick, stop_first=True) -> Lens:
    """Stop, then (shape, thickness, material) rows, semi-diameters 8 mm."""
    rows = [Surface(INF, 2.0, Material.air(), 6.0, stop=True)] if stop_first else []
    for shape, t, m in shapes_thick:
        rows.append(Surface(shape=shape, thickness_mm=t, material=m, semi_diameter_mm=8.0))
    return Lens("anamorphic test", "tests", 50.0, 4.0, tuple(rows))


def parallel_rays(n=2000, seed=0, half=5.0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-half, half, (2, n))
    o = np.vstack([xy, np.full(n, 50.0)])
    d = np.tile(np.array([[0.0], [0.0], [-1.0]]), (1, n))
    return Rays(o, d, np.full(n, D))


@pytest.mark.parametrize("radius", [60.0, -45.0])
def test_01_biconic_and_toroid_with_equal_radii_trace_as_the_sphere(radius):
    """A biconic and a toroid with both radii R (turned anyhow) bend rays as the sphere of
    radius R: exit points and directions equal to 1e-9."""
    sphere = lens_of((StandardSurface(radius), 5.0, GLASS), (StandardSurface(-80.0), 40.0,
                                                            Material.air()))
    rays = parallel_rays()
    ref = trace(sphere, rays, from_sensor=False, sensor_z=None)
    for shape in (Biconic(radius, radius, 0.0, 0.0, 33.0), Toroidal(radius, radius, 0.0, 71.0)):
        lens = lens_of((shape, 5.0, GLASS), (StandardSurface(-80.0), 40.0, Material.air()))
        got = trace(lens, rays, from_sensor=False, sensor_z=None)
        assert np.array_equal(got.valid, ref.valid) and ref.valid.mean() > 0.9
        v = ref.valid
        np.testing.assert_allclose(got.rays.o[:, v], ref.rays.o[:, v], atol=1e-9)
        np.testing.assert_allclose(got.rays.d[:, v], ref.rays.d[:, v], atol=1e-9)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_02_a_plano_cylindrical_lens_has_power_in_one_meridian(axis):
    """A plano-convex cylinder of radius R focuses its powered meridian at f = R / (n - 1)
    (the thick plano-convex lens's EFL) and leaves the other without power (refused: no
    image); exact rays near the axis in the powered meridian meet at the paraxial focus,
    those in the other leave parallel."""
    R = 51.68
    lens = lens_of((Cylinder.make(R, axis), 4.0, GLASS), (StandardSurface(INF), 80.0,
                                                          Material.air()))
    powered, flat = ("y", "x") if axis == "x" else ("x", "y")
    pd = paraxial_data(lens, meridian=powered)
    assert pd.efl_mm == pytest.approx(R / (1.5168 - 1.0), rel=1e-9)
    with pytest.raises(LensError, match="no optical power"):
        paraxial_data(lens, meridian=flat)
    k = 0 if powered == "x" else 1
    o = np.zeros((3, 2))
    o[k] = (0.05, 0.1)
    o[2] = float(lens.vertex_z[0]) + 5.0
    d = np.tile(np.array([[0.0], [0.0], [-1.0]]), (1, 2))
    res = trace(lens, Rays(o, d, np.full(2, D)), from_sensor=False, sensor_z=None)
    assert res.valid.all()
    z_focus = res.rays.o[2] - res.rays.o[k] * res.rays.d[2] / res.rays.d[k]
    np.testing.assert_allclose(z_focus, pd.rear_focal_z_mm, atol=2e-3)
    o2 = np.zeros((3, 1))
    o2[1 - k] = 0.1
    o2[2] = float(lens.vertex_z[0]) + 5.0
    res = trace(lens, Rays(o2, d[:, :1], np.full(1, D)), from_sensor=False, sensor_z=None)
    np.testing.assert_allclose(res.rays.d[:, 0], [0.0, 0.0, -1.0], atol=1e-12)


def test_03_turning_a_surface_turns_its_meridians():
    """A cylinder turned by 90 degrees swaps its meridians' curvatures; at 45 degrees each
    meridian sees half its curvature."""
    c = Cylinder.make(40.0, "x")
    assert (c.paraxial_curvature, c.paraxial_curvature_x) == (pytest.approx(1 / 40.0), 0.0)
    t = Cylinder.make(40.0, "x", 0.0, 90.0)
    assert t.paraxial_curvature == pytest.approx(0.0, abs=1e-18)
    assert t.paraxial_curvature_x == pytest.approx(1 / 40.0)
    h = Cylinder.make(40.0, "x", 0.0, 45.0)
    assert h.paraxial_curvature == pytest.approx(0.5 / 40.0)
    assert h.paraxial_curvature_x == pytest.approx(0.5 / 40.0)


def test_04_a_cylindrical_adapter_squeezes_the_horizontal_field():
    """Before a spherical singlet, a Galilean pair of cylinders powered in x (a negative then
    a positive cylinder, the classic front anamorphic attachment) shortens the x meridian's
    focal length and leaves y's: squeeze f_y / f_x > 1.25, f_y equal to the singlet's alone,
    and exact rays in x converge at the x meridian's paraxial focus."""
    from testdata.anamorphic_lenses import cylinder_attachment_lens
    lens = cylinder_attachment_lens()
    alone = lens.with_surfaces(lens.surfaces[4:])          # the stop and the singlet
    fy = paraxial_data(lens).efl_mm
    fx = paraxial_data(lens, meridian="x").efl_mm
    assert fy == pytest.approx(paraxial_data(alone).efl_mm, rel=1e-9)
    assert squeeze(lens) == pytest.approx(fy / fx) and squeeze(lens) > 1.25
    assert squeeze(alone) == 1.0
    pdx = paraxial_data(lens, meridian="x")
    z0 = float(lens.vertex_z[0]) + 5.0
    o = np.array([[0.05, 0.1], [0.0, 0.0], [z0, z0]])
    d = np.tile(np.array([[0.0], [0.0], [-1.0]]), (1, 2))
    res = trace(lens, Rays(o, d, np.full(2, D)), from_sensor=False, sensor_z=None)
    assert res.valid.all()
    z = res.rays.o[2] - res.rays.o[0] * res.rays.d[2] / res.rays.d[0]
    np.testing.assert_allclose(z, pdx.rear_focal_z_mm, atol=5e-3)
    assert lens.anamorphic and not alone.anamorphic
    assert loads_lens(dump_lens(lens), path="a.toml") == lens


def test_05_rays_never_turn_nan():
    """Rays from every direction at strongly curved biconic, cylinder and toroid surfaces
    (grazing, missing, from behind): t finite, misses and unconverged rays flagged; a trace
    returns finite rays and statuses only."""
    rng = np.random.default_rng(5)
    n = 5000
    o = rng.uniform(-30, 30, (3, n))
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    for shape in (Biconic(9.0, -12.0, -2.0, 1.5, 17.0), Cylinder.make(8.5, "x", 0.0, 30.0),
                  Toroidal(9.0, -10.0, 0.5, 60.0)):
        t, valid = shape.intersect(1.0, o, d)
        assert np.isfinite(t).all() and valid.any() and not valid.all()
        lens = lens_of((shape, 4.0, GLASS), (StandardSurface(-30.0), 30.0, Material.air()))
        res = trace(lens, Rays(o + np.array([[0.0], [0.0], [60.0]]), -np.abs(d) * [[1], [1], [1]],
                               np.full(n, D)), from_sensor=False, sensor_z=None)
        assert np.isfinite(res.rays.o).all() and np.isfinite(res.rays.d).all()


def test_06_what_cannot_take_an_anamorphic_lens_says_so():
    """The .zmx writer refuses an anamorphic lens with a one-line error naming the kind (not a
    wrong file or model); the Cycles exact camera traces it (a Newton function per anamorphic
    surface), its learned camera refuses it. (The trainer learns it in the cartesian frame:
    tests/trainer/test_learned_lens.py.)"""
    from neurolens_addon.core.lensfile import dump_zmx
    from neurolens_addon.cycles import CameraSpec, CameraSpecError, generate_osl
    lens = lens_of((Cylinder.make(40.0, "x"), 4.0, GLASS), (StandardSurface(-60.0), 50.0,
                                                            Material.air()))
    with pytest.raises(LensError, match="cylinder"):
        dump_zmx(lens)
    assert "nl_ana_1(" in generate_osl(CameraSpec("exact", lens=lens))
    with pytest.raises(CameraSpecError, match="anamorphic"):
        generate_osl(CameraSpec("learned", lens=lens, model_dir="/nonexistent.neurolens"))
