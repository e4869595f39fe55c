"""Every compiled kernel made ready before a frame's first bundle, and what that cost.

numba compiles a kernel at its first call, or loads it from the user's cache (core.jit) when an
earlier process compiled it. `warm_up()` calls each kernel once on a few rows of the types a
render passes (the shading's, the lights', the exact lens trace's through a real preset), so the
cost falls before the frame starts and is stated (the render's summary line): the first render
after an install or an update compiles (tens of seconds, once), later processes load the cache
(a fraction of a second), and later frames of the same process pay nothing. A checkout (a
farm image, the benchmarks) can pay it ahead; numba keeps a cache per copy of the source files,
so an installed extension warms its own on its first render:

    python -m neurolens_addon.engine.kernel_warmup
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import jit


@dataclass(frozen=True)
class WarmUp:
    seconds: float       # wall time of this warm-up (0 where an earlier one in the process did)
    compiled: int        # kernel compilations now (numba's cache misses)
    loaded: int          # kernels loaded from the cache (its hits)
    already: bool        # an earlier warm-up in this process made them ready

    def describe(self) -> str:
        if self.already:
            return "kernels ready"
        if self.compiled:
            return (f"kernels compiled in {self.seconds:.1f} s (the first render after an "
                    f"install or update; cached for later ones)")
        return f"kernels loaded from the cache in {self.seconds:.1f} s"


_LOCK = threading.Lock()
_DONE: list = []


def _dispatchers():
    from ..core import coatings_kernels, trace_compiled
    from . import (camera_kernels, film_kernels, light_kernels, mesh_kernels, shading_kernels,
                   stage_kernels)
    out = []
    for module in (trace_compiled, coatings_kernels, shading_kernels, light_kernels,
                   mesh_kernels, film_kernels, stage_kernels, camera_kernels):
        for value in vars(module).values():
            if hasattr(value, "stats") and hasattr(value, "py_func"):
                out.append(value)
    return out


def _exercise():
    """One call of every kernel a render calls, on the argument types it passes (the
    per-stage kernels only the tests call, e.g. evaluate_parts, compile there)."""
    from ..core.lensfile import load_lens
    from ..core.rays import Rays
    from ..core.trace import trace
    from . import microfacet, shading_kernels, stage_kernels
    from .lights import Light
    from .materials import SurfacePoint
    from .scene_cast import Hits
    from .shading import Paths
    k = 4
    rng = np.random.default_rng(0)
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    wo = np.tile([0.0, 0.6, 0.8], (k, 1))
    u, rows3 = rng.random(k), rng.random((k, 3))
    f0, flag = np.full(k, 0.04), np.ones(k, dtype=bool)
    tabs = microfacet.tables()
    sp = SurfacePoint(rows3, u, u, rows3, n, u, u + 1.0, f0, u, u, u)
    kinds = np.zeros((k, 4), np.int64)
    shading_kernels.run_hash_u01(0, np.arange(k), np.arange(k), 0)
    paths = Paths(np.arange(k), rows3, -wo, rows3.copy(), u, u, np.zeros(k, np.int64), kinds)
    hits = Hits(np.arange(k), rows3, n, np.zeros(k, np.int64), np.zeros(k, np.int32))
    light = Light("POINT", np.ones(3), np.zeros(3), np.eye(3)[0], np.eye(3)[1],
                  -np.eye(3)[2], radius=0.1)
    stage_kernels.run_misses(paths, hits, stage_kernels.light_table([light])[0], np.ones(3),
                             True, False, 0.0, 0.0, np.zeros((k, 3)))
    stage_kernels.run_surface(paths, hits, sp, u, np.arange(k), np.arange(k), 0, 16, 8, 1.0,
                              0.0, 0.0, np.zeros((k, 3)))
    terms = shading_kernels.run_layer_terms(u, n, wo, f0, u, tabs)
    stage_kernels.run_take_paths(flag, *paths.fields())
    for world in ((wo, rows3, u), np.ones(3)):       # a textured world, a flat one
        stage_kernels.run_light_samples(0, [10, 8, 6], np.arange(k), np.arange(k),
                                        stage_kernels.light_table([]), None, world, rows3, sp,
                                        n, n, wo, u, flag, flag, terms, rows3, u)
    shading_kernels.run_accumulate(np.zeros((k, 3)), np.arange(k), rows3, flag, 0.0, 1.0)
    shading_kernels.run_accumulate_rows(np.zeros((k, 3)), np.arange(k), np.arange(k), flag,
                                        rows3, flag, 0.0, 1.0)
    shading_kernels.run_bounce(rows3, u, np.zeros(k, np.int64), kinds, sp, n, n, wo, rows3, u,
                               flag, flag, [u, u, u, u], u, np.full(4, 8), 3, tabs, terms)
    from . import mesh_kernels
    from .film import Film
    from .plan import Tile
    film = Film(2, 2)
    for unc, albedo in ((None, None), (u, rows3)):      # both variants a render passes
        film.add(Tile(0, 0, 2, 2), np.arange(k) % 4, rgb=rows3, valid=flag, hit=flag, depth=u,
                 normal=rows3, illumination=u, uncertainty=unc, albedo=albedo)
    i32 = np.zeros(k, np.int32)                          # Embree's answers' types
    mesh_kernels.run_gather_hits(i32, i32, np.ones(k, np.float32), rows3, n, n, i32, i32)
    mesh_kernels.run_face_normals(rows3, np.arange(3, dtype=np.int32)[None])
    i64 = np.zeros(k, np.int64)
    mesh_kernels.run_surface_rows(i64, i64, n, i64[:1], i64[:1] + 1, i64[:1], flag[:1],
                                  i64[:1] - 1, (u,) * 8, (rows3,) * 2)
    mesh_kernels.run_locate(np.zeros(k, np.int64), rows3, np.zeros(1, np.int64),
                            np.ones(1, np.int64), np.eye(3), np.arange(3)[None])
    mesh_kernels.run_locate_smooth(np.zeros(k, np.int64), rows3, np.zeros(1, np.int64),
                                   np.ones(1, np.int64), np.eye(3), np.arange(3)[None],
                                   np.arange(3)[None], np.eye(3), np.ones(1, bool), rows3)
    lens = load_lens(Path(__file__).resolve().parents[2] / "presets" / "lenses"
                     / "double_gauss_50mm_f2.toml")
    # camera rays: from the sensor plane (z = 0) through the lens, to the world
    from types import SimpleNamespace

    from ..core.pupil import RearDiscSampler
    from ..core.sensor_response import sensor_response
    from . import camera_kernels
    film = SimpleNamespace(width_px=2, height_px=2, width_mm=36.0, height_mm=24.0,
                           shift_x_mm=0.0, shift_y_mm=0.0)
    tables = camera_kernels.CameraTables(0, film, 1.0, sensor_response(),
                                         camera_kernels.PER_CHANNEL, RearDiscSampler(lens),
                                         (0.5, 0.5), 0.5, 550.0, range(6))
    o, d, lam, w, spectral = tables.sensor_rays(np.arange(k), np.arange(k))
    res = trace(lens, Rays(o, d, lam), kernels="compiled")
    camera_kernels.run_to_world(res.rays.o, res.rays.d, res.valid, w, 1.0, spectral, 0.0,
                                1000.0, np.eye(4))
    from ..core.coatings_kernels import stack_reflectance     # ghosts' and flare's coatings
    stack_reflectance(1.0, 1.5, u, np.full(k, 550.0), ((1.38, 100.0),))
    # a ghost path from the scene with a coating's weights (the lamps' flare, engine.flare)
    from ..core.coatings import Coating
    from ..core.ghosts import all_ghosts
    from . import light_kernels
    front = np.tile([[0.0], [0.0], [lens.front_vertex_z + 50.0]], (1, k))
    back = np.tile([[0.0], [0.0], [-1.0]], (1, k))
    trace(lens, Rays(front, back, np.full(k, 550.0)), from_sensor=False,
          ghost=all_ghosts(lens)[0], coating=Coating("single"), kernels="compiled")
    light_kernels.run_sample(light.row, rows3, u, u)


def warm_up() -> WarmUp | None:
    """Make every compiled kernel ready (module docstring); None where the kernels are not in
    use (NEUROLENS_KERNELS=numpy, or numba absent)."""
    if jit.mode() != "compiled":
        return None
    with _LOCK:
        if _DONE:
            return WarmUp(0.0, 0, 0, True)
        t0 = time.perf_counter()
        _exercise()
        misses = hits = 0
        for d in _dispatchers():
            misses += sum(d.stats.cache_misses.values())
            hits += sum(d.stats.cache_hits.values())
        result = WarmUp(time.perf_counter() - t0, misses, hits, False)
        _DONE.append(result)
        return result


def main() -> int:
    result = warm_up()
    if result is None:
        print("compiled kernels are not in use here (numba absent, or NEUROLENS_KERNELS=numpy)")
        return 1
    print(f"{result.describe()}; cache: {jit.cache_dir()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
