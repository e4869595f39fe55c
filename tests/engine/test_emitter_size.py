"""Which emissive meshes the engine's flare layer traces from the light: those that are small
at the camera (engine.flare.traces_emitters), by the solid angle they subtend
(engine.emitters.Emitters.solid_angle_at), checked against a disc's exact solid angle."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from neurolens_addon.engine.emitters import Emitters
from neurolens_addon.engine.flare import SMALL_EMITTERS_SR, traces_emitters


def _disc(radius: float, distance: float, n: int = 64) -> Emitters:
    """A disc of triangles facing the origin from `distance` along +y."""
    t = np.linspace(0.0, 2.0 * np.pi, n + 1)
    rim = np.stack([radius * np.cos(t), np.full(n + 1, distance), radius * np.sin(t)], axis=1)
    centre = np.array([0.0, distance, 0.0])
    corners = np.stack([np.repeat(centre[None], n, 0), rim[:-1], rim[1:]], axis=1)
    return Emitters(corners, np.ones((n, 3)))


@pytest.mark.parametrize("radius, distance", [(0.3, 8.0), (0.05, 2.0), (1.0, 5.0)])
def test_a_discs_solid_angle_is_its_exact_one(radius, distance):
    """2 pi (1 - d / sqrt(d^2 + r^2)) within 1 % for a disc seen face on."""
    exact = 2.0 * math.pi * (1.0 - distance / math.hypot(distance, radius))
    assert _disc(radius, distance).solid_angle_at(np.zeros(3)) == pytest.approx(exact,
                                                                                  rel=0.01)


def test_small_emitters_are_traced_large_ones_left_to_the_camera_side():
    """With ghosts on, a disc subtending less than SMALL_EMITTERS_SR is light-traced, a larger
    one is not; without ghosts nothing is."""
    ghosts = SimpleNamespace(ghost_plan=object())
    small, large = _disc(0.3, 8.0), _disc(0.5, 3.0)
    assert small.solid_angle_at(np.zeros(3)) < SMALL_EMITTERS_SR
    assert traces_emitters(ghosts, small, np.zeros(3))
    assert not traces_emitters(ghosts, large, np.zeros(3))
    assert not traces_emitters(SimpleNamespace(ghost_plan=None), small, np.zeros(3))
