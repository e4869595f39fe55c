"""Tiles, progressive sample passes and bounded ray bundles: the engine's memory bound.

A frame of W x H pixels at S samples per pixel is W H S camera samples; a 4K frame at 256
samples is 2.1 G samples, far beyond memory. The renderer therefore never builds them at once:

  passes   the samples per pixel are split into progressive passes [s0, s1): 1, 1, 2, 4, 8, ...
           (doubling, so the whole image appears after one sample per pixel and sharpens),
           each pass no larger than what one tile may take in one bundle;
  tiles    the frame is cut into T x T tiles (the last row and column may be smaller), in
           Blender's pixel coordinates (x to the right, y up, (0, 0) the bottom-left pixel);
  bundles  one pass of one tile is one bundle of (tile pixels) x (s1 - s0) samples, or, when a
           tile at one sample per pixel would already exceed the bound, several bundles of
           consecutive tile pixels.

Every bundle holds at most `max_rays` camera samples: with P pixels and k = s1 - s0 samples,
k <= max(1, max_rays // P) by construction of the passes, and a tile is split into pixel runs
of max(1, max_rays // k) pixels. Secondary rays (shadow, bounce) are made per bundle, so they
are bounded by a constant times max_rays too.

Order. Progressive (pass by pass, every tile in each pass) shows the whole frame after one
sample, but every tile's sums live until the last pass: the film is frame-sized. Tile by tile
(`tile_major`: every pass of a tile before the next tile) finishes a tile before starting the
next, so the film need only hold the tile in progress (film.Film streamed). Both orders make the
same bundles (the passes are the same, cut by the largest tile), and a pixel meets its passes in
the same order, so the image is the same, bit for bit; with one pass the orders coincide.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

#: default upper bound on camera samples in one bundle (the issue asks for <= 256 K)
DEFAULT_MAX_RAYS = 65536
HARD_MAX_RAYS = 262144


@dataclass(frozen=True)
class Tile:
    x: int          # left pixel column
    y: int          # bottom pixel row
    w: int
    h: int

    @property
    def pixels(self) -> int:
        return self.w * self.h


@dataclass(frozen=True)
class Bundle:
    """Camera samples [s0, s1) of the tile's pixels [p0, p1) (row-major within the tile)."""

    tile_index: int
    tile: Tile
    s0: int
    s1: int
    p0: int
    p1: int
    last_of_tile: bool   # the tile's pass is complete after this bundle
    last_pass: bool = False   # ... and it was the tile's last pass: the tile is finished

    @property
    def rays(self) -> int:
        return (self.p1 - self.p0) * (self.s1 - self.s0)


def tiles(width: int, height: int, size: int) -> list[Tile]:
    """Row-major tiles from the bottom-left; the last row / column may be narrower."""
    if width < 1 or height < 1 or size < 1:
        raise ValueError(f"need a positive frame and tile size, got {width}x{height}, tile {size}")
    return [Tile(x, y, min(size, width - x), min(size, height - y))
            for y in range(0, height, size) for x in range(0, width, size)]


def sample_passes(samples: int, cap: int) -> list[tuple[int, int]]:
    """Progressive passes [s0, s1) covering 0..samples: 1, 1, 2, 4, ... samples, at most cap."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    cap = max(1, int(cap))
    out, s0, k = [], 0, 1
    while s0 < samples:
        s1 = min(samples, s0 + min(k, cap))
        out.append((s0, s1))
        if s0 > 0:
            k *= 2
        s0 = s1
    return out


def passes_of(width: int, height: int, samples: int, tile_size: int,
              max_rays: int = DEFAULT_MAX_RAYS) -> list[tuple[int, int]]:
    """The progressive passes of a frame: no pass takes more than `max_rays` samples of its
    largest tile in one bundle."""
    largest = max(t.pixels for t in tiles(width, height, tile_size))
    return sample_passes(samples, max(1, max_rays // largest))


def bundles(width: int, height: int, samples: int, tile_size: int,
            max_rays: int = DEFAULT_MAX_RAYS, tile_major: bool = False) -> Iterator[Bundle]:
    """Every bundle of a frame, pass by pass, tile by tile (a generator: O(1) memory), or with
    `tile_major` tile by tile, pass by pass (the module docstring's order)."""
    if max_rays < 1:
        raise ValueError(f"max_rays must be >= 1, got {max_rays}")
    ts = tiles(width, height, tile_size)
    passes = passes_of(width, height, samples, tile_size, max_rays)

    def of(i, t, s0, s1):
        run = max(1, max_rays // (s1 - s0))
        for p0 in range(0, t.pixels, run):
            p1 = min(t.pixels, p0 + run)
            yield Bundle(i, t, s0, s1, p0, p1, p1 == t.pixels,
                         p1 == t.pixels and s1 == samples)

    if tile_major:
        for i, t in enumerate(ts):
            for s0, s1 in passes:
                yield from of(i, t, s0, s1)
    else:
        for s0, s1 in passes:
            for i, t in enumerate(ts):
                yield from of(i, t, s0, s1)


def total_samples(width: int, height: int, samples: int) -> int:
    return width * height * samples
