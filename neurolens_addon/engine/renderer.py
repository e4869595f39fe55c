"""The progressive render loop: passes x tiles x bundles, timing, progress and cancellation.

    for each progressive pass [s0, s1)           (plan.sample_passes: 1, 1, 2, 4, ... spp)
        for each tile                              (plan.tiles, bottom-left first)
            for each bundle of the tile (<= max_rays camera samples)
                camera samples -> lens -> world rays      camera_rays (time: "lens")
                paths: ray casts + shading                shading / scene_cast ("cast", "shade")
                accumulate on the film                    film ("film")
            write the tile's passes to the sink (Blender: begin/update/end_result)
            report progress and statistics
On a streamed film (film.Film, chosen by engine.memory.streamed_film for large frames) the two
outer loops swap: tile by tile, every pass of a tile before the next (plan.bundles tile_major),
and a tile's sums are dropped once its last pass is written; the image is the same.
Python's cyclic garbage collector is paused during the loop: every ray cast allocates a
result tuple, two Vectors and a Matrix that the collector would scan again and again (its cost
is in docs/render-engine.md); nothing in the loop makes reference cycles.
The sink's should_stop() (Blender: RenderEngine.test_break) is polled before every bundle and,
through scene_cast, between chunks of ray casts, so a cancel takes effect within tens of
milliseconds of ray casting; the bundle in flight is dropped, every finished tile pass stays
in the result (each pixel then holds the mean of the passes it completed). No bpy types here.
"""

from __future__ import annotations

import gc
import os
import threading
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from . import plan
from .scene_cast import RenderCancelled

#: callables(fraction, text) told about progress (the command line draws its bar with one)
LISTENERS: list = []
#: a stop asked of every render in this process (the command line sets it on SIGINT and
#: SIGTERM); renders poll it with the sink's should_stop
STOP_REQUESTED = threading.Event()


@dataclass
class RenderStats:
    width: int = 0
    height: int = 0
    samples: int = 0
    lens: str = ""
    provider: str = ""
    intersector: str = ""          # the caster's backend: "embree" or "blender"
    samples_total: int = 0
    samples_done: int = 0
    bundles: int = 0
    max_bundle_rays: int = 0       # most camera samples built at once (instrumented)
    max_cast_batch: int = 0        # most rays handed to one scene_cast call
    max_film_tiles: int = 0        # most tiles a streamed film held at once (instrumented)
    streamed: bool = False         # the film was streamed (tile by tile order)
    memory_estimate: int = 0       # bytes engine.memory estimated for the render
    casts_closest: int = 0
    casts_shadow: int = 0
    seconds: dict = field(default_factory=lambda: {"setup": 0.0, "lens": 0.0, "cast": 0.0,
                                                    "shade": 0.0, "film": 0.0, "total": 0.0})
    cancelled: bool = False
    notes: list = field(default_factory=list)
    kernels: str = ""              # the compiled kernels' warm-up (kernel_warmup.WarmUp)

    def add_time(self, name: str, dt: float):
        self.seconds[name] = self.seconds.get(name, 0.0) + dt

    @property
    def casts(self) -> int:
        return self.casts_closest + self.casts_shadow

    def shares(self) -> dict:
        """Fractions of the render loop's work per stage (worker threads' time summed)."""
        stages = ("lens", "cast", "shade", "film")
        work = max(sum(self.seconds[k] for k in stages), 1e-12)
        return {k: self.seconds[k] / work for k in stages}

    def summary(self) -> str:
        loop = max(self.seconds["total"] - self.seconds["setup"], 1e-12)
        sh = self.shares()
        # the denoiser is named when it ran (a frame left noisy has a note saying why instead)
        denoised = (f" | denoised (Open Image Denoise, {self.seconds['denoise']:.1f} s)"
                    if "denoise" in self.seconds else "")
        kernels = f" | {self.kernels}" if self.kernels else ""
        if "flare" in self.seconds:            # the lamps' flare (engine.flare), after the loop
            denoised += f" | flare {self.seconds['flare']:.2f} s"
        return (f"{self.samples_done / loop:,.0f} samples/s, {self.casts / loop:,.0f} casts/s "
                f"({self.intersector or 'blender'}) | "
                f"lens {100 * sh['lens']:.0f}%, casts {100 * sh['cast']:.0f}%, "
                f"shading {100 * sh['shade']:.0f}%, film {100 * sh['film']:.0f}%"
                f"{denoised}{kernels}")


class FrameRenderer:
    """Renders one frame into a Film, writing tiles to a sink as they complete.

    sink: write_tile(tile, passes: dict), progress(fraction, text), should_stop() -> bool.
    """

    def __init__(self, generator, shader, film, settings, sink, stats: RenderStats | None = None):
        self.generator = generator
        self.shader = shader
        self.film = film
        self.settings = settings
        self.sink = sink
        self.stats = stats or RenderStats()
        self._lens_lock = threading.Lock()

    def run(self) -> RenderStats:
        """Render the whole frame (every bundle of `steps`), the garbage collector paused (the
        cast loop makes ~10 objects per ray: no cycle scans)."""
        gc_was_enabled = gc.isenabled()
        gc.disable()
        try:
            for _ in self.steps():
                pass
        finally:
            if gc_was_enabled:
                gc.enable()
        return self.stats

    def workers(self) -> int:
        """Threads that shade bundles at once: numpy and Embree release Python's lock, so
        bundles overlap; one for Blender's own ray casts (its API is not thread-safe)."""
        if not self.shader.caster.thread_safe:
            return 1
        n = self.settings.workers or (os.cpu_count() or 1)
        return max(1, min(int(n), 16))

    def steps(self):
        """Render bundle by bundle, yielding after each (the viewport interleaves them with
        drawing); the stats are complete when the generator ends. Bundles are shaded by
        `workers()` threads, a few ahead, and reach the film in order, so the image does not
        depend on the number of threads."""
        st, s, f = self.stats, self.settings, self.film
        W, H = f.width, f.height
        st.width, st.height, st.samples = W, H, s.samples
        st.samples_total = plan.total_samples(W, H, s.samples)
        t_start = time.perf_counter() - st.seconds["setup"]
        caster = self.shader.caster
        learned = self.generator.evaluator.learned is not None
        ntiles = len(plan.tiles(W, H, s.tile_size))
        workers = self.workers()
        pool = ThreadPoolExecutor(workers, thread_name_prefix="neurolens") if workers > 1 \
            else None
        stop = threading.Event()
        if pool is not None:
            caster.should_stop = stop.is_set     # workers never call into Blender to ask
        pending: deque = deque()
        try:
            # a bundle's bound counts lens rays: with dispersion a sample is three of them
            max_samples = max(1, s.max_bundle_rays // self.generator.rays_per_sample)
            st.streamed = f.streamed
            bundles = plan.bundles(W, H, s.samples, s.tile_size, max_samples,
                                   tile_major=f.streamed)
            while True:
                b = next(bundles, None)
                if b is not None:
                    if self.sink.should_stop() or STOP_REQUESTED.is_set():
                        raise RenderCancelled()
                    unc = learned and b.s0 < s.uncertainty_samples
                    pending.append((b, pool.submit(self._compute, b, unc) if pool else
                                    self._compute(b, unc)))
                    if len(pending) <= workers and pool is not None:
                        continue                  # keep every worker busy
                if not pending:
                    break
                b, work = pending.popleft()
                self._accumulate(b, work.result() if pool else work)
                st.bundles += 1
                if b.last_of_tile:
                    t0 = time.perf_counter()
                    passes = f.readout(b.tile)
                    self.sink.write_tile(b.tile, passes)
                    st.max_film_tiles = max(st.max_film_tiles, f.tiles_in_progress)
                    if b.last_pass:
                        f.finish(b.tile, passes)
                    del passes
                    st.add_time("film", time.perf_counter() - t0)
                    st.seconds["total"] = time.perf_counter() - t_start
                    st.casts_closest = caster.casts["closest"]
                    st.casts_shadow = caster.casts["shadow"]
                    frac = st.samples_done / st.samples_total
                    text = (f"Sample {b.s1}/{s.samples} | Tile {b.tile_index + 1}/{ntiles} | "
                            + st.summary())
                    self.sink.progress(frac, text)
                    for fn in LISTENERS:
                        fn(frac, text)
                yield b
        except RenderCancelled:
            st.cancelled = True
        finally:
            stop.set()
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
                caster.should_stop = self.sink.should_stop
        st.seconds["total"] = time.perf_counter() - t_start
        st.casts_closest = caster.casts["closest"]
        st.casts_shadow = caster.casts["shadow"]

    def _compute(self, b: plan.Bundle, uncertainty: bool):
        """One bundle's camera samples and their shading (a worker thread's part): (pixel
        within the tile of each sample, camera samples, shading, seconds per stage)."""
        t = b.tile
        k = b.s1 - b.s0
        local = np.repeat(np.arange(b.p0, b.p1), k)
        ly, lx = np.divmod(local, t.w)
        pixel = (t.y + ly) * self.film.width + (t.x + lx)
        sample = np.tile(np.arange(b.s0, b.s1), b.p1 - b.p0)
        caster = self.shader.caster
        t0 = time.perf_counter()
        with self._lens_lock:                    # one lens evaluation at a time: it threads
            lens = []                            # itself (onnxruntime), and owns caches
            self.generator.timer = lambda name, dt: lens.append(dt)
            cam = self.generator.generate(pixel, sample, uncertainty=uncertainty)
        t1 = time.perf_counter()
        cast0 = caster.thread_seconds
        res = self.shader.shade(cam)
        t2 = time.perf_counter()
        cast = caster.thread_seconds - cast0
        # camera-ray generation beyond the lens call itself (sampling, space changes) is
        # counted as shading work: it is the engine's own numpy, not the lens
        seconds = {"lens": sum(lens), "cast": cast,
                   "shade": (t2 - t1) - cast + (t1 - t0) - sum(lens)}
        return local, cam, res, seconds

    def _accumulate(self, b: plan.Bundle, work) -> None:
        """Add a shaded bundle to the film and the statistics (the calling thread's part)."""
        local, cam, res, seconds = work
        st, f = self.stats, self.film
        for name, dt in seconds.items():
            st.add_time(name, dt)
        t2 = time.perf_counter()
        ray_local = local if cam.source is None else local[cam.source]
        f.add(b.tile, ray_local, rgb=res.rgb, valid=cam.valid, hit=res.hit, depth=res.depth,
              normal=res.normal, illumination=cam.illumination, uncertainty=cam.uncertainty,
              share=cam.share, albedo=res.albedo, data=res.data)
        st.add_time("film", time.perf_counter() - t2)
        st.samples_done += local.size
        st.max_bundle_rays = max(st.max_bundle_rays, cam.pixel.size)
        st.max_cast_batch = self.shader.caster.max_batch
