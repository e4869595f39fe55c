"""Camera samples: film point, aperture sample and wavelength, through the lens, to world space.

Film. Pixel (i, j) with jitter (a, b) lies at the image point (p, q) (right, up; mm) that
core.film gives (sensor size, fit, pixel aspect and shift, as Cycles frames it). A real lens
forms an inverted image, so (p, q) is read from the lens-space film point (x, y) = (-p, -q):
the film readout flips the image back (a 180 degree rotation, not a mirror).

Aperture. The derived camera's sampler (camera.derived: core.pupil.camera_ray_sampler) aims
each film point at a uniform point of the cells of its exit-pupil grid that pass the lens
(RearPupilSampler, pupil-aware: few rays are wasted on the barrel), or, for an anamorphic lens,
of the rear element's disc (RearDiscSampler), with the irradiance estimator's weight
g = cos^4(t) / (dz^2 p_A). Channel c of a pixel is
    C_c = E[ g V L(lambda_c) ] / g_0,   lambda_c ~ s_c,
V the ray's validity (it passed every aperture), L the radiance the scene returns along it,
s_c channel c's non-negative response (core.sensor_response; integral 1, so white stays
white), and g_0 = E_0 the derived camera's centre irradiance (core.pupil.centre_irradiance:
E[g V] at the film centre, the value the Cycles camera divides by too), so a uniform scene of
radiance L reads L at the centre and falls off with the lens's natural and mechanical
vignetting elsewhere. With
dispersion a sample is three lens rays, one per channel (generate: no colour noise), or, with
colour_rays = 1, one ray at a wavelength drawn from the whole sensor, p = (s_R + s_G + s_B) / 3,
weighted 3 s_c / sum s (as the Cycles camera: three times less shading per sample, with colour
noise); without dispersion, one ray at the d line counts towards all three.

Random numbers are a counter-based hash of (seed, pixel, sample, dimension), so a sample is
the same whatever the tiling or bundle size and the exact and learned lenses see identical
samples. Pixel jitter is the R2 sequence (Roberts 2018) and the wavelength the golden-ratio
sequence, both Cranley-Patterson rotated per pixel by the hash (stratified across a pixel's
samples); the three aperture dimensions are independent hashes. Wavelength and aperture
samples therefore share no structure (decorrelated): the dispersion of the lens cannot alias
with the position in the pupil.

Ghosts (opt-in, LensSetup.ghosts): a sample is a ghost sample with probability s (the share),
decided by its own hash (DIM_GHOST; the three channel rays of a sample decide alike); it picks
ghost g of the derived camera's plan (DerivedCamera.ghost_plan, the brightest) with
probability p_g proportional to its energy E_g (DIM_GHOST + 1), aims uniformly over the rear
element's disc (core.pupil.disc_rays: a ghost leaves through any part of it) and follows the
ghost's path in the exact lens (core.trace with the ghost and the coating; a learned model
knows only the image's path):
    weight = c_disc V w_g / T_0 * k / (s p_g) / g_0,
w_g the path's reflectances and transmittances (the coating), T_0 the image path's mean
transmittance at the film centre (so a ghost's light is relative to the image's, as E_g is),
k the intensity. The other samples carry the image with weight g V / g_0 * kappa / (1 - s),
kappa = 1 / (1 + k sum_g E_g): the ghosts' light is taken from the image, so a uniformly lit
scene keeps its total light. Both estimators are unbiased for their share.

Lens. Each bundle goes through the lens in one batch: core.trace.trace (exact, float64) or
neural LearnedLens.trace_from_sensor (onnxruntime). The learned lens's ensemble spread
(when asked) is reduced per ray to u = sqrt(s_1^2 + s_2^2), its two stages' RMS disagreement.

To Blender. Lens space is mm with +z towards the scene and the sensor plane at z = z_s; the
camera looks down its local -Z in scene units, with its origin on the sensor plane (so that the
focus distance is measured from the sensor, like a camera's scale). A lens-space point and
direction map to camera space as
    P_cam = k (x, y, -(z - z_s)),   D_cam = (d_x, d_y, -d_z),   k = 1 / (1000 * unit scale)
(x and y keep their sense; (x, y, z) -> (x, y, -z) is a reflection, harmless for a rotationally
symmetric lens) and to world space with the camera's matrix M = [R | t] (R with its scale
removed):  P = R P_cam + t,  D = R D_cam / |R D_cam|.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core.rays import Rays
from ..core.prescription import WAVELENGTH_D_NM
from ..core.sensor_response import sensor_response
from . import camera_kernels, shading_kernels

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)
_R2 = (1.0 / 1.32471795724474602596, 1.0 / 1.32471795724474602596 ** 2)
_GOLDEN = 0.6180339887498949
#: sample dimensions (hash salts)
DIM_PIXEL, DIM_WAVELENGTH, DIM_APERTURE, DIM_GHOST = 0, 2, 3, 6


# ---------------------------------------------------------------- random numbers

def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    x = x ^ (x >> np.uint64(30))
    x = x * _M2
    x = x ^ (x >> np.uint64(27))
    x = x * _M3
    return x ^ (x >> np.uint64(31))


def hash_u01(seed: int, pixel: np.ndarray, sample: np.ndarray, dim: int) -> np.ndarray:
    """Uniform [0, 1) float64, a pure function of (seed, pixel, sample, dim)."""
    if shading_kernels.active():
        return shading_kernels.run_hash_u01(seed, pixel, sample, dim)
    return hash_u01_numpy(seed, pixel, sample, dim)


def hash_u01_numpy(seed: int, pixel: np.ndarray, sample: np.ndarray, dim: int) -> np.ndarray:
    """`hash_u01` in numpy, the reference of the compiled kernel."""
    p = np.asarray(pixel, dtype=np.uint64)
    s = np.asarray(sample, dtype=np.uint64)
    salt, dim1 = shading_kernels.salts(seed, dim)
    with np.errstate(over="ignore"):
        x = _mix(p * _M1 + salt)
        x = _mix(x ^ (s * _M2 + dim1))
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


def camera_uniforms(seed: int, pixel: np.ndarray, sample: np.ndarray) -> dict:
    """The six uniforms of each camera sample: jitter (2, stratified), wavelength (1,
    stratified), aperture (3, independent); keys 'jitter' (2, N), 'wavelength' (N,),
    'aperture' (3, N)."""
    k = np.asarray(sample, dtype=np.float64)
    rot_x = hash_u01(seed, pixel, 0, DIM_PIXEL)
    rot_y = hash_u01(seed, pixel, 0, DIM_PIXEL + 1)
    jitter = np.stack([np.mod(rot_x + k * _R2[0], 1.0), np.mod(rot_y + k * _R2[1], 1.0)])
    wl = np.mod(hash_u01(seed, pixel, 0, DIM_WAVELENGTH) + k * _GOLDEN, 1.0)
    ap = np.stack([hash_u01(seed, pixel, sample, DIM_APERTURE + i) for i in range(3)])
    return {"jitter": jitter, "wavelength": wl, "aperture": ap}


# ---------------------------------------------------------------- lens evaluation

@dataclass
class LensOutput:
    o: np.ndarray                  # (3, N) lens-space origins (mm), 0 where invalid
    d: np.ndarray                  # (3, N) unit directions
    valid: np.ndarray              # (N,) bool
    uncertainty: np.ndarray | None  # (N,) per-ray ensemble spread, None if not computed


class LensEvaluator:
    """One derived camera (camera.derived.DerivedCamera): rays from the sensor through its
    lens, one batch."""

    def __init__(self, camera, *, learned=None):
        self.camera = camera
        self.learned = learned           # neural.model.LearnedLens when the model is learned
        self.mode = camera.model

    @property
    def provider(self) -> str:
        if self.learned is not None:
            return self.learned.provider
        from ..core.jit import mode
        return "numba (exact)" if mode() == "compiled" else "numpy (exact)"

    def __call__(self, rays: Rays, uncertainty: bool = False) -> LensOutput:
        c = self.camera
        if self.learned is None:
            from ..core.trace import trace
            r = trace(c.lens, rays, from_sensor=True, stop_radius=c.stop_radius_mm,
                      aperture=c.aperture, sensor_z=c.sensor_z_mm)
            return LensOutput(r.rays.o, r.rays.d, r.valid, None)
        # a lens known only from a ray table has no stop: its model's domain bounds its rays
        stop, shape = (None, None) if c.table else (c.stop_radius_mm, c.aperture)
        r = self.learned.trace_from_sensor(rays, c.sensor_z_mm, stop_radius=stop,
                                           aperture=shape, uncertainty=uncertainty)
        unc = None
        if uncertainty and r.uncertainty is not None:
            unc = np.sqrt((r.uncertainty.astype(np.float64) ** 2).sum(axis=1))
        return LensOutput(r.rays.o, r.rays.d, r.valid, unc)


_MODEL_CACHE: dict = {}


def make_evaluator(camera, providers=None, threads=None) -> LensEvaluator:
    """An evaluator for a DerivedCamera; learned models are loaded once per (path, lens)."""
    if camera.model != "learned":
        return LensEvaluator(camera)
    from ..neural.model import LearnedLens
    key = (camera.model_dir, camera.lens.content_hash(), tuple(providers or ()), threads)
    model = _MODEL_CACHE.get(key)
    if model is None:
        model = LearnedLens.load(camera.model_dir, lens=None if camera.table else camera.lens,
                                 providers=providers, threads=threads)
        _MODEL_CACHE.clear()            # one model at a time: they hold onnxruntime sessions
        _MODEL_CACHE[key] = model
    return LensEvaluator(camera, learned=model)


# ---------------------------------------------------------------- space changes

def lens_to_camera(o: np.ndarray, d: np.ndarray, sensor_z: float, mm_per_unit: float):
    """Lens space (3, N) mm -> camera space (N, 3) scene units (module docstring)."""
    k = 1.0 / mm_per_unit
    pc = np.empty((o.shape[1], 3))
    pc[:, 0] = o[0] * k
    pc[:, 1] = o[1] * k
    pc[:, 2] = -(o[2] - sensor_z) * k
    dc = np.empty((d.shape[1], 3))
    dc[:, 0] = d[0]
    dc[:, 1] = d[1]
    dc[:, 2] = -d[2]
    return pc, dc


def lens_to_world(points: np.ndarray, m: np.ndarray, sensor_z: float,
                  mm_per_unit: float) -> np.ndarray:
    """(3, N) lens-space points (mm) -> (N, 3) world points: lens_to_camera and
    camera_to_world for points alone, p = R c + t."""
    pc, _dc = lens_to_camera(points, points[:, :0], sensor_z, mm_per_unit)
    return np.einsum("ij,kj->ik", pc, m[:3, :3]) + m[:3, 3]


def world_to_lens(points: np.ndarray, m: np.ndarray, sensor_z: float,
                  mm_per_unit: float) -> np.ndarray:
    """(N, 3) world points -> (N, 3) lens-space points (mm): camera_to_world and
    lens_to_camera inverted, c = R^T (p - t), (x, y, z) = (c_x / k, c_y / k, z_s - c_z / k)."""
    k = 1.0 / mm_per_unit
    c = np.einsum("ij,jk->ik", points - m[:3, 3], m[:3, :3])      # R^T (p - t), as rows
    out = np.empty_like(c)
    out[:, 0] = c[:, 0] / k
    out[:, 1] = c[:, 1] / k
    out[:, 2] = sensor_z - c[:, 2] / k
    return out


def rigid(matrix_world) -> np.ndarray:
    """4x4 camera matrix with the scale removed from its rotation columns."""
    m = np.array(matrix_world, dtype=np.float64).reshape(4, 4).copy()
    norms = np.linalg.norm(m[:3, :3], axis=0)
    m[:3, :3] /= np.where(norms > 0, norms, 1.0)
    return m


def camera_to_world(pc: np.ndarray, dc: np.ndarray, m: np.ndarray):
    """(N, 3) camera-space points and directions -> world space with the rigid matrix m."""
    r, t = m[:3, :3], m[:3, 3]
    # einsum, not matmul: a BLAS product wakes BLAS's own threads, which then spin and take
    # the core another bundle's worker thread needs
    p = np.einsum("ij,kj->ik", pc, r) + t
    d = np.einsum("ij,kj->ik", dc, r)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return p, d


# ---------------------------------------------------------------- the generator

@dataclass
class CameraSamples:
    """One bundle's camera samples; world rays only for the valid ones (`index` into all)."""

    pixel: np.ndarray          # (N,) global pixel index y * W + x
    sample: np.ndarray         # (N,) sample index within the pixel
    valid: np.ndarray          # (N,) bool: the ray passed the lens
    weight: np.ndarray         # (N, 3) g V w(lambda) / g_0 (0 where invalid)
    illumination: np.ndarray   # (N,) g V / g_0: the relative illumination, without colour
    index: np.ndarray          # (M,) indices of the valid samples
    origin: np.ndarray         # (M, 3) world-space origins of the valid rays
    direction: np.ndarray      # (M, 3) unit world directions
    uncertainty: np.ndarray | None   # (N,) per-sample ensemble spread (0 where invalid)
    source: np.ndarray | None = None  # (N,) the requested sample each ray belongs to (None:
                                      # one ray per sample, in the order requested)
    share: float = 1.0               # each ray's share of its sample in the non-colour passes
    ghost: np.ndarray | None = None  # (N,) bool: a ghost sample (None: no ghosts)


class CameraRayGenerator:
    """Camera samples for pixels and sample indices, through one derived camera (the
    evaluator's) and one camera placement."""

    def __init__(self, evaluator: LensEvaluator, camera_matrix, mm_per_unit: float = 1000.0,
                 *, seed: int = 0, dispersion: bool = True, colour_rays: int = 3, timer=None):
        self.evaluator = evaluator
        self.camera = c = evaluator.camera
        self.film = c.film
        self.matrix = rigid(camera_matrix)
        self.mm_per_unit = float(mm_per_unit)
        self.seed = int(seed)
        self.dispersion = bool(dispersion)
        if colour_rays not in (1, 3):
            raise ValueError(f"colour rays per sample must be 1 or 3, got {colour_rays}")
        self.colour_rays = int(colour_rays)
        self.timer = timer                       # callable(name, seconds) or None
        self.sampler = c.sampler
        self.g0 = c.centre_irradiance
        self.ghosts = c.ghost_plan
        self._ghost_cdf = (None if self.ghosts is None else
                           np.concatenate([[0.0], np.cumsum(self.ghosts.probability)]))
        # the compiled passes (camera_kernels; ghosts keep the numpy path), set up once
        self._tables = None
        if shading_kernels.active() and self.ghosts is None:
            mode = (camera_kernels.PER_CHANNEL if self.rays_per_sample == 3 else
                    camera_kernels.SENSOR if self.dispersion else camera_kernels.D_LINE)
            self._tables = camera_kernels.CameraTables(
                self.seed, self.film, c.squeeze, sensor_response(), mode, self.sampler, _R2,
                _GOLDEN, WAVELENGTH_D_NM, (DIM_PIXEL, DIM_PIXEL + 1, DIM_WAVELENGTH,
                                           DIM_APERTURE, DIM_APERTURE + 1, DIM_APERTURE + 2))

    def _trace_ghosts(self, pixel, sample, x, y, a, lam):
        """(o, d, valid, weight) of ghost samples from sensor points (x, y) (module
        docstring), weight already divided by g_0."""
        from ..core.pupil import disc_rays
        from ..core.trace import trace
        c = self.camera
        plan = self.ghosts
        ghosts = plan.ghosts
        factor = plan.ghost_factor / self.g0
        pick = np.clip(np.searchsorted(self._ghost_cdf,
                                       hash_u01(self.seed, pixel, sample, DIM_GHOST + 1),
                                       side="right") - 1, 0, len(ghosts) - 1)
        rays, c_disc = disc_rays(c.lens, x, y, c.sensor_z_mm, a[0], a[1], lam)
        n = x.shape[0]
        o, d = np.zeros((3, n)), np.zeros((3, n))
        d[2] = 1.0
        valid = np.zeros(n, dtype=bool)
        weight = np.zeros(n)
        for j in np.unique(pick):
            sel = np.flatnonzero(pick == j)
            sub = Rays(rays.o[:, sel], rays.d[:, sel], rays.wavelength[sel])
            res = trace(c.lens, sub, ghost=ghosts[j], coating=c.coating,
                        stop_radius=c.stop_radius_mm, aperture=c.aperture)
            o[:, sel], d[:, sel], valid[sel] = res.rays.o, res.rays.d, res.valid
            weight[sel] = c_disc[sel] * res.weight * factor / plan.probability[j]
        return o, d, valid, weight

    # -- a bundle

    @property
    def rays_per_sample(self) -> int:
        """Lens rays one camera sample makes: one per colour channel with dispersion (unless
        colour_rays is 1)."""
        return 3 if self.dispersion and self.colour_rays == 3 else 1

    def generate(self, pixel: np.ndarray, sample: np.ndarray,
                 uncertainty: bool = False) -> CameraSamples:
        """Camera samples for global pixel indices and sample indices (both (N,)).

        With dispersion a sample is three rays, R, G and B, each at a wavelength drawn from its
        channel's response (core.sensor_response) and counting towards that channel only, with
        weight 1: their colour weights sum to white exactly. They share the film point, the
        aperture sample and (through pixel and sample) every shading random number, so a grey
        surface stays grey sample by sample and only the lens's own colour remains.
        """
        pixel = np.asarray(pixel, dtype=np.int64)
        sample = np.asarray(sample, dtype=np.int64)
        if self._tables is not None:
            return self._generate_compiled(pixel, sample, uncertainty)
        f = self.film
        u = camera_uniforms(self.seed, pixel, sample)
        iy, ix = np.divmod(pixel, f.width_px)
        p, q = f.image_points(ix, iy, u["jitter"][0], u["jitter"][1])
        a = u["aperture"]
        k = self.rays_per_sample
        source = None
        if k == 3:
            response = sensor_response()
            lam = np.stack([response.sample_channel(u["wavelength"], c) for c in range(3)],
                           axis=1).ravel()
            spectral = np.tile(np.eye(3), (pixel.size, 1))
            source = np.repeat(np.arange(pixel.size), 3)
            pixel, sample, p, q, a = pixel[source], sample[source], p[source], q[source], \
                a[:, source]
        elif self.dispersion:
            lam, spectral = sensor_response().sample_sensor(u["wavelength"])
        else:
            lam = np.full(pixel.shape, WAVELENGTH_D_NM)
            spectral = np.ones((pixel.size, 3))
        lam = np.broadcast_to(np.asarray(lam, dtype=np.float64), pixel.shape)
        # inverted image; an anamorphic lens's film is desqueezed: the sensor is 1 / S as wide
        s = self.sampler.sample(-p / self.camera.squeeze, -q, a[0], a[1], a[2], lam)
        t0 = time.perf_counter()
        ghost = None
        if self.ghosts is not None:
            ghost = hash_u01(self.seed, pixel, sample, DIM_GHOST) < self.ghosts.share
        if ghost is None or not ghost.any():
            out = self.evaluator(s.rays, uncertainty=uncertainty)
            valid = out.valid & (s.weight > 0)
            illumination = np.where(valid, s.weight, 0.0) / self.g0
            if ghost is not None:
                illumination *= self.ghosts.image_factor
        else:
            out, valid, illumination = self._with_ghosts(s, ghost, pixel, sample, p, q, a, lam,
                                                         uncertainty)
        if self.timer is not None:
            self.timer("lens", time.perf_counter() - t0)
        weight = spectral * illumination[:, None]
        index = np.flatnonzero(valid)
        pc, dc = lens_to_camera(out.o[:, index], out.d[:, index], self.camera.sensor_z_mm,
                                self.mm_per_unit)
        origin, direction = camera_to_world(pc, dc, self.matrix)
        unc = None
        if out.uncertainty is not None:
            unc = np.where(valid, out.uncertainty, 0.0)
        return CameraSamples(pixel, sample, valid, weight, illumination, index, origin,
                             direction, unc, source, 1.0 / k, ghost)

    def _generate_compiled(self, pixel, sample, uncertainty):
        """`generate` through camera_kernels' two passes around the lens (no ghosts)."""
        t = self._tables
        o, d, lam, w, spectral = t.sensor_rays(pixel, sample)
        source = None
        if t.rays_per_sample == 3:
            source = np.repeat(np.arange(pixel.size), 3)
            pixel, sample = pixel[source], sample[source]
        t0 = time.perf_counter()
        out = self.evaluator(Rays(o, d, lam), uncertainty=uncertainty)
        if self.timer is not None:
            self.timer("lens", time.perf_counter() - t0)
        valid, illumination, weight, index, origin, direction = camera_kernels.run_to_world(
            out.o, out.d, out.valid, w, self.g0, spectral, self.camera.sensor_z_mm,
            self.mm_per_unit, self.matrix)
        unc = None
        if out.uncertainty is not None:
            unc = np.where(valid, out.uncertainty, 0.0)
        return CameraSamples(pixel, sample, valid, weight, illumination, index, origin,
                             direction, unc, source, 1.0 / t.rays_per_sample)

    def _with_ghosts(self, s, ghost, pixel, sample, p, q, a, lam, uncertainty):
        """The bundle's image samples through the evaluator, its ghost samples along their
        ghosts: (LensOutput of all, valid, illumination)."""
        img = np.flatnonzero(~ghost)
        gh = np.flatnonzero(ghost)
        n = ghost.shape[0]
        o, d = np.zeros((3, n)), np.zeros((3, n))
        d[2] = 1.0
        valid = np.zeros(n, dtype=bool)
        illumination = np.zeros(n)
        unc = np.zeros(n) if uncertainty else None
        if img.size:
            part = self.evaluator(Rays(s.rays.o[:, img], s.rays.d[:, img],
                                       s.rays.wavelength[img]), uncertainty=uncertainty)
            v = part.valid & (s.weight[img] > 0)
            o[:, img], d[:, img], valid[img] = part.o, part.d, v
            illumination[img] = (np.where(v, s.weight[img], 0.0) / self.g0
                                 * self.ghosts.image_factor)
            if unc is not None and part.uncertainty is not None:
                unc[img] = part.uncertainty
        go, gd, gv, gw = self._trace_ghosts(pixel[gh], sample[gh],
                                            -p[gh] / self.camera.squeeze, -q[gh], a[:, gh],
                                            lam[gh])
        o[:, gh], d[:, gh], valid[gh], illumination[gh] = go, gd, gv, gw
        return LensOutput(o, d, valid, unc), valid, illumination

    # -- helpers for tests and diagnostics

    @property
    def view_axis(self) -> np.ndarray:
        """World direction the camera looks along (-Z of its matrix)."""
        return -self.matrix[:3, 2]

    @property
    def position(self) -> np.ndarray:
        return self.matrix[:3, 3]
