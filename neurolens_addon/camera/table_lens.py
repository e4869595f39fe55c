"""A lens known only from a ray table: its learned model is the lens.

`python -m trainer fit-table TABLE.npz --out NAME` learns a lens from rays traced or measured
elsewhere, with no prescription (model.json names the lens "table-" + a digest of the table).
Nothing else knows that lens, so its model renders it whatever its cost (there is no exact
trace to compare with or fall back to), at the one focus and aperture the table was taken at.
A camera names it by the model directory, where it would name a lens file.

What a camera needs of a lens is read from the model (the learned lens, LearnedLens):
  sensor plane     the table's input plane z_s (planes.input_z): the table starts on the film
  passing rays     those the model's domain holds (trace_from_sensor's valid: the table's
                   coverage of (r, u_r, u_t), the radial frame's film radius and direction
                   cosines): the pass test of core.pupil's sampler and centre irradiance
  sampling plane   where the bundles of every film radius centre: a bundle from film radius r
                   aims at r + P t on the plane z_s + P (t = u_r / w its radial slope), centred
                   on the axis when P = -sum(r t) / sum(t^2) over the occupied cells (least
                   squares: the exit pupil's distance from the film); half width the largest
                   aim offset of any occupied cell's corners, grown by PLANE_MARGIN
  centre irradiance E_0 by core.pupil.centre_irradiance with that pass test
  f-number         the working f-number of E_0: a cone of half-angle a carries E_0 = pi sin^2 a,
                   N = 1 / (2 sin a) = sqrt(pi / (4 E_0))
  focus            where the film centre's rays meet the axis in the scene, by the angle
                   they miss it by: their scene-side lines (points p_i = (x_i, y_i) on the
                   plane z_o, slopes t_i = (d_x, d_y) / d_z) pass the axis point at distance
                   1 / s beyond z_o at the angle |p_i s + t_i|; s minimising their sum of
                   squares is s = -sum(p_i . t_i) / sum(p_i . p_i) (in 1 / distance: the
                   least squares stay well posed at infinity, where the distance's own do
                   not). Infinity where s <= 0 (parallel or diverging rays); else the focus
                   distance is z_o + 1 / s - z_s.
  focal length     the pinhole that frames alike: f = h / tan(theta) for the film point at
                   h = FIELD_FRACTION x the film radius, theta the angle of its rays' mean
                   scene-side direction (the image is inverted: the point at +h looks to -x)
  chief rays       with no stop to pass through the centre of, the ray from a film point
                   aimed at the centroid of its passing rays' aims on the sampling plane (the
                   exit pupil's centre as that point sees it; a CHIEF_GRID^2 grid of aims over
                   the plane's square), one ray per film radius through the model: its angle
                   theta(r) and where its scene-side line meets the axis, the chief-ray table
                   of core.stmap (ST-maps, lens data, the Vector pass). The model's directions
                   err by ~1e-4 rad, an offset near the axis no lens of revolution has: theta
                   is the least-squares odd polynomial theta = a_1 r + a_3 r^3 + ... (a term
                   more while it lowers the RMS residual by more than ODD_FIT_GAIN: the smooth
                   curve under the noise), the pinhole's focal length its paraxial limit
                   1 / a_1; where the line meets the axis, a least-squares a + b r^2 + c r^4,
                   its rows weighted by theta^2 (its error grows as 1 / theta^2 towards the
                   axis: inverse variance)
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from ..core.errors import LensError, ModelError
from ..core.prescription import WAVELENGTH_D_NM
from ..core.rays import Rays

#: the content hash prefix of a model learned from a ray table (trainer.pipeline.fit_table)
TABLE_PREFIX = "table-"
#: the sampling plane's half width beyond the largest aim offset of an occupied cell
PLANE_MARGIN = 1.1
#: the film point whose rays give the focal length, as a fraction of the film radius
FIELD_FRACTION = 0.1
#: rays traced from one film point for the focus and the focal length
PROBE_RAYS = 20000
#: aims per side of the grid over the sampling plane whose passing rays' centroid a chief ray
#: is aimed at, and film radii of the chief-ray table
CHIEF_GRID = 64
CHIEF_RADII = 97
#: the chief rays' angles are smoothed by an odd polynomial in the film radius, a term more
#: while it lowers the RMS residual by more than ODD_FIT_GAIN (at most ODD_FIT_TERMS terms)
ODD_FIT_GAIN = 0.1
ODD_FIT_TERMS = 8


def is_table_model(directory) -> bool:
    """Whether `directory` is a model directory of a lens known only from a ray table."""
    from ..neural.modelfile import read_header
    p = Path(directory)
    if not (p / "model.json").is_file():
        return False
    try:
        return read_header(p).lens_content_hash.startswith(TABLE_PREFIX)
    except ModelError:
        return False


class TableLens:
    """The lens of a ray-table model, as far as a camera needs one (module docstring). It has
    no surfaces: whatever needs them (the exact trace, ghosts, flare, the Cycles exact camera)
    is not available."""

    table = True
    anamorphic = False
    zoom_gaps = None
    focus_gaps = None
    stop_radius_mm = None
    field_of_view_deg = None

    def __init__(self, directory):
        from ..neural.modelfile import decode_occupancy, read_model_json
        directory, meta, _guards, _files = read_model_json(directory)
        self.directory = Path(directory)
        self.path = str(self.directory)
        lens = meta["lens"]
        self._hash = str(lens["content_hash"])
        if not self._hash.startswith(TABLE_PREFIX):
            raise ModelError("this model was learned from a lens file, not a ray table: choose "
                             "the lens file, and the model with it", path=self.path)
        self.name = str(lens["name"])
        self.sensor_z = float(meta["planes"]["input_z"])
        self.film_radius_mm = float(meta["domain"]["film_radius_mm"])
        self.dispersion = bool(meta["domain"].get("dispersion", False))
        self.source = f"Learned from the ray table {lens.get('source', '(unnamed)')}"
        occ = meta["stages"][0]["occupancy"]
        grid = decode_occupancy(occ)
        self.plane = _sampling_plane(grid, np.asarray(occ["lo"], float),
                                     np.asarray(occ["hi"], float), self.sensor_z)
        self._chief_tables = {}

    def content_hash(self) -> str:
        return self._hash

    @functools.cached_property
    def learned(self):
        """The model, loaded once (ModelError without onnxruntime)."""
        from ..neural.model import LearnedLens
        return LearnedLens.load(self.directory)

    def trace(self, rays: Rays):
        """Camera rays (from the sensor plane) through the table lens: the model's result
        (.valid, .rays on its output plane)."""
        return self.learned.trace_from_sensor(rays, self.sensor_z)

    def passes(self, rays: Rays) -> np.ndarray:
        """Which camera rays the table lens passes (the model's domain holds them)."""
        return np.asarray(self.trace(rays).valid, bool)

    def sampler(self, film_radius_mm: float, *, bands: int | None = None,
                grid: int | None = None):
        """core.pupil.RearPupilSampler of the table lens's passing rays over a film radius."""
        from ..core.pupil import RearPupilSampler
        return RearPupilSampler(None, film_radius_mm, sensor_z=self.sensor_z, bands=bands,
                                grid=grid, passes=self.passes, plane=self.plane)

    @functools.cached_property
    def centre_irradiance(self) -> float:
        """E_0 of the table lens (module docstring)."""
        from ..core.pupil import centre_irradiance
        return centre_irradiance(None, sensor_z=self.sensor_z, passes=self.passes,
                                 disc=self.plane, name=self.name)

    @property
    def f_number(self) -> float:
        """The working f-number of the centre irradiance (module docstring)."""
        return math.sqrt(math.pi / (4.0 * self.centre_irradiance))

    def _probe(self, h: float):
        """(origins, directions) of the valid scene-side rays from the film point (h, 0)."""
        s = self.sampler(max(h, 1e-3) * 1.0001 if h > 0 else 1e-3, bands=1, grid=48)
        u = np.random.default_rng(7).random((3, PROBE_RAYS))
        n = PROBE_RAYS
        samples = s.sample(np.full(n, h), np.zeros(n), u[0], u[1], u[2],
                           np.full(n, WAVELENGTH_D_NM))
        res = self.learned.trace_from_sensor(samples.rays, self.sensor_z)
        ok = np.asarray(res.valid, bool) & (samples.weight > 0)
        if ok.sum() < 16:
            raise LensError(f"lens '{self.name}': too few rays from the film point {h:.3g} mm "
                            "pass the table lens to measure it", path=self.path)
        return res.rays.o[:, ok], res.rays.d[:, ok]

    @functools.cached_property
    def focus_mm(self) -> float:
        """The focus distance from the sensor (module docstring); inf at infinity."""
        o, d = self._probe(0.0)
        t = d[:2] / d[2]
        pp = float(np.sum(o[:2] * o[:2]))
        s = -float(np.sum(o[:2] * t)) / pp if pp > 0 else 0.0
        if not s > 0.0:                      # parallel, or diverging from a virtual point
            return math.inf
        return float(o[2].mean() + 1.0 / s - self.sensor_z)

    @functools.cached_property
    def efl_mm(self) -> float:
        """The focal length of the pinhole that frames alike (module docstring)."""
        h = FIELD_FRACTION * self.film_radius_mm
        _o, d = self._probe(h)
        m = d.mean(axis=1)
        tan = -m[0] / m[2]
        if not tan > 0:
            raise LensError(f"lens '{self.name}': the table lens does not form an inverted "
                            "image near the axis; it cannot frame a camera", path=self.path)
        return float(h / tan)

    @property
    def focal_length_mm(self) -> float:
        return self.efl_mm

    def _aimed(self, h: np.ndarray, ax: np.ndarray, ay: np.ndarray):
        """The model's result for rays from film points (h, 0) aimed at (ax, ay) on the
        sampling plane (arrays of one length)."""
        from ..core.aimed_rays import aimed_rays
        rays = aimed_rays(h, np.zeros(h.size), ax, ay, self.sensor_z, self.plane[0],
                          WAVELENGTH_D_NM)
        return self.learned.trace_from_sensor(rays, self.sensor_z)

    def chief_ray_table(self, film_radius_mm: float):
        """core.stmap.ChiefRayTable of the table lens out to `film_radius_mm` (at most the
        model's film radius), by its chief rays (module docstring), made once a radius;
        LensError where too few film points near the axis have a passing chief ray."""
        r_max = round(min(float(film_radius_mm), self.film_radius_mm), 9)
        cached = self._chief_tables.get(r_max)
        if cached is None:
            cached = self._chief_tables[r_max] = self._chief_ray_table(r_max)
        return cached

    def _chief_ray_table(self, r_max: float):
        from ..core.stmap import ChiefRayTable
        radii = np.linspace(0.0, r_max, CHIEF_RADII)[1:]
        half = self.plane[1]
        g = (np.arange(CHIEF_GRID) + 0.5) / CHIEF_GRID * 2.0 - 1.0
        gx, gy = (a.ravel() * half for a in np.meshgrid(g, g))
        aim = np.full(radii.size, np.nan)
        for k, h in enumerate(radii):
            res = self._aimed(np.full(gx.size, h), gx, gy)
            ok = np.asarray(res.valid, bool)
            if ok.any():
                aim[k] = float(gx[ok].mean())            # y's centroid is 0 by symmetry
        live = np.isfinite(aim)
        if live.sum() < 8:
            raise LensError(f"lens '{self.name}': too few film radii near the axis have a "
                            "passing ray in the table lens", path=self.path)
        res = self._aimed(radii[live], aim[live], np.zeros(int(live.sum())))
        ok = np.zeros(radii.size, bool)
        ok[live] = np.asarray(res.valid, bool)
        o = np.zeros((3, radii.size))
        d = np.zeros((3, radii.size))
        o[:, live], d[:, live] = res.rays.o, res.rays.d
        theta = np.arctan2(np.hypot(d[0], d[1]), d[2])
        ok &= d[0] < 0.0                      # the image is inverted: +x film looks to -x
        rising = np.concatenate([[True], np.diff(theta) > 0.0])
        end = np.flatnonzero(~(ok & rising))
        last = int(end[0]) if end.size else radii.size
        if last < 8:
            raise LensError(f"lens '{self.name}': too few film radii near the axis have a "
                            "passing chief ray in the table lens", path=self.path)
        r, theta, o, d = radii[:last], theta[:last], o[:, :last], d[:, :last]
        x = r / r[-1]
        smooth = _odd_poly(x, theta)
        theta = np.polyval(smooth, x)
        if np.any(np.diff(theta) <= 0.0):
            raise LensError(f"lens '{self.name}': the table lens's chief rays do not rise "
                            "with the film radius", path=self.path)
        # the scene-side line x = o_x + (z - o_z) d_x / d_z meets the axis at
        # z = o_z - o_x d_z / d_x, ill-conditioned near the axis (error ~ dtheta / theta^2):
        # a smooth fit in r^2, each row weighted by theta^2 (inverse variance)
        crossing = o[2] - o[0] * d[2] / d[0]
        q = x * x
        basis = np.stack([np.ones_like(q), q, q * q], axis=1)
        w = (theta / theta[-1]) ** 2
        coef = np.linalg.lstsq(basis * w[:, None], crossing * w, rcond=None)[0]
        axis_z = np.concatenate([[coef[0]], basis @ coef])
        # the fit's slope at the axis, d theta / dr = 1 / f: the paraxial limit
        slope = float(np.polyval(np.polyder(smooth), 0.0)) / r[-1]
        return ChiefRayTable(np.concatenate([[0.0], r]), np.concatenate([[0.0], theta]),
                             1.0 / slope, None, self.sensor_z, axis_z)


def _odd_poly(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """np.polyval coefficients of the least-squares odd polynomial y = a_1 x + a_3 x^3 + ...
    with as many terms as lower the RMS residual by more than ODD_FIT_GAIN each (at most
    ODD_FIT_TERMS): the smooth curve under the model's noise."""
    best, rms = None, math.inf
    for terms in range(1, ODD_FIT_TERMS + 1):
        a = np.stack([x ** (2 * k + 1) for k in range(terms)], axis=1)
        c = np.linalg.lstsq(a, y, rcond=None)[0]
        now = float(np.sqrt(np.mean((a @ c - y) ** 2)))
        if best is not None and now > (1.0 - ODD_FIT_GAIN) * rms:
            break
        coef = np.zeros(2 * terms + 1)
        coef[-2::-2] = c                    # x^1, x^3, ... from the lowest power up
        best, rms = coef, now
    return best


def _sampling_plane(grid: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    sensor_z: float) -> tuple[float, float]:
    """(z, half width) of the plane the table lens's rays are aimed at (module docstring),
    from its domain's occupancy over (r, u_r, u_t) in [lo, hi]."""
    shape = np.array(grid.shape)
    step = (hi - lo) / shape
    idx = np.argwhere(grid)
    if idx.size == 0:
        raise ModelError("the model's domain holds no ray")
    centre = lo + (idx + 0.5) * step
    r, ur, ut = centre[:, 0], centre[:, 1], centre[:, 2]
    w = np.sqrt(np.clip(1.0 - ur * ur - ut * ut, 1e-6, None))
    t = ur / w
    den = float(np.sum(t * t))
    p = -float(np.sum(r * t)) / den if den > 0 else 0.0
    # a plane behind the film (or on it) cannot be aimed at: at least the film's radius ahead
    p = max(p, float(hi[0]))
    corners = centre[:, None, :] + (np.array([[a, b, c] for a in (-0.5, 0.5)
                                              for b in (-0.5, 0.5) for c in (-0.5, 0.5)])
                                    * step)[None]
    cr, cu, cv = corners[..., 0], corners[..., 1], corners[..., 2]
    cw = np.sqrt(np.clip(1.0 - cu * cu - cv * cv, 1e-6, None))
    wide = float(max(np.abs(cr + p * cu / cw).max(), np.abs(p * cv / cw).max()))
    return sensor_z + p, PLANE_MARGIN * wide
