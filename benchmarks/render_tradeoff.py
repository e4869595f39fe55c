"""Rendered images at equal time against an exact-lens reference (issue 6 figures).

The shipped demo scene (presets/scenes/demo.blend) through the 50 mm double Gauss at f/2,
focus 1.6 m, rendered headless by the NEUROLENS engine (`python -m neurolens_addon.render`):
  reference   the exact lens at REF_SPP samples per pixel (seed 1);
  each model  (exact, the shipped NeuroLens model, its lean variant, the polynomial baseline)
              rendered with the samples it affords in the time the exact lens takes for
              BUDGET_SPP samples (seed 2). A model's time per sample and fixed cost come from
              two calibration renders (CAL_SPP[0] and CAL_SPP[1] samples; the render time the
              command prints, start-up excluded).
Figures: SSIM (luminance clipped to [0, 1], Gaussian window sigma 1.5) and RMSE of the
Combined pass against the reference. A model's bias (e.g. rays it passes that the real lens
vignettes) shows as error that more samples do not remove; noise as error that they do.
Blender's thin lens is not in this table: it renders another lens (its departure from the
real one is in the speed-accuracy table).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from .common import ROOT, md_table

SCENE = ROOT / "presets" / "scenes" / "demo.blend"
LENS = "double_gauss_50mm_f2"
RES = "160x90"
REF_SPP = 128
BUDGET_SPP = 16
CAL_SPP = (4, 12)
TIME_RE = re.compile(r", ([0-9.]+) s( \||$)", re.M)


def _models():
    out = [("exact", "exact"), ("neurolens", "learned")]
    lean = ROOT / "presets" / "models" / f"{LENS}.lean.neurolens"
    if lean.exists():
        out.append(("neurolens lean", str(lean)))
    poly = ROOT / "build" / "bench-models" / f"{LENS}.poly.neurolens"
    if (poly / "model.json").exists():
        out.append(("polynomial", str(poly)))
    return out


def render(model: str, spp: int, seed: int, out: Path) -> float:
    """Render with the CLI; returns the render time it reports (seconds)."""
    cmd = [sys.executable, "-m", "neurolens_addon.render", str(SCENE), "--lens", LENS,
           "--model", model, "--focus", "1.6", "--fstop", "2", "--samples", str(spp),
           "--seed", str(seed), "--resolution", RES, "--engine", "neurolens", "--quiet",
           "--out", str(out)]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    if p.returncode != 0:
        raise RuntimeError(f"render failed: {p.stderr[-400:]}")
    m = TIME_RE.search(p.stdout + p.stderr)
    if m is None:
        raise RuntimeError(f"no render time in the output: {(p.stdout + p.stderr)[-300:]}")
    return float(m.group(1))


def combined(path: Path) -> np.ndarray:
    import OpenEXR
    with OpenEXR.File(str(path)) as f:
        chans = {}
        for part in f.parts:
            for name, ch in part.channels.items():
                chans[name] = np.array(ch.pixels, dtype=np.float64)
    key = next(k for k in chans if k.endswith("Combined") or k.endswith("Combined.R")
               or k == "RGBA" or k.endswith("RGBA"))
    px = chans[key]
    if px.ndim == 3:
        return px[..., :3]
    base = key.rsplit(".", 1)[0]
    return np.stack([chans[f"{base}.{c}"] for c in "RGB"], axis=-1)


def _blur(a: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    r = int(3 * sigma)
    x = np.arange(-r, r + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    a = np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode="reflect"), k, "valid"), 0, a)
    return np.apply_along_axis(lambda v: np.convolve(np.pad(v, r, mode="reflect"), k, "valid"), 1, a)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of two luminance images in [0, 1] (Wang et al. 2004, K1 0.01, K2 0.03)."""
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ma, mb = _blur(a), _blur(b)
    va, vb = _blur(a * a) - ma * ma, _blur(b * b) - mb * mb
    cov = _blur(a * b) - ma * mb
    s = ((2 * ma * mb + c1) * (2 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
    return float(s.mean())


def luminance(rgb: np.ndarray) -> np.ndarray:
    return np.clip(rgb @ np.array([0.2126, 0.7152, 0.0722]), 0.0, 1.0)


def run() -> tuple[str, dict]:
    figs = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t_ref = render("exact", REF_SPP, 1, tmp / "ref.exr")
        ref = combined(tmp / "ref.exr")
        cal = {}
        for label, model in _models():
            t0 = render(model, CAL_SPP[0], 3, tmp / "c0.exr")
            t1 = render(model, CAL_SPP[1], 3, tmp / "c1.exr")
            per = max((t1 - t0) / (CAL_SPP[1] - CAL_SPP[0]), 1e-6)
            cal[label] = (model, per, max(t0 - per * CAL_SPP[0], 0.0))
        budget = cal["exact"][2] + cal["exact"][1] * BUDGET_SPP
        rows = []
        for label, (model, per, fixed) in cal.items():
            spp = max(1, int(round((budget - fixed) / per)))
            t = render(model, spp, 2, tmp / f"{label}.exr".replace(" ", "_"))
            img = combined(tmp / f"{label}.exr".replace(" ", "_"))
            s = ssim(luminance(img), luminance(ref))
            rmse = float(np.sqrt(np.mean((img - ref) ** 2)))
            figs[label] = {"samples": spp, "seconds": t, "ms_per_sample_pass": 1000 * per,
                           "ssim": s, "rmse": rmse}
            rows.append([label, spp, f"{t:.1f}", f"{1000 * per:.0f}", f"{s:.4f}", f"{rmse:.4f}"])
            print(f"  {label}: {spp} spp in {t:.1f} s, SSIM {s:.4f}, RMSE {rmse:.4f}", flush=True)
    text = "\n".join([
        "## Rendered images at equal time (NEUROLENS engine, demo scene)",
        "",
        f"{LENS} at f/2, focus 1.6 m, {RES}; reference: exact lens, {REF_SPP} spp "
        f"({t_ref:.0f} s). Each model gets the time the exact lens needs for {BUDGET_SPP} spp. "
        "SSIM and RMSE of the Combined pass against the reference.",
        "",
        md_table(["model", "samples", "render s", "ms per sample pass", "SSIM", "RMSE"], rows)])
    return text, {"reference_seconds": t_ref, "models": figs}
