"""Batches of world-space rays against the scene: the casters, and the only caller of
`scene.ray_cast`.

Two backends answer the same two questions (closest hit, occlusion) for whole arrays of rays:
`SceneCaster` here (Blender's own BVH through `scene.ray_cast`, the reference, always there)
and `embree_cast.EmbreeCaster` (Intel Embree through the `embreex` package over the frame's
triangles, tens of times faster); `casters.make_caster` picks one ("AUTO": Embree when
installed).
Both share `Caster`'s bookkeeping: object ids, cast counters, time, the cancel check.

Blender exposes its BVH to Python one ray at a time:
    scene.ray_cast(depsgraph, origin, direction, distance=...) ->
        (hit, location, normal, polygon index, object, matrix)
with the location and the (geometric, face) normal in world space, the polygon index into the
evaluated mesh, and the original object. Every call pays Python and mathutils overhead, which
makes it the engine's bottleneck (figures: docs/render-engine.md), so the loop here is the
minimum: `scene.ray_cast` and the depsgraph are bound once, the rays enter as Python lists
(one `tolist` per chunk, no mathutils construction), and a hit is unpacked straight into flat
lists that become numpy arrays once per chunk. Closest-hit queries keep location, normal,
polygon and object (and, where the frame has instanced copies, which copy was hit: the
matrix `scene.ray_cast` returns is that copy's, looked up by object and matrix among the
depsgraph's instances, so that the Vector pass can follow the copy's motion); shadow queries
keep only the hit flag. Rays go in chunks of CHUNK; the
cancel callback runs between chunks, so Esc waits for at most one chunk of casts.
Objects get small integer ids in the order they are first hit (`objects[id]`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

CHUNK = 4096
#: record every n-th ray cast for a bare replay (0: off; benchmarks/engine_bench.py sets it)
RECORD_STRIDE = 0
#: distance used for rays without a bound (Blender's own default is 1.7e38)
FAR = 1.0e30


class RenderCancelled(Exception):
    """The user pressed Esc (RenderEngine.test_break returned True)."""


@dataclass
class Hits:
    ray: np.ndarray        # (K,) indices of the rays that hit
    location: np.ndarray   # (K, 3) world-space hit points
    normal: np.ndarray     # (K, 3) world-space face normals (unit, not oriented)
    polygon: np.ndarray    # (K,) polygon index in the evaluated mesh
    object: np.ndarray     # (K,) object id (SceneCaster.objects)
    instance: np.ndarray | None = None   # (K,) the instanced copy hit (the caster's
                                         # `instances`; -1: an object's own), or None


def instance_key(inst) -> tuple:
    """What names an instance (a collection's, a particle's, a geometry-nodes one) from frame
    to frame: its object, the object instancing it and its persistent id."""
    return (inst.object.original.name_full, inst.parent.original.name_full,
            tuple(inst.persistent_id))


def _matrix_key(m) -> tuple:
    """A 4 x 4 matrix as a dictionary key, rounded (the copy's matrix as scene.ray_cast
    returns it against the depsgraph's)."""
    return tuple(round(float(v), 6) for row in m for v in row)


class Caster:
    """What every backend keeps: object ids (the original objects hit, `objects[id]`), cast
    counters, time spent, the largest batch, recorded rays (benchmarks) and the cancel check
    polled between chunks."""

    backend = "?"
    #: whether casts may run from several threads at once (Blender's API may not)
    thread_safe = False

    def __init__(self, should_stop=None, chunk: int = CHUNK):
        self.should_stop = should_stop
        self.chunk = int(chunk)
        self.objects: list = []
        self._ids: dict = {}
        self.casts = {"closest": 0, "shadow": 0}
        self.seconds = 0.0
        self._lock = threading.Lock()
        self._thread = threading.local()          # this thread's seconds (renderer timing)
        self.max_batch = 0
        #: every record_stride-th ray is kept in `recorded` (benchmarks replay them bare)
        self.record_stride = RECORD_STRIDE
        self.recorded: list = []

    def _account(self, kind: str, origin, direction, distance, t0: float) -> None:
        """Count one batch of `kind` casts, keep every record_stride-th ray when recording,
        and add the batch's time since t0."""
        n = origin.shape[0]
        dt = time.perf_counter() - t0
        with self._lock:
            self.casts[kind] += n
            self.max_batch = max(self.max_batch, n)
            if self.record_stride:
                k = self.record_stride
                self.recorded.append((origin[::k].copy(), direction[::k].copy(),
                                      None if distance is None else distance[::k].copy()))
            self.seconds += dt
        self._thread.seconds = self.thread_seconds + dt

    @property
    def thread_seconds(self) -> float:
        """Seconds of casting done by the calling thread."""
        return getattr(self._thread, "seconds", 0.0)

    def _check(self):
        if self.should_stop is not None and self.should_stop():
            raise RenderCancelled()

    def _object_ids(self, objs: list) -> np.ndarray:
        with self._lock:
            return self._object_ids_locked(objs)

    def _object_ids_locked(self, objs: list) -> np.ndarray:
        ids = self._ids
        out = np.empty(len(objs), dtype=np.int32)
        for k, ob in enumerate(objs):
            i = ids.get(ob)
            if i is None:
                i = ids[ob] = len(self.objects)
                self.objects.append(ob)
            out[k] = i
        return out

    @property
    def total_casts(self) -> int:
        return self.casts["closest"] + self.casts["shadow"]


class SceneCaster(Caster):
    """scene.ray_cast over arrays of rays (Blender's BVH, one Python call a ray)."""

    backend = "blender"

    def __init__(self, scene, depsgraph, should_stop=None, chunk: int = CHUNK):
        super().__init__(should_stop, chunk)
        self._ray_cast = scene.ray_cast
        self._depsgraph = depsgraph
        #: the instanced copies ((instance_key, matrix) each, as EmbreeCaster's), and each
        #: one's index by (object, matrix key): the Vector pass follows a copy's motion
        self.instances: list = []
        self._instance_at: dict = {}
        for inst in depsgraph.object_instances:
            if inst.is_instance:
                m = inst.matrix_world
                self._instance_at[(inst.object.original.name_full, _matrix_key(m))] = \
                    len(self.instances)
                self.instances.append((instance_key(inst), np.array(m, np.float64)))

    def closest(self, origin: np.ndarray, direction: np.ndarray) -> Hits:
        """First hit of each ray (origin, unit direction: (N, 3) float arrays)."""
        t0 = time.perf_counter()
        rc, dg = self._ray_cast, self._depsgraph
        n = origin.shape[0]
        rays, flat, polys, objs, mats = [], [], [], [], []
        add_ray, add_flat, add_poly, add_obj = rays.append, flat.extend, polys.append, objs.append
        add_mat = mats.append if self.instances else None
        for lo in range(0, n, self.chunk):
            self._check()
            hi = min(n, lo + self.chunk)
            for i, a, b in zip(range(lo, hi), origin[lo:hi].tolist(),
                               direction[lo:hi].tolist()):
                hit, loc, nor, poly, ob, mat = rc(dg, a, b)
                if hit:
                    add_ray(i)
                    add_flat(loc)
                    add_flat(nor)
                    add_poly(poly)
                    add_obj(ob)
                    if add_mat is not None:
                        add_mat(mat)
        k = len(rays)
        ln = np.array(flat, dtype=np.float64).reshape(k, 6)
        hits = Hits(np.array(rays, dtype=np.int64), ln[:, :3], ln[:, 3:],
                    np.array(polys, dtype=np.int64), self._object_ids(objs))
        if add_mat is not None:                 # which instanced copy each hit is on
            at = self._instance_at
            hits.instance = np.array([at.get((ob.original.name_full, _matrix_key(m)), -1)
                                      for ob, m in zip(objs, mats)], dtype=np.int64)
        self._account("closest", origin, direction, None, t0)
        return hits

    def occluded(self, origin: np.ndarray, direction: np.ndarray,
                 distance: np.ndarray) -> np.ndarray:
        """Whether anything lies on each ray within its distance, (N,) bool."""
        t0 = time.perf_counter()
        rc, dg = self._ray_cast, self._depsgraph
        n = origin.shape[0]
        out = np.empty(n, dtype=bool)
        dist = np.minimum(distance, FAR)
        for lo in range(0, n, self.chunk):
            self._check()
            hi = min(n, lo + self.chunk)
            out[lo:hi] = [rc(dg, a, b, distance=t)[0] for a, b, t in
                          zip(origin[lo:hi].tolist(), direction[lo:hi].tolist(),
                              dist[lo:hi].tolist())]
        self._account("shadow", origin, direction, dist, t0)
        return out


def bare_ray_cast_rate(scene, depsgraph, origin: np.ndarray, direction: np.ndarray,
                       distance: np.ndarray | None = None) -> float:
    """Calls per second of the barest possible loop over scene.ray_cast (the reference the
    engine's own rate is compared with): lists prepared beforehand, results discarded, the
    garbage collector paused as in the engine. With `distance`, each call passes it (shadow
    rays)."""
    import gc
    rc = scene.ray_cast
    ol, dl = origin.tolist(), direction.tolist()
    was = gc.isenabled()
    gc.disable()
    try:
        t0 = time.perf_counter()
        if distance is None:
            for a, b in zip(ol, dl):
                rc(depsgraph, a, b)
        else:
            for a, b, t in zip(ol, dl, np.minimum(distance, FAR).tolist()):
                rc(depsgraph, a, b, distance=t)
        dt = time.perf_counter() - t0
    finally:
        if was:
            gc.enable()
    return len(ol) / max(dt, 1e-9)


def replay_rate(scene, depsgraph, recorded: list) -> float:
    """Bare calls per second over rays a SceneCaster recorded (the engine's own mix of
    primary, bounce and shadow rays, same arguments)."""
    n, t = 0, 0.0
    for o, d, dist in recorded:
        if o.shape[0] == 0:
            continue
        rate = bare_ray_cast_rate(scene, depsgraph, o, d, dist)
        n += o.shape[0]
        t += o.shape[0] / rate
    return n / max(t, 1e-12)
