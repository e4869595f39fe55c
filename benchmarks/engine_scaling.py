"""How the engine's ray casts scale with the scene: Embree against scene.ray_cast from 10 K to
5 M triangles.

For each size a grid mesh of about that many triangles (wavy, so rays meet it at every angle)
fills the view of a camera 2 m away. Measured in one run: the export of the frame's triangles
and the Embree BVH build (EmbreeCaster's own timers), Embree's casts per second on 200 000
closest-hit rays from the camera into the grid, and the bare scene.ray_cast loop's on 20 000 of
the same rays.

    python -m benchmarks.run engine_scaling
"""

from __future__ import annotations

import math
import re
import time

import numpy as np

from .common import md_table

SIZES = (10_000, 100_000, 1_000_000, 5_000_000)
EMBREE_RAYS, BARE_RAYS = 200_000, 20_000


def _grid(triangles: int):
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    s = max(2, int(math.sqrt(triangles / 2.0)))
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=s, y_subdivisions=s, size=4.0,
                                    location=(0.0, 0.0, -2.0))
    ob = bpy.context.object
    mesh = ob.data
    co = np.empty(3 * len(mesh.vertices))
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    co[:, 2] = 0.05 * np.sin(7.0 * co[:, 0]) * np.cos(5.0 * co[:, 1])
    mesh.vertices.foreach_set("co", co.ravel())
    mesh.update()
    bpy.context.view_layer.update()
    return bpy.context.scene, bpy.context.evaluated_depsgraph_get(), 2 * (s - 1) ** 2


def _rays(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    d = np.stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.9, 0.9, n), -np.ones(n)], axis=1)
    return np.zeros((n, 3)), d / np.linalg.norm(d, axis=1, keepdims=True)


#: (renderer, resolution, samples) of the peak-memory figures: the engine at 4K at two sample
#: counts (flat in the samples), and the engine against Cycles on the same frames
PEAKS = (("neurolens", "3840x2160", 1), ("neurolens", "3840x2160", 2),
         ("cycles", "3840x2160", 1), ("neurolens", "1920x1080", 1), ("cycles", "1920x1080", 1))


def peak_memory() -> list[dict]:
    """Peak resident memory of renders of the demo scene (learned lens, denoised; the engine
    with Embree, Cycles with the project's OSL camera), each the whole command in its own
    process (PEAKS): the engine's film is its only frame-sized memory and bundles are
    bounded, so its peak must not grow with the samples (a 256-sample frame then needs what
    these do), and it is set against Cycles' on the same frame."""
    import sys
    import tempfile
    from pathlib import Path

    from .common import ROOT, peak_rss_of
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for engine, res, spp in PEAKS:
            t0 = time.perf_counter()
            rc, _text, peak = peak_rss_of(
                [sys.executable, "-m", "neurolens_addon.render",
                 ROOT / "presets" / "scenes" / "demo.blend", "--lens", "double_gauss_50mm_f2",
                 "--model", "learned", "--engine", engine, "--samples", spp, "--resolution",
                 res, "--quiet", "--out", Path(tmp) / "f.exr"])
            out.append({"engine": engine, "resolution": res, "samples": spp,
                        "peak_mib": round(peak / 2 ** 20),
                        "seconds": round(time.perf_counter() - t0, 1), "ok": rc == 0})
            print(f"  peak: {out[-1]}", flush=True)
    return out


#: (resolution, samples) of the frame-time figures
FRAMES = (("160x90", 16), ("320x180", 16), ("640x360", 16), ("320x180", 4), ("320x180", 64))
_SECONDS = re.compile(r"focus [0-9.]+ m, ([0-9.]+) s")


def frame_times() -> list[dict]:
    """The demo scene's frame time (the render the command prints: set-up, Embree, shading,
    denoising) against resolution and samples, learned lens, the scene's light paths."""
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from .common import ROOT
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for res, spp in FRAMES:
            p = subprocess.run([sys.executable, "-m", "neurolens_addon.render",
                                str(ROOT / "presets" / "scenes" / "demo.blend"), "--lens",
                                "double_gauss_50mm_f2", "--model", "learned", "--samples",
                                str(spp), "--resolution", res, "--quiet", "--out",
                                str(Path(tmp) / "f.exr")],
                               cwd=ROOT, capture_output=True, text=True, timeout=1800)
            m = _SECONDS.search(p.stdout + p.stderr)
            w, h = (int(v) for v in res.split("x"))
            sec = float(m.group(1)) if m else float("nan")
            out.append({"resolution": res, "samples": spp, "seconds": sec,
                        "samples_per_s": round(w * h * spp / sec) if m else None})
            print(f"  frame: {out[-1]}", flush=True)
    return out


def run() -> tuple[str, dict]:
    from neurolens_addon.engine.embree_cast import EmbreeCaster
    from neurolens_addon.engine.scene_cast import bare_ray_cast_rate
    rows, figs = [], []
    o, d = _rays(EMBREE_RAYS)
    for size in SIZES:
        try:
            scene, dg, tris = _grid(size)
            caster = EmbreeCaster(dg)
            best = math.inf
            for _ in range(3):
                t0 = time.perf_counter()
                hits = caster.closest(o, d)
                best = min(best, time.perf_counter() - t0)
            bare = bare_ray_cast_rate(scene, dg, o[:BARE_RAYS], d[:BARE_RAYS])
        except MemoryError:
            figs.append({"triangles": size, "error": "out of memory"})
            continue
        f = {"triangles": int(caster.triangles), "export_s": round(caster.export_seconds, 3),
             "build_s": round(caster.build_seconds, 3),
             "embree_casts_per_s": round(EMBREE_RAYS / best),
             "bare_casts_per_s": round(bare), "ratio": round(EMBREE_RAYS / best / bare, 1),
             "hit_fraction": round(hits.ray.size / EMBREE_RAYS, 3)}
        figs.append(f)
        print(f"  {f}", flush=True)
        rows.append([f"{f['triangles']:,}", f"{f['export_s']:.3f}", f"{f['build_s']:.3f}",
                     f"{f['embree_casts_per_s']:,}", f"{f['bare_casts_per_s']:,}",
                     f"{f['ratio']}x"])
    text = "\n".join([
        "## How ray casts scale with the scene (Embree against scene.ray_cast)",
        "",
        "A wavy grid of each size 2 m before the camera (`benchmarks/engine_scaling.py`): the "
        "frame's export and Embree's BVH build, then closest-hit casts per second of Embree "
        f"({EMBREE_RAYS:,} rays) and of the bare `scene.ray_cast` loop ({BARE_RAYS:,} of the "
        "same rays), one run.",
        "",
        md_table(["triangles", "export (s)", "BVH build (s)", "Embree casts/s",
                  "scene.ray_cast casts/s", "Embree / ray_cast"], rows)])
    frames = frame_times()
    text += "\n\n" + "\n".join([
        "Frame time of the demo scene (learned lens, its own light paths, Embree, denoised; "
        "the render time the command prints) against resolution and samples:", "",
        md_table(["resolution", "samples", "seconds", "samples/s"],
                 [[f["resolution"], str(f["samples"]), f"{f['seconds']:.1f}",
                   f"{f['samples_per_s']:,}"] for f in frames])])
    peaks = peak_memory()
    name = {"neurolens": "engine", "cycles": "Cycles"}
    text += "\n\n" + "\n".join([
        "Peak memory of the demo scene's frame (learned lens, denoised; the engine with Embree, "
        "Cycles on the CPU with the project's OSL camera; the whole command in its own "
        "process, its resident-set high-water mark):", "",
        md_table(["renderer", "resolution", "samples", "peak (MiB)", "seconds"],
                 [[name[p["engine"]], p["resolution"], str(p["samples"]),
                   f"**{p['peak_mib']:,}**", f"{p['seconds']}"] for p in peaks]),
        "",
        "The engine's frame-sized memory (its film, 16 floats a pixel, its full-frame "
        "readout, Blender's render result and the denoiser's copies) does not grow with the "
        "samples and bundles are bounded, so 256 samples need what 1 and 2 do."])
    return text, {"sizes": figs, "frames": frames, "peaks": peaks}
