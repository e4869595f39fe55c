"""engine.data_passes and the film's data sums without Blender: a surface point moved by its
triangle's vertices, what counts as still (an instance's hit, a changed vertex count), no hits,
ghost-free means, and means over samples of three rays (a third a ray)."""

from __future__ import annotations

import numpy as np
import pytest

from neurolens_addon.engine.data_passes import DataLayout, FirstHitData, MotionStep
from neurolens_addon.engine.film import Film
from neurolens_addon.engine.plan import Tile
from neurolens_addon.engine.scene_cast import Hits

#: one triangle 5 m before a camera at the origin looking down -Z (scene units: metres)
CORNERS = np.array([[0.0, 0.0, -5.0], [1.0, 0.0, -5.0], [0.0, 1.0, -5.0]])


class _Table:
    """An object table of one triangle (mesh_tables.ObjectTable's interface)."""

    poly_material = np.zeros(1, np.int64)

    def triangles(self):
        return (np.zeros(1, np.int64), np.ones(1, np.int64), CORNERS,
                np.array([[0, 1, 2]]), np.array([[0, 1, 2]]))

    def locate(self, poly, p):
        a, b, c = CORNERS
        v = (p[:, 0] - a[0]) / (b[0] - a[0])
        w = (p[:, 1] - a[1]) / (c[1] - a[1])
        return np.zeros(p.shape[0], np.int64), np.stack([1.0 - v - w, v, w], axis=1)

    def uv(self, name):
        return np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])


class _Named:
    name_full = "Triangle"


class _Pinhole:
    """Pixels of lens-space points (mm) through a pinhole of 100 px per unit slope."""

    def pixels(self, lens_points):
        x, y, z = lens_points.T
        return np.stack([50.0 + 100.0 * x / z, 50.0 + 100.0 * y / z], axis=1), z > 0


def _data(prev_shift, next_shift, vertices=None):
    steps = [MotionStep(np.eye(4), {"Triangle": CORNERS + shift if vertices is None
                                    else vertices})
             for shift in (prev_shift, next_shift)]
    return FirstHitData(DataLayout(("Vector", "Position", "UV")), placement=_Pinhole(),
                        camera_matrix=np.eye(4), steps=steps)


def _hits(points):
    points = np.asarray(points, dtype=np.float64)
    k = points.shape[0]
    return Hits(np.arange(k), points, np.tile([0.0, 0.0, 1.0], (k, 1)), np.zeros(k, np.int64),
                np.zeros(k, np.int32))


def test_01_a_surface_point_moves_with_its_triangle():
    """The triangle 0.1 m left a frame before and 0.2 m right a frame after: the hit at
    (0.25, 0.25) moves 2 px and 4 px on the pinhole (100 px a unit slope, 5 m away), in
    Cycles' signs; Position and UV are the hit's own; both sample columns count it."""
    data = _data(np.array([-0.1, 0.0, 0.0]), np.array([0.2, 0.0, 0.0]))
    lay = data.layout
    v = data.values(_hits([[0.25, 0.25, -5.0]]), [_Named()], lambda oid: _Table())
    assert v[0, lay.columns("Vector")] == pytest.approx([-2.0, 0.0, -4.0, 0.0, 1.0])
    assert v[0, lay.columns("Position")] == pytest.approx([0.25, 0.25, -5.0])
    assert v[0, lay.columns("UV")] == pytest.approx([0.25, 0.25])
    assert v[0, -2:].tolist() == [1.0, 1.0]


@pytest.mark.parametrize("case", ["instance", "vertex count", "no motion data"])
def test_02_what_cannot_be_followed_counts_as_still(case):
    """An instance's hit (off the object's own triangle), an object whose vertex count
    changed between frames, and one the other frames do not hold: vector 0, still placed."""
    shift = np.array([0.3, 0.0, 0.0])
    point = [[0.25, 0.25, -5.0]]
    if case == "instance":
        data, point = _data(-shift, shift), [[0.25, 0.25, -3.0]]
    elif case == "vertex count":
        data = _data(-shift, shift, vertices=np.zeros((4, 3)))
    else:
        data = _data(-shift, shift)
        data.steps[0].vertices.clear()
        data.steps[1].vertices.clear()
    v = data.values(_hits(point), [_Named()], lambda oid: _Table())
    assert v[0, data.layout.columns("Vector")].tolist() == [0.0, 0.0, 0.0, 0.0, 1.0]


def test_03_no_hits_no_rows():
    data = _data(np.zeros(3), np.zeros(3))
    v = data.values(_hits(np.zeros((0, 3))), [_Named()], lambda oid: _Table())
    assert v.shape == (0, data.layout.width)


def test_04_means_over_three_ray_samples_are_the_hits_own():
    """A pixel of one sample of three rays (a third each), one of which hits at depth 4 and
    position (1, 2, -4): Depth, Normal and Position are that hit's (not a third of it), UV's A
    its coverage (a third), alpha on a transparent film the hits over the valid rays."""
    lay = DataLayout(("Position", "UV"))
    film = Film(1, 1, transparent=True, data=lay)
    tile = Tile(0, 0, 1, 1)
    data = np.zeros((3, lay.width))
    data[:, -2] = 1.0                                   # three image rays
    data[0, lay.columns("Position")] = [1.0, 2.0, -4.0]
    data[0, lay.columns("UV")] = [0.5, 0.25]
    data[0, -1] = 1.0                                   # one hit
    film.add(tile, np.zeros(3, np.int64), rgb=np.zeros((3, 3)), valid=np.ones(3, bool),
             hit=np.array([True, False, False]), depth=np.array([4.0, 0.0, 0.0]),
             normal=np.tile([0.0, 0.0, 1.0], (3, 1)), illumination=np.ones(3),
             share=1.0 / 3.0, data=data)
    out = film.readout(tile)
    assert out["Depth"][0, 0] == pytest.approx(4.0, rel=1e-6)
    assert out["Normal"][0] == pytest.approx([0.0, 0.0, 1.0], rel=1e-6)
    assert out["Position"][0] == pytest.approx([1.0, 2.0, -4.0], rel=1e-6)
    assert out["UV"][0] == pytest.approx([0.5, 0.25, 1.0 / 3.0], rel=1e-6)
    assert out["Combined"][0, 3] == pytest.approx(1.0 / 3.0, rel=1e-6)


def test_05_an_instanced_copy_moves_with_its_matrix():
    """A hit on an instanced copy (hits.instance names it; the caster's list gives its matrix
    now) moves by M' M^-1: the copy, 0.1 m right of the original now, 0.1 m further left a frame
    before and 0.2 m further right after: -2 px and -4 px (100 px a unit slope, 5 m), whatever
    the original object does; a copy the other frames do not hold stays still."""
    data = _data(np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))   # the original moves
    key = ("Triangle", "Empty", (0,))
    now = np.eye(4)
    now[0, 3] = 0.1
    for s, dx in enumerate((-0.1, 0.2)):
        m = now.copy()
        m[0, 3] += dx
        data.steps[s].instances[key] = m
    hits = _hits([[0.35, 0.25, -5.0], [0.35, 0.25, -5.0]])
    hits.instance = np.array([0, 1])
    instances = [(key, now), (("Triangle", "Empty", (1,)), now)]
    v = data.values(hits, [_Named()], lambda oid: _Table(), instances)
    vec = v[:, data.layout.columns("Vector")]
    assert vec[0] == pytest.approx([-2.0, 0.0, -4.0, 0.0, 1.0])
    assert vec[1].tolist() == [0.0, 0.0, 0.0, 0.0, 1.0]
