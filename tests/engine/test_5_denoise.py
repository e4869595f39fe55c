"""Open Image Denoise on the engine's frame: the real OIDN (pyoidn), guided by albedo and
normal; the noisy frame kept; nothing lost when the denoiser is missing."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.slow          # engine renders
pytest.importorskip("pyoidn")

from neurolens_addon.engine import denoise as dn  # noqa: E402
from testdata import engine_scenes as scenes  # noqa: E402


def test_01_oidn_removes_most_of_the_noise_of_an_image():
    """A smooth HDR image times exponential noise (a 1-sample estimate): OIDN guided by a flat
    albedo and normal brings the RMSE down at least five-fold; NaN input is refused."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:64, 0:96] / 64.0
    clean = np.stack([0.5 + 0.4 * np.sin(6 * x) * (y > 0.5), 0.3 + 0.2 * x, 0.2 + 0 * y],
                     -1).astype(np.float32)
    noisy = clean * rng.exponential(1.0, clean.shape[:2])[..., None].astype(np.float32)
    normal = np.dstack([np.zeros((64, 96)), np.zeros((64, 96)), np.ones((64, 96))])
    out = dn.denoise(noisy, np.full_like(clean, 0.8), normal)
    rmse = lambda a: float(np.sqrt(((a - clean) ** 2).mean()))  # noqa: E731
    assert out.shape == clean.shape and np.isfinite(out).all()
    assert rmse(out) < rmse(noisy) / 5
    bad = noisy.copy()
    bad[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        dn.denoise(bad)


def test_02_the_engine_denoises_and_keeps_the_noisy_frame(tmp_path):
    """At 4 samples: Noisy Image is exactly the frame rendered without denoising (same seed),
    the denoised Combined is at least twice as close to a 64-sample reference as the noisy
    one, alpha is untouched, and the guide passes hold the first hits' albedo and normal; the
    summary line names the denoiser only for the denoised frame."""
    from neurolens_addon.blender.render_engine import LAST
    scenes.sphere_on_plane()
    ref = scenes.render(tmp_path / "ref.exr", 48, 32, 64, denoise=False)
    raw = scenes.render(tmp_path / "raw.exr", 48, 32, 4, denoise=False)
    assert "denoised" not in LAST["stats"].summary()
    den = scenes.render(tmp_path / "den.exr", 48, 32, 4, denoise=True)
    assert "| denoised (Open Image Denoise, " in LAST["stats"].summary()
    rgb = lambda ch, p="Combined": np.stack([ch[f"{p}.{k}"] for k in "RGB"], -1)  # noqa: E731
    np.testing.assert_array_equal(rgb(den, "Noisy Image"), rgb(raw))
    np.testing.assert_array_equal(den["Combined.A"], raw["Combined.A"])
    err = lambda a: float(np.sqrt(((a - rgb(ref)) ** 2).mean()))  # noqa: E731
    assert err(rgb(den)) < 0.5 * err(rgb(raw)), (err(rgb(den)), err(rgb(raw)))
    albedo = rgb(den, "Denoising Albedo")
    assert albedo.min() >= 0.0 and albedo.max() <= 1.0 and albedo[..., 0].max() > 0.7
    n = np.stack([den[f"Denoising Normal.{k}"] for k in "XYZ"], -1)
    assert np.abs(np.linalg.norm(n, axis=-1) - 1.0)[16, 4] < 0.05     # the floor, unit


def test_03_without_the_denoiser_the_frame_stays_noisy_and_says_so(tmp_path, monkeypatch):
    """When OIDN cannot load, the render keeps the noisy frame in Combined and notes why (and
    the summary line does not claim a denoiser)."""
    from neurolens_addon.blender.render_engine import LAST

    def missing():
        raise dn.DenoiserUnavailable("the pyoidn package (Open Image Denoise) is not usable "
                                     "here (simulated)")
    monkeypatch.setattr(dn, "_oidn", missing)
    scenes.sphere_on_plane()
    ch = scenes.render(tmp_path / "n.exr", 24, 16, 2, denoise=True)
    for k in "RGB":
        np.testing.assert_array_equal(ch[f"Combined.{k}"], ch[f"Noisy Image.{k}"])
    assert any("Not denoised" in n for n in LAST["stats"].notes)
    assert "denoised (" not in LAST["stats"].summary()
