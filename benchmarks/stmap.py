"""ST-maps of every preset (issue 32 figures): their accuracy against the chief ray and their
cost.

Per preset, focused at infinity, on a full-frame sensor (36 mm) at 1920 x 1280 pixels (an
anamorphic lens's maps in the desqueezed frame, from its chief-ray grid: core.chief_grid):
  accuracy    the largest distance, in pixels, between the pinhole point the distort map
              samples and where the chief ray points, over 300 random pixels, the chief ray
              solved independently in two dimensions at each pixel's azimuth
              (testdata.chief_rays.chief_direction; the map's table is one-dimensional; an
              anamorphic lens's at the pixel's own film point: grid_distort_error_px)
  round trip  the largest distance, in pinhole pixels, of each pixel of the undistorted image
              (960 x 640 and its overscan) from itself after the undistort map and the distort
              map sampled bilinearly (as Nuke's STMap node reads them)
  overscan    the undistorted image's size over the sensor that the distort map needs to find
              every border pixel (inf: the frame's corners lie beyond the image circle)
  4K time     the chief-ray table (or grid) and both maps at 4096 x 2160 (best of 2), and
              writing one of them as EXR (OpenEXR, ZIP)
Targets: within 0.1 px of the chief ray at 1920 px; the round trip within 0.05 px; a 4K map in
under 2 s.

    python -m benchmarks.run stmap
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

from .common import md_table, preset_paths

FRAME_1920 = (1920, 1280, 36.0)
TRIP = (960, 640, 36.0)
K4 = (4096, 2160, 36.0)


def _one(path: Path, tmp: Path) -> dict:
    from neurolens_addon.core.exr import write_exr
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.stmap import MapFrame, lens_at_setting, needed_overscan, st_map
    from testdata.chief_rays import distort_error_px, grid_distort_error_px, round_trip_px
    lens = load_lens(path)
    frame = MapFrame(*FRAME_1920)
    _l, _z, table = lens_at_setting(lens, film_radius_mm=frame.film_radius_mm, frame=frame)
    dis = st_map(table, frame, "distort")
    err, checked = (grid_distort_error_px(lens, table, frame, dis) if lens.anamorphic
                    else distort_error_px(table, frame, dis))
    need = needed_overscan(table, frame)
    trip = MapFrame(*TRIP, overscan=min(need, 1.5) if math.isfinite(need) else 1.0)
    _l, _z, t_trip = lens_at_setting(lens, film_radius_mm=trip.film_radius_mm, frame=trip)
    rt, share = round_trip_px(trip, st_map(t_trip, trip, "undistort"),
                              st_map(t_trip, trip, "distort"))
    k4 = MapFrame(*K4)
    best = math.inf
    for _ in range(2):
        t0 = time.perf_counter()
        _l, _z, t4 = lens_at_setting(lens, film_radius_mm=k4.film_radius_mm, frame=k4)
        t1 = time.perf_counter()
        dis = st_map(t4, k4, "distort")
        t2 = time.perf_counter()
        st_map(t4, k4, "undistort")
        t3 = time.perf_counter()
        best = min(best, t3 - t0)
        table_s, distort_s, undistort_s = t1 - t0, t2 - t1, t3 - t2
    t0 = time.perf_counter()
    write_exr(tmp / "map.exr", {"R": dis[..., 0], "G": dis[..., 1], "A": dis[..., 2]})
    exr_s = time.perf_counter() - t0
    f_p = table.f_y_mm if lens.anamorphic else table.f_p_mm
    return {"anamorphic": bool(lens.anamorphic), "f_p_mm": f_p, "error_px": err,
            "checked": checked,
            "round_trip_px": rt, "round_trip_share": share, "overscan_needed": need,
            "table_s": table_s, "distort_s": distort_s, "undistort_s": undistort_s,
            "both_4k_s": best, "exr_s": exr_s}


def run() -> tuple[str, dict]:
    figs = {}
    with tempfile.TemporaryDirectory() as tmp:
        for path in preset_paths():
            figs[path.stem] = f = _one(path, Path(tmp))
            print(f"[stmap] {path.stem}: {f}", flush=True)
    rows = []
    for stem, f in figs.items():
        over = "inf" if not math.isfinite(f["overscan_needed"]) else f"{f['overscan_needed']:.3f}"
        rows.append([stem + (" (anamorphic: f_p vertical)" if f["anamorphic"] else ""),
                     f"{f['f_p_mm']:.3f}", f"{f['error_px']:.2g}",
                     f"{f['round_trip_px']:.2g}", over,
                     f"{f['table_s']:.2f} + {f['distort_s']:.2f} + {f['undistort_s']:.2f}",
                     f"{f['exr_s']:.2f}"])
    good = list(figs.values())
    worst_err = max(f["error_px"] for f in good)
    worst_trip = max(f["round_trip_px"] for f in good)
    worst_map = max(f["table_s"] + max(f["distort_s"], f["undistort_s"]) for f in good)
    text = "\n".join([
        "## ST-maps: accuracy and cost per preset", "",
        "`benchmarks/stmap.py`: each preset focused at infinity on a 36 mm sensor (the "
        "anamorphic presets' maps in the desqueezed frame, from their chief-ray grid: "
        "core.chief_grid). Error: the distort map at 1920 x 1280 against the chief ray solved "
        "independently in two dimensions (300 random pixels, in pixels); round trip: each "
        "undistorted pixel (960 x 640 with the overscan needed, at most 1.5) through the "
        "undistort map and back through the distort map sampled bilinearly (in pixels); "
        "overscan: what the undistorted CG needs so the distorted frame has no empty edge "
        "(inf: the frame's corners lie beyond the image circle); 4K: the chief-ray table, the "
        "distort map and the undistort map at 4096 x 2160, seconds (best of 2), and writing one "
        "as EXR.",
        "",
        f"Worst of {len(good)} presets: error {worst_err:.2g} px (target 0.1), round trip "
        f"{worst_trip:.2g} px (target 0.05), a 4K map (table and one map) "
        f"{worst_map:.2f} s (target 2 s).", "",
        md_table(["preset", "f_p (mm)", "error (px)", "round trip (px)", "overscan",
                  "4K: table + distort + undistort (s)", "EXR (s)"], rows)])
    return text, figs
