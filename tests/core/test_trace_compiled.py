"""The compiled exact trace (core.trace_compiled, numba) against the numpy reference
(core.trace_kernel), the switch between them, and where numba's kernel cache goes.

Agreement, on the same rays through both (trace(..., kernels="compiled" / "numpy")):
- validity identical but for at most EDGE_RAYS_PER_10K rays in 10 000 (a ray within rounding
  of a clipping edge: a semi-diameter, the stop, a total-internal-reflection limit, may be kept
  by one and clipped by the other; the trace's products are evaluated in another order in
  places and the asphere's Newton iteration stops per ray);
- where both keep a ray, positions and directions within ATOL_MM (1e-9 mm), wavelengths and
  (with a coating) weights equal (to 1e-12 relative);
- where neither keeps it, the same status and surface.
Rays: from the sensor (film points towards the exit pupil, a little beyond it) and from the
scene (camera rays turned round, and points in front aimed over the front element, some from
a kilometre away), wavelengths
per ray over 380-780 nm and single wavelengths, the design's stop and smaller ones, the circle
(built in, and as CircularAperture), a bladed iris and an image mask; every preset, and a lens
of every registered surface kind (tests/core/test_surfaces.SAMPLES).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba")

from neurolens_addon.core import jit  # noqa: E402
from neurolens_addon.core.aperture import (CircularAperture, ImageMaskAperture,  # noqa: E402
                                           PolygonAperture)
from neurolens_addon.core.coatings import Coating  # noqa: E402
from neurolens_addon.core.field import design_film_radius_mm  # noqa: E402
from neurolens_addon.core.ghosts import all_ghosts  # noqa: E402
from neurolens_addon.core.lensfile import load_lens  # noqa: E402
from neurolens_addon.core.paraxial import paraxial_data  # noqa: E402
from neurolens_addon.core.rays import Rays, RayStatus  # noqa: E402
from neurolens_addon.core.trace import trace  # noqa: E402
from tests.core.test_surfaces import SHAPES, IDS, lens_with  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PRESETS = sorted((ROOT / "presets" / "lenses").glob("*.toml"))
ATOL_MM = 1e-9
EDGE_RAYS_PER_10K = 1
N = 4000


def mask_aperture():
    """A ring with a bar across it, 64 x 64 pixels."""
    y, x = np.mgrid[-1:1:64j, -1:1:64j]
    r = np.hypot(x, y)
    m = ((r < 0.95) & (r > 0.3)) | (np.abs(y) < 0.1)
    return ImageMaskAperture(m.astype(float))


APERTURES = [("circle", None, 1.0), ("circle-small", None, 0.45),
             ("circle-shape", CircularAperture(), 0.7),
             ("iris", PolygonAperture(6, 12.0, 0.3), 0.8), ("mask", mask_aperture(), 1.0)]


def assert_same(a, b, n):
    """a (compiled) agrees with b (numpy): the module docstring's terms."""
    differ = a.valid != b.valid
    assert differ.sum() <= EDGE_RAYS_PER_10K * max(1, n // 10000), \
        f"{differ.sum()} of {n} rays valid in one trace only"
    both = a.valid & b.valid
    assert both.any() or not b.valid.any()
    np.testing.assert_allclose(a.rays.o[:, both], b.rays.o[:, both], rtol=0, atol=ATOL_MM)
    np.testing.assert_allclose(a.rays.d[:, both], b.rays.d[:, both], rtol=0, atol=ATOL_MM)
    np.testing.assert_array_equal(a.rays.wavelength[~differ], b.rays.wavelength[~differ])
    neither = ~a.valid & ~b.valid
    np.testing.assert_array_equal(a.status[neither], b.status[neither])
    np.testing.assert_array_equal(a.surface[neither], b.surface[neither])
    assert (a.status[a.valid] == 0).all() and (a.surface[a.valid] == -1).all()
    for r in (a, b):       # invalid rays carry zeros, never NaN
        assert np.isfinite(r.rays.o).all() and np.isfinite(r.rays.d).all()
        assert not r.rays.o[:, ~r.valid].any() and not r.rays.wavelength[~r.valid].any()
    if b.weight is not None:
        np.testing.assert_allclose(a.weight[~differ], b.weight[~differ], rtol=1e-12, atol=0)


def both(lens, rays, **kw):
    return (trace(lens, rays, kernels="compiled", **kw),
            trace(lens, rays, kernels="numpy", **kw))


def wavelengths(rng, n, kind):
    return rng.uniform(380.0, 780.0, n) if kind == "mixed" else np.full(n, float(kind))


def sensor_rays(lens, n, rng, wl="mixed"):
    """Film points over the image circle aimed at uniform points of a disc 1.3 times the exit
    pupil's (paraxial) radius in its plane (or the rear vertex's, where the pupil lies behind
    the film): most pass, many are clipped."""
    xp = paraxial_data(lens).exit_pupil
    z = xp.z_mm if xp.z_mm > 1.0 else float(lens.vertex_z[-1])
    r = design_film_radius_mm(lens) * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    rp = 0.65 * xp.diameter_mm * np.sqrt(rng.random(n))
    phip = 2 * np.pi * rng.random(n)
    o = np.vstack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)])
    d = np.vstack([rp * np.cos(phip), rp * np.sin(phip), np.full(n, z)]) - o
    return Rays(o, d / np.linalg.norm(d, axis=0), wavelengths(rng, n, wl))


def scene_rays(lens, n, rng, wl="mixed"):
    """Half: camera rays that leave the lens (numpy trace), turned round and started again
    up to 1 km out, a little off their line; half: points in front of the lens aimed over and
    a little beyond the front element."""
    out = trace(lens, sensor_rays(lens, 2 * n, rng), kernels="numpy")
    k = np.flatnonzero(out.valid)[:n // 2]
    back = -out.rays.d[:, k] + rng.normal(0.0, 0.01, (3, k.size))
    back /= np.linalg.norm(back, axis=0)
    far = np.where(rng.random(k.size) < 0.2, 1e6, rng.uniform(1.0, 200.0, k.size))
    o1 = out.rays.o[:, k] - far * back
    m = n - k.size
    front = lens.surfaces[0].semi_diameter_mm
    z0 = float(lens.vertex_z[0])
    dist = np.where(rng.random(m) < 0.1, 1e6, rng.uniform(5.0, 300.0, m))
    o2 = np.vstack([rng.uniform(-1, 1, (2, m)) * dist * 0.3, z0 + dist])
    aim = np.vstack([rng.uniform(-1.1, 1.1, (2, m)) * front, np.full(m, z0)])
    d2 = (aim - o2) / np.linalg.norm(aim - o2, axis=0)
    return Rays(np.hstack([o1, o2]), np.hstack([back, d2]), wavelengths(rng, n, wl))


@pytest.mark.parametrize("path", PRESETS, ids=[p.stem for p in PRESETS])
def test_01_every_preset_from_the_sensor_and_the_scene(path):
    """Every preset, both directions, every aperture of APERTURES, wavelengths per ray and one
    single wavelength: the compiled trace gives the numpy trace's result."""
    lens = load_lens(path)
    rng = np.random.default_rng(sum(path.stem.encode()))
    passed = {True: 0, False: 0}
    for k, (label, aperture, scale) in enumerate(APERTURES):
        wl = "mixed" if k != 2 else "486.1327"
        stop = lens.stop_radius_mm * scale
        for from_sensor in (True, False):
            rays = (sensor_rays if from_sensor else scene_rays)(lens, N, rng, wl)
            a, b = both(lens, rays, from_sensor=from_sensor, stop_radius=stop,
                        aperture=aperture)
            passed[from_sensor] += int(b.valid.sum())
            assert_same(a, b, N)
    assert min(passed.values()) > 100          # rays do get through, both ways


@pytest.mark.parametrize("shape", SHAPES, ids=IDS)
def test_02_every_surface_kind(shape):
    """A lens of each registered kind (sphere, plane, conics, aspheres, biconics, cylinders,
    toroids, turned): the surface and the one behind it (surfaces=(1, 3), so that no stop
    shields it), rays from 5 mm in front of it, many of them steep (clipping; by the shape:
    misses, total internal reflection, Newton failures), at three wavelengths; and the whole
    lens from the sensor."""
    lens = lens_with(shape)
    rng = np.random.default_rng(7)
    for wl in ("mixed", "435.8343", "656.2725"):
        n = 3000
        o = np.vstack([rng.uniform(-9, 9, (2, n)), np.full(n, lens.vertex_z[1] + 5.0)])
        d = np.vstack([rng.normal(0, 0.8, (2, n)), -np.ones(n)])
        rays = Rays(o, d / np.linalg.norm(d, axis=0), wavelengths(rng, n, wl))
        a, b = both(lens, rays, from_sensor=False, surfaces=(1, 3), sensor_z=None)
        assert b.valid.any() and not b.valid.all()
        assert_same(a, b, n)
        back = Rays(np.vstack([rng.uniform(-3, 3, (2, n)), np.zeros(n)]),
                    rays.d * np.array([[1.0], [1.0], [-1.0]]), rays.wavelength)
        assert_same(*both(lens, back), n)


def test_03_bad_rays_are_flagged_as_the_numpy_trace_flags_them():
    """NaN and inf components, zero and backwards directions, NaN, negative and absurd
    wavelengths: the same statuses (BAD_INPUT, BAD_WAVELENGTH, ...) and no NaN out."""
    lens = load_lens(PRESETS[[p.stem for p in PRESETS].index("double_gauss_50mm_f2")])
    rng = np.random.default_rng(3)
    good = sensor_rays(lens, 12, rng)
    o, d, wl = good.o.copy(), good.d.copy(), good.wavelength.copy()
    o[0, 0] = np.nan
    o[2, 1] = np.inf
    d[1, 2] = -np.inf
    d[:, 3] = 0.0
    d[2, 4] = -abs(d[2, 4])                 # travelling away from the lens
    wl[5] = np.nan
    wl[6] = -500.0
    wl[7] = np.inf
    d[:, 8] *= 1e-200                      # tiny but fine once normalised
    d[:, 9] *= 1e200
    for from_sensor in (True, False):
        rays = Rays(o, d if from_sensor else -d, wl)
        a, b = both(lens, rays, from_sensor=from_sensor)
        np.testing.assert_array_equal(a.valid, b.valid)
        np.testing.assert_array_equal(a.status, b.status)
        np.testing.assert_array_equal(a.surface, b.surface)
        assert_same(a, b, 12)
        assert not a.valid[:8].any()
        if from_sensor:
            assert (a.status[:5] == RayStatus.BAD_INPUT).all()
            assert (a.status[5:8] == RayStatus.BAD_WAVELENGTH).all()


def test_04_ghosts_with_coatings_and_shaped_stops():
    """Ghost paths (reflecting twice, crossing the stop one or three times) with their coating
    weights, bare, single-layer, multi-layer and tabulated coatings, circle and iris stops."""
    lens = load_lens(ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml")
    rng = np.random.default_rng(11)
    ghosts = all_ghosts(lens)
    coatings = [Coating("bare"), Coating("single"), Coating("multi"),
                Coating("table", table_nm=(400.0, 550.0, 700.0), table_r=(0.02, 0.005, 0.03))]
    picked = [ghosts[i] for i in rng.choice(len(ghosts), 8, replace=False)]
    three = [g for g in ghosts if g.a < 5 < g.b][:2]     # the stop (surface 5) between them
    for k, ghost in enumerate(picked + three):
        rays = sensor_rays(lens, N, rng)
        aperture = PolygonAperture(5, 0.0, 0.0) if k % 2 else None
        a, b = both(lens, rays, ghost=ghost, coating=coatings[k % 4], aperture=aperture,
                    stop_radius=lens.stop_radius_mm * 0.8)
        assert_same(a, b, N)
    image_a, image_b = both(lens, sensor_rays(lens, N, rng), coating=coatings[2])
    assert_same(image_a, image_b, N)
    assert 0.5 < image_a.weight[image_a.valid].mean() < 1.0


def test_05_lens_groups_and_no_sensor_plane():
    """surfaces=(lo, hi) (the trainer's two stages) and sensor_z=None."""
    lens = load_lens(ROOT / "presets" / "lenses" / "aspheric_50mm_f1_2.toml")
    stop = next(i for i, s in enumerate(lens.surfaces) if s.stop)
    rng = np.random.default_rng(5)
    rays = sensor_rays(lens, N, rng)
    assert_same(*both(lens, rays, surfaces=(stop, len(lens.surfaces))), N)
    front = scene_rays(lens, N, rng)
    assert_same(*both(lens, front, from_sensor=False, surfaces=(0, stop), sensor_z=None), N)
    assert_same(*both(lens, front, from_sensor=False, sensor_z=None), N)


def test_06_threads_and_calls_do_not_change_the_result():
    """One thread or all, one call or two halves: the same bits."""
    lens = load_lens(ROOT / "presets" / "lenses" / "zoom_70_200mm_f2_8.toml")
    rays = sensor_rays(lens, 150_000, np.random.default_rng(2))
    one = trace(lens, rays, kernels="compiled", threads=1)
    every = trace(lens, rays, kernels="compiled")
    np.testing.assert_array_equal(one.rays.o, every.rays.o)
    np.testing.assert_array_equal(one.rays.d, every.rays.d)
    np.testing.assert_array_equal(one.status, every.status)
    half = Rays(rays.o[:, :70_000], rays.d[:, :70_000], rays.wavelength[:70_000])
    np.testing.assert_array_equal(trace(lens, half, kernels="compiled").rays.o,
                                  every.rays.o[:, :70_000])


def _python(code: str, env_changes: dict, timeout=600):
    env = {k: v for k, v in os.environ.items()
           if k not in ("NEUROLENS_KERNELS", "NUMBA_CACHE_DIR", "NEUROLENS_CACHE_DIR")}
    env.update(env_changes)
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


TRACE_ONE = """
import sys, numpy as np
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.trace import trace
lens = load_lens('presets/lenses/double_gauss_50mm_f2.toml')
n = 1000
o = np.zeros((3, n)); o[0] = np.linspace(-5, 5, n); o[2] = lens.vertex_z[0] + 10.0
d = np.zeros((3, n)); d[2] = -1.0
res = trace(lens, Rays(o, d, np.full(n, 550.0)), from_sensor=False)
print(res.valid.sum(), 'neurolens_addon.core.trace_compiled' in sys.modules)
"""


def test_07_the_switch_and_the_fall_back_without_numba():
    """NEUROLENS_KERNELS=numpy never loads the compiled trace; by default it runs; where numba
    does not import, the numpy trace runs and asking for "compiled" is an error."""
    off = _python(TRACE_ONE, {"NEUROLENS_KERNELS": "numpy"}).split()
    on = _python(TRACE_ONE, {}).split()
    assert off == [on[0], "False"] and on[1] == "True" and int(on[0]) > 0
    blocked = """
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] == 'numba':
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
""" + TRACE_ONE + """
from neurolens_addon.core import jit
assert not jit.available() and jit.mode() == 'numpy'
try:
    trace(lens, Rays(o, d, np.full(n, 550.0)), kernels='compiled')
except RuntimeError as exc:
    print('refused')
"""
    out = _python(blocked, {}).split()
    assert out == [on[0], "False", "refused"]
    with pytest.raises(ValueError, match="kernels"):
        jit.mode("fast")


def test_08_the_kernel_cache_is_in_the_user_cache_folder(tmp_path):
    """With no cache folder set, the kernels are cached under $XDG_CACHE_HOME/neurolens/numba
    (loaded from there when warm, compiled and written there when not), and the add-on's
    package folder gains no file."""
    package = ROOT / "neurolens_addon"

    def files():
        return {str(p.relative_to(package)): p.stat().st_mtime_ns
                for p in package.rglob("*") if p.is_file()}

    cache = tmp_path / "neurolens" / "numba"
    warm = jit.cache_dir()
    if warm.is_dir():
        shutil.copytree(warm, cache)
    before = files()
    code = TRACE_ONE + """
from neurolens_addon.core import trace_compiled as tc
print(tc.trace_chunk.stats.cache_path)
"""
    out = _python(code, {"XDG_CACHE_HOME": str(tmp_path), "PYTHONDONTWRITEBYTECODE": "1"})
    cache_path = Path(out.split()[-1])
    assert cache_path.is_relative_to(cache)
    written = sorted(p.name for p in cache_path.iterdir())
    assert any(n.startswith("trace_compiled.trace_chunk") and n.endswith(".nbi")
               for n in written)
    assert files() == before
    assert not [p for p in package.rglob("*") if p.suffix in (".nbi", ".nbc")]


def test_09_the_cache_folder_follows_the_platform_and_the_settings(monkeypatch, tmp_path):
    """NEUROLENS_CACHE_DIR, then the platform's user cache: never inside the add-on."""
    monkeypatch.setenv("NEUROLENS_CACHE_DIR", str(tmp_path))
    assert jit.default_cache_dir() == tmp_path / "numba"
    monkeypatch.delenv("NEUROLENS_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    if sys.platform.startswith("linux"):
        assert jit.default_cache_dir() == tmp_path / "xdg" / "neurolens" / "numba"
    assert not jit.default_cache_dir().is_relative_to(ROOT / "neurolens_addon")
    assert not jit.cache_dir().is_relative_to(ROOT / "neurolens_addon")
