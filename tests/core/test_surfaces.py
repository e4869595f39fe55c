"""Surface kinds: the registry, lens-file round trips, and geometry consistent with the sag."""

import dataclasses
import math

import numpy as np
import pytest

from neurolens_addon.core.errors import LensError
from neurolens_addon.core.lensfile import dump_lens, loads_lens, validate_lens
from neurolens_addon.core.paraxial import paraxial_data
from neurolens_addon.core.prescription import Lens, Material, Surface
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.surfaces import (DEFAULT_KIND, Biconic, Cylinder, EvenAsphere,
                                           StandardSurface, Toroidal, kind_class, kinds)
from neurolens_addon.core.trace import trace

INF = math.inf
SD = 8.0
GLASS = Material.from_abbe(1.6, 50.0)

#: representative shapes of every registered kind (a new kind must add its own here)
SAMPLES = {
    "standard": [StandardSurface(40.0), StandardSurface(-25.0), StandardSurface(INF),
                 StandardSurface(60.0, -1.0), StandardSurface(-80.0, 0.8),
                 StandardSurface(35.0, -2.5)],
    "even_asphere": [EvenAsphere(30.0, -0.7, ((4, 2e-5), (6, -3e-8), (8, 1e-10))),
                     EvenAsphere(-50.0, 0.0, ((2, 1e-3), (4, -1e-6))),
                     EvenAsphere(INF, 0.0, ((4, 1e-5),))],
    "biconic": [Biconic(60.0, 35.0), Biconic(-45.0, 90.0, -0.6, 0.4, 30.0),
                Biconic(INF, 40.0, 0.0, -1.0, 12.0)],
    "cylinder": [Cylinder.make(30.0, "x"), Cylinder.make(-50.0, "y", 0.0, 45.0),
                 Cylinder.make(40.0, "x", -0.8, 10.0)],
    "toroidal": [Toroidal(40.0, 70.0), Toroidal(-60.0, 35.0, -0.5, 20.0),
                 Toroidal(45.0, INF, 0.0, 90.0), Toroidal(50.0, -30.0)],
}
SHAPES = [s for kind in SAMPLES.values() for s in kind]
IDS = [f"{s.kind}-{i}" for i, s in enumerate(SHAPES)]


def lens_with(shape) -> Lens:
    """Stop, then `shape` with glass behind it, then a convex rear face (so that a flat
    `shape` still makes a lens with power: a window is refused)."""
    return Lens("kinds", "tests", 50.0, 4.0, (
        Surface(INF, 3.0, Material.air(), 6.0, stop=True),
        Surface(shape=shape, thickness_mm=6.0, material=GLASS, semi_diameter_mm=SD),
        Surface(-200.0, 40.0, Material.air(), SD)))


def test_01_every_registered_kind_has_samples():
    """The samples cover the registry exactly, and a file without `kind` reads as the default."""
    assert set(SAMPLES) == set(kinds())
    assert DEFAULT_KIND in kinds()
    for name in kinds():
        assert kind_class(name).kind == name
        assert all(type(s) is kind_class(name) for s in SAMPLES[name])


@pytest.mark.parametrize("shape", SHAPES, ids=IDS)
def test_02_round_trip_through_the_lens_file(shape):
    """dump -> load gives the same shape; naming the kind explicitly reads the same."""
    lens = lens_with(shape)
    validate_lens(lens)
    text = dump_lens(lens)
    again = loads_lens(text, path="kinds.toml")
    assert again == lens and type(again.surfaces[1].shape) is type(shape)
    assert again.content_hash() == lens.content_hash()
    if not shape.implied:               # the writer names kinds the columns cannot describe
        assert f'kind = "{shape.kind}"' in text
        return
    header = "[[surface]]"
    at = text.index(header, text.index(header) + 1) + len(header)
    named = text[:at] + f'\nkind = "{shape.kind}"' + text[at:]
    assert loads_lens(named, path="kinds.toml") == lens


def test_03_tables_read_as_the_simplest_kind_they_describe():
    """Without terms an even asphere is a standard surface (equal to one built in code)."""
    lens = lens_with(StandardSurface(40.0))
    text = dump_lens(lens)
    assert "\nkind =" not in text
    at = text.index("radius = 40.0")
    for kind in ("standard", "even_asphere"):
        named = text[:at] + f'kind = "{kind}"\n' + text[at:]
        assert type(loads_lens(named).surfaces[1].shape) is StandardSurface
    asph = text.replace("radius = 40.0", "radius = 40.0\naspheric = { a4 = 1e-6 }")
    assert loads_lens(asph).surfaces[1].shape == EvenAsphere(40.0, 0.0, ((4, 1e-6),))
    assert loads_lens(text.replace("radius = 40.0", "radius = 40.0\naspheric = { a4 = 0.0 }")
                      ).surfaces[1].shape == StandardSurface(40.0)


@pytest.mark.parametrize("value,needle", [('"zernike"', "unknown surface kind 'zernike'"),
                                          ('"standrad"', "did you mean 'standard'"),
                                          ("3", "expected a string naming a surface kind")])
def test_04_unknown_kind_is_a_lens_error_naming_file_surface_and_field(value, needle):
    text = dump_lens(lens_with(StandardSurface(40.0)))
    at = text.index("radius = 40.0")
    with pytest.raises(LensError) as info:
        loads_lens(text[:at] + f"kind = {value}\n" + text[at:], path="lenses/odd.toml")
    msg = str(info.value)
    assert info.value.field == "kind" and info.value.surface == 2
    assert msg.startswith("lenses/odd.toml, surface 2, field 'kind'") and needle in msg
    assert "standard" in msg and "even_asphere" in msg


def test_05_registry_lookup_and_keys_of_another_kind():
    """kind_class raises LensError(field 'kind'); a kind refuses the keys it does not have."""
    with pytest.raises(LensError) as info:
        kind_class("freeform", path="x.toml", surface=4)
    assert info.value.field == "kind" and info.value.surface == 4 and "x.toml" in str(info.value)
    text = dump_lens(lens_with(EvenAsphere(30.0, 0.0, ((4, 1e-6),))))
    at = text.index("radius = 30.0")
    with pytest.raises(LensError) as info:
        loads_lens(text[:at] + 'kind = "standard"\n' + text[at:], path="k.toml")
    assert info.value.field == "aspheric" and "of kind 'standard'" in str(info.value)


def _rays_at(shape, zv, n, rng, from_scene):
    """Rays from 10 mm in front of (or behind) the vertex, aimed at random points of the
    surface within 0.9 SD; the first tenth start 100 mm away near the axis and leave along it."""
    r = 0.9 * SD * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    xt, yt = r * np.cos(phi), r * np.sin(phi)
    target = np.stack([xt, yt, zv - shape.sag(xt, yt)])
    side = 1.0 if from_scene else -1.0
    o = np.stack([rng.uniform(-SD, SD, n), rng.uniform(-SD, SD, n), np.full(n, zv + 10 * side)])
    d = target - o
    d /= np.linalg.norm(d, axis=0)
    away = slice(0, n // 10)
    o[:, away] = [[0.3], [-0.2], [zv + 100 * side]]
    d[:, away] = [[0.0], [0.0], [side]]
    return o, d


@pytest.mark.parametrize("from_scene", [True, False], ids=["from-scene", "from-sensor"])
@pytest.mark.parametrize("shape", SHAPES, ids=IDS)
def test_06_intersection_lies_on_the_sag_and_normal_is_its_gradient(shape, from_scene):
    """Hits satisfy z = z_v - sag(x, y); the normal is parallel to grad(z_v - z - sag) by
    finite differences; t is 0 (never NaN) where invalid; rays aimed away miss."""
    rng = np.random.default_rng(11)
    zv = 3.0
    o, d = _rays_at(shape, zv, 4000, rng, from_scene)
    t, valid = shape.intersect(zv, o, d)
    assert t.dtype == np.float64 and np.isfinite(t).all() and np.all(t[~valid] == 0.0)
    assert not valid[:400].any() and valid[400:].mean() > 0.98
    p = o + t * d
    x, y, z = p[:, valid]
    assert np.allclose(zv - z, shape.sag(x, y), rtol=0, atol=1e-9)

    nx, ny, nz = shape.normal(zv, x, y, z.copy(), x * x + y * y)
    nx, ny, nz = (np.broadcast_to(c, x.shape) for c in (nx, ny, nz))
    if shape.normal_is_unit:
        assert np.allclose(nx * nx + ny * ny + nz * nz, 1.0, rtol=0, atol=1e-15)
    h = 1e-6
    gx = -(shape.sag(x + h, y) - shape.sag(x - h, y)) / (2 * h)
    gy = -(shape.sag(x, y + h) - shape.sag(x, y - h)) / (2 * h)
    n = np.stack([nx, ny, nz]) / np.sqrt(nx * nx + ny * ny + nz * nz)
    g = np.stack([gx, gy, -np.ones_like(gx)]) / np.sqrt(gx * gx + gy * gy + 1.0)
    assert np.allclose(np.abs((n * g).sum(axis=0)), 1.0, rtol=0, atol=1e-8)


@pytest.mark.parametrize("shape", SHAPES, ids=IDS)
def test_07_paraxial_curvature_is_the_sag_at_the_vertex(shape):
    """sag(0, y) ~ c_p y^2 / 2 near the axis; beyond a sphere's rim the sag is NaN (or clamped)."""
    y = 1e-3
    assert shape.sag(0.0, y) == pytest.approx(0.5 * shape.paraxial_curvature * y * y,
                                              rel=1e-5, abs=1e-15)
    c = shape.curvature
    if c != 0.0:
        rim = 1.0 / (abs(c) * math.sqrt(1.0 + shape.conic)) if shape.conic > -1 else None
        if rim is not None:
            assert np.isnan(shape.sag(0.0, rim * 1.01))
            assert np.isfinite(shape.sag(0.0, rim * 1.01, clamp=True))


def test_08_paraxial_trace_uses_the_r2_term():
    """An asphere's a2 term adds 2 a2 to the paraxial curvature: the lens has the same paraxial
    data as the sphere of curvature c + 2 a2, and the exact trace focuses near-axis rays there."""
    c, a2 = 1.0 / 60.0, 2e-3
    asph = lens_with(EvenAsphere(60.0, 0.0, ((2, a2),)))
    sphere = lens_with(StandardSurface(1.0 / (c + 2 * a2)))
    pa, ps = paraxial_data(asph), paraxial_data(sphere)
    assert pa.efl_mm == pytest.approx(ps.efl_mm, rel=1e-12)
    assert pa.rear_focal_z_mm == pytest.approx(ps.rear_focal_z_mm, rel=1e-12)
    h = 1e-3
    rays = Rays(np.array([[0.0], [h], [100.0]]), np.array([[0.0], [0.0], [-1.0]]),
                np.array([587.5618]))
    res = trace(asph, rays, from_sensor=False, sensor_z=None)
    (oy, oz), (dy, dz) = res.rays.o[1:, 0], res.rays.d[1:, 0]
    assert res.valid[0]
    assert oz - oy * dz / dy == pytest.approx(pa.rear_focal_z_mm, abs=1e-4)


def test_09_surfaces_built_either_way_are_equal_and_replaceable():
    """The patent-column constructor, shape= and dataclasses.replace agree."""
    a = Surface(30.0, 2.0, GLASS, 5.0, conic=-0.5, aspheric=((4, 1e-6),), stop=True)
    b = Surface(shape=EvenAsphere(30.0, -0.5, ((4, 1e-6),)), thickness_mm=2.0, material=GLASS,
                semi_diameter_mm=5.0, stop=True)
    assert a == b and hash(a) == hash(b) and repr(a) == repr(b)
    assert (a.radius_mm, a.conic, a.aspheric) == (30.0, -0.5, ((4, 1e-6),))
    c = dataclasses.replace(a, stop=False, thickness_mm=3.0)
    assert c.shape is a.shape and (c.stop, c.thickness_mm) == (False, 3.0)
    with pytest.raises(TypeError):
        Surface(30.0, 2.0, GLASS, 5.0, shape=StandardSurface(30.0))
