"""trainer.occupancy.table_occupancy: the domain of a lens known only from a ray table, checked
against the set its synthetic rays were drawn from (a disc of directions per film radius whose
centre moves with the radius, as a lens's bundles do)."""

from __future__ import annotations

import numpy as np
import pytest

from trainer.occupancy import TABLE_SHAPE, table_occupancy

FILM, PUPIL_DISTANCE, HALF_ANGLE = 20.0, 90.0, 0.1


def _table(n: int, seed: int = 3):
    """(r, u_r, u_t) of n rays: film points uniform over the disc (few near the axis), their
    directions uniform over the disc of radius HALF_ANGLE about (-r / PUPIL_DISTANCE, 0)."""
    rng = np.random.default_rng(seed)
    r = FILM * np.sqrt(rng.random(n))
    a, t = HALF_ANGLE * np.sqrt(rng.random(n)), 2.0 * np.pi * rng.random(n)
    return np.stack([r, -r / PUPIL_DISTANCE + a * np.cos(t), a * np.sin(t)], axis=1)


def _box(base, pad=0.1):
    lo, hi = base.min(axis=0), base.max(axis=0)
    span = hi - lo
    lo, hi = lo - pad * span, hi + pad * span
    lo[0], hi[0] = 0.0, base[:, 0].max()
    return lo, hi


@pytest.mark.parametrize("n", [60_000, 200_000])
def test_each_film_slice_holds_the_disc_of_directions_it_was_drawn_from(n):
    """Every slice's domain (cells whose middle is inside) covers the disc of directions at the
    slice's middle radius to within 3 % of its area, the axis slice too (under 60 rays of its
    own at n = 60,000), and holds no cell further than one cell's diagonal outside it."""
    base = _table(n)
    lo, hi = _box(base)
    grid = table_occupancy(base, lo, hi)
    assert grid.shape == TABLE_SHAPE
    step = (hi - lo) / np.array(TABLE_SHAPE)
    iu, iv = np.meshgrid(lo[1] + (np.arange(TABLE_SHAPE[1]) + 0.5) * step[1],
                         lo[2] + (np.arange(TABLE_SHAPE[2]) + 0.5) * step[2], indexing="ij")
    disc = np.pi * HALF_ANGLE ** 2
    for k in range(TABLE_SHAPE[0]):
        r = lo[0] + (k + 0.5) * step[0]
        area = grid[k].sum() * step[1] * step[2]
        assert abs(area / disc - 1.0) < 0.03, (k, area / disc)
        distance = np.hypot(iu - (-r / PUPIL_DISTANCE), iv)
        assert distance[grid[k]].max() < HALF_ANGLE + np.hypot(step[1], step[2]), k


def test_a_slice_without_rays_stays_empty_and_the_film_beyond_the_table_is_dark():
    """A table that reaches only half the film radius it is gridded over leaves the slices
    beyond it empty: the domain never invents light where the table has none."""
    base = _table(40_000)
    lo, hi = _box(base)
    hi[0] = 2.0 * FILM
    grid = table_occupancy(base, lo, hi)
    assert grid[:TABLE_SHAPE[0] // 2 - 1].any(axis=(1, 2)).all()
    assert not grid[TABLE_SHAPE[0] // 2 + 1:].any()
