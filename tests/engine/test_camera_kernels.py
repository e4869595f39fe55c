"""The compiled camera samples (engine.camera_kernels) against the numpy generator
(camera_rays.CameraRayGenerator.generate without its tables): the same film points, wavelengths,
colour weights, sensor rays, validity, illumination and world rays, for a lens of revolution
(RearPupilSampler's grids) and an anamorphic one (the rear disc), with three colour rays, one
from the whole sensor and without dispersion, a shifted film and a rotated, scaled, moved
camera; pixels at the frame's corners and samples far into the sequence included."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from neurolens_addon.camera.lenses import PRESETS_DIR  # noqa: E402
from neurolens_addon.camera.resolve import resolve_camera  # noqa: E402
from neurolens_addon.camera.settings import CameraSettings, GhostSettings  # noqa: E402
from neurolens_addon.core import pupil  # noqa: E402
from neurolens_addon.core.film import FilmSettings  # noqa: E402
from neurolens_addon.engine import camera_kernels, camera_rays  # noqa: E402

FILM = FilmSettings(sensor_width=36.0, sensor_height=24.0, resolution_x=64, resolution_y=40,
                    shift_x=0.05, shift_y=-0.03)


def _matrix():
    """A camera turned 30 degrees about z and 20 about x, scaled by 2 and moved."""
    a, b = np.radians(30.0), np.radians(20.0)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    m = np.eye(4)
    m[:3, :3] = 2.0 * rz @ rx
    m[:3, 3] = (1.0, -2.0, 0.5)
    return m


@pytest.fixture(autouse=True)
def small_sampler(monkeypatch):
    """Coarse sampler grids (their size does not change what is compared)."""
    monkeypatch.setattr(pupil, "SAMPLER_BANDS", 6)
    monkeypatch.setattr(pupil, "SAMPLER_GRID", 24)
    monkeypatch.setattr(pupil, "SAMPLER_COARSE_GRID", 24)


CASES = [("double_gauss_50mm_f2", True, 3), ("double_gauss_50mm_f2", True, 1),
         ("double_gauss_50mm_f2", False, 1), ("fisheye_16mm_f2_8_diagonal", True, 1)]
ANAMORPHIC = "anamorphic_2x_60mm_f1_9"


def _generator(name, dispersion, colour_rays):
    setup = resolve_camera(CameraSettings(
        camera="cam", lens_path=str(PRESETS_DIR / f"{name}.toml"), model="exact",
        f_number=2.8, focus_distance_mm=3000.0, dispersion=dispersion, film=FILM))
    return camera_rays.CameraRayGenerator(
        camera_rays.make_evaluator(setup.derived), _matrix(), 1000.0, seed=7,
        dispersion=dispersion, colour_rays=colour_rays)


def _pixels():
    rng = np.random.default_rng(4)
    n = FILM.resolution_x * FILM.resolution_y
    pixel = np.concatenate([[0, FILM.resolution_x - 1, n - FILM.resolution_x, n - 1],
                            rng.integers(0, n, 3000)])
    sample = np.concatenate([[0, 1, 255, 100000], rng.integers(0, 4096, 3000)])
    return pixel.astype(np.int64), sample.astype(np.int64)


def _compare(gen):
    assert gen._tables is not None, "the compiled path is in use"
    pixel, sample = _pixels()
    fast = gen.generate(pixel, sample)
    tables, gen._tables = gen._tables, None
    try:
        ref = gen.generate(pixel, sample)
    finally:
        gen._tables = tables
    for field in ("pixel", "sample", "valid", "index"):
        np.testing.assert_array_equal(getattr(fast, field), getattr(ref, field), err_msg=field)
    assert (fast.source is None) == (ref.source is None)
    if ref.source is not None:
        np.testing.assert_array_equal(fast.source, ref.source)
    assert fast.share == ref.share
    for field in ("weight", "illumination", "origin", "direction"):
        np.testing.assert_allclose(getattr(fast, field), getattr(ref, field), rtol=1e-9,
                                   atol=1e-12, err_msg=field)
    # a good share passes the lens (the world rays compared are not a handful)
    assert ref.valid.mean() > 0.1
    return ref


@pytest.mark.parametrize("name,dispersion,colour_rays", CASES)
def test_camera_samples_equal_the_numpy_generator(name, dispersion, colour_rays):
    ref = _compare(_generator(name, dispersion, colour_rays))
    if dispersion and colour_rays == 1:        # weights from the whole sensor: not all white
        assert np.ptp(ref.weight[ref.valid], axis=0).max() > 0.5


def test_anamorphic_camera_samples_equal_the_numpy_generator():
    """An anamorphic lens: rays aimed over the rear disc, the film desqueezed."""
    gen = _generator(ANAMORPHIC, True, 3)
    assert gen._tables.kind == camera_kernels.REAR_DISC and gen.camera.squeeze != 1.0
    _compare(gen)


def test_the_sensor_rays_equal_the_uniforms_and_sampler_of_the_reference():
    """The sensor-side rays themselves (before the lens), row for row, against
    camera_uniforms, the film, sensor_response and the sampler called directly."""
    gen = _generator("double_gauss_50mm_f2", True, 1)
    pixel, sample = _pixels()
    o, d, lam, w, spectral = gen._tables.sensor_rays(pixel, sample)
    u = camera_rays.camera_uniforms(gen.seed, pixel, sample)
    iy, ix = np.divmod(pixel, FILM.resolution_x)
    p, q = gen.film.image_points(ix, iy, u["jitter"][0], u["jitter"][1])
    lam_ref, spectral_ref = camera_rays.sensor_response().sample_sensor(u["wavelength"])
    s = gen.sampler.sample(-p, -q, *u["aperture"], lam_ref)
    np.testing.assert_allclose(lam, lam_ref, rtol=1e-12)
    np.testing.assert_allclose(spectral, spectral_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(o, s.rays.o, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(d, s.rays.d, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(w, s.weight, rtol=1e-9)


def test_ghosts_keep_the_numpy_path():
    """Ghost samples follow their ghosts in the exact lens (numpy): a camera with ghosts makes
    no tables, and its image samples are still those of the compiled path's camera."""
    path = str(PRESETS_DIR / "double_gauss_50mm_f2.toml")
    settings = CameraSettings(camera="cam", lens_path=path, model="exact", f_number=2.8,
                              focus_distance_mm=3000.0, film=FILM,
                              ghosts=GhostSettings(enabled=True, count=2))
    gen = camera_rays.CameraRayGenerator(
        camera_rays.make_evaluator(resolve_camera(settings).derived), np.eye(4))
    assert gen.ghosts is not None and gen._tables is None
    pixel, sample = _pixels()
    out = gen.generate(pixel, sample)
    assert out.valid.any() and np.isfinite(out.weight).all()
