"""An ST-map on a real frame: the engine renders straight bars through a fisheye (strong
barrel distortion: bowed on the film), and the undistort map, sampled as a compositor
samples it, makes them straight again; the frame and the map agree on which way is up and
which is left."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testdata import engine_scenes as scenes

pytestmark = pytest.mark.slow          # an engine render

bpy = scenes.bpy
ROOT = Path(__file__).resolve().parents[2]
LENS, FOCUS_M, W, H = "fisheye_f4", 3.0, 288, 192


def _bars():
    """Two thin glowing bars 3 m ahead that do not cross: one level above the centre, one
    upright left of it."""
    from presets.scenes.make_demo_scene import principled
    glow = principled("glow", (0.0, 0.0, 0.0), emission=(1.0, 1.0, 1.0), strength=5.0)
    for location, scale in (((1.0, 1.5, -FOCUS_M), (4.0, 0.02, 0.02)),
                            ((-2.0, -0.6, -FOCUS_M), (0.02, 3.0, 0.02))):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=location, scale=scale)
        bpy.context.object.data.materials.append(glow)


def _bilinear(img, u, v):
    """img (rows from the bottom) at pixel coordinates (u, v) (centres at integers)."""
    h, w = img.shape
    i0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    j0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = u - i0, v - j0
    return ((1 - a) * (1 - b) * img[j0, i0] + a * (1 - b) * img[j0, i0 + 1]
            + (1 - a) * b * img[j0 + 1, i0] + a * b * img[j0 + 1, i0 + 1])


def _bow(img, axis: int, near: slice, span: slice) -> float:
    """Peak-to-peak distance (px) of a bar's centre line from its best straight line: the
    intensity-weighted centroid across the bar (rows `near` for a horizontal bar, columns for
    a vertical one) at each position along `span`."""
    band = img[near, span] if axis == 0 else img[span, near].T
    pos = np.arange(near.start, near.start + band.shape[0])[:, None]
    weight = band.sum(axis=0)
    t = np.flatnonzero(weight > 0.3 * weight.max())        # where the bar is
    t = t[(t > t.min() + 0.1 * np.ptp(t)) & (t < t.max() - 0.1 * np.ptp(t))]   # not its ends
    assert t.size > 40
    centre = (band * pos).sum(axis=0)[t] / weight[t]
    fit = np.polyval(np.polyfit(t, centre, 1), t)
    return float(np.ptp(centre - fit))


def test_bars_bowed_on_the_film_are_straight_through_the_undistort_map(tmp_path):
    """Bars bowed by more than 1.5 px on the film are straight within 0.5 px (a quarter of
    their bow at most) after the undistort map, sampled bilinearly: the map and the
    engine's frame agree on the mapping and on its orientation (a flipped axis would bow
    them more)."""
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.stmap import MapFrame, lens_at_setting, st_map
    from testdata.agreement_scenes import SENSOR_WIDTH_MM, _camera
    scenes.reset()
    _bars()
    _camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), FOCUS_M, 8.0, lens=LENS)
    ch = scenes.render(tmp_path / "bars.exr", W, H, 64)
    img = (ch["Combined.R"] + ch["Combined.G"] + ch["Combined.B"])[::-1].astype(np.float64)
    frame = MapFrame(W, H, SENSOR_WIDTH_MM)
    lens = load_lens(ROOT / "presets" / "lenses" / f"{LENS}.toml")
    _l, _z, table = lens_at_setting(lens, focus_mm=1000.0 * FOCUS_M,
                                    film_radius_mm=frame.film_radius_mm)
    und = st_map(table, frame, "undistort")
    flat = _bilinear(img, und[..., 0] * W - 0.5, und[..., 1] * H - 0.5) * (und[..., 2] == 1)
    # the level bar: the rows about it where it crosses the centre column, along every
    # column; the upright bar: the columns about it where it crosses the centre row
    top = int(np.argmax(img[H // 2:, W // 2])) + H // 2
    top_flat = int(np.argmax(flat[H // 2:, W // 2])) + H // 2
    left = int(np.argmax(img[H // 2, :W // 2]))
    left_flat = int(np.argmax(flat[H // 2, :W // 2]))
    cols, rows = slice(0, W), slice(0, H)
    bowed = (_bow(img, 0, slice(top - 8, top + 9), cols),
             _bow(img, 1, slice(left - 8, left + 9), rows))
    straight = (_bow(flat, 0, slice(top_flat - 8, top_flat + 9), cols),
                _bow(flat, 1, slice(left_flat - 8, left_flat + 9), rows))
    # measured 2026-11-28: bowed 2.6 and 1.9 px, straightened to 0.41 and 0.37 px (what is
    # left: render noise, the bars' depth seen from the side, and the entrance pupil moving
    # with the field angle, so that bars 3 m away are not seen from one point)
    assert min(bowed) > 1.5, bowed
    assert max(straight) < 0.5 and max(s / b for s, b in zip(straight, bowed)) < 0.25, (
        straight, bowed)
