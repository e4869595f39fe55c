"""Rendered images at equal time against an exact-lens reference (issue 6 figures).

The shipped demo scene (presets/scenes/demo.blend) through every preset at its design
f-number (a zoom at its first tabulated focal length, where its preset models and the
polynomial baseline were trained), focused at 1.6 m (or 1.3 x the lens's closest focus when
that is farther; a lens with focusing groups at its tabulated close distance nearest 1.6 m,
where its position model renders), rendered headless by the NEUROLENS engine (`python -m neurolens_addon.render`):
  reference   the exact lens at REF_SPP samples per pixel (seed 1);
  each model  (exact, the shipped NeuroLens model and its variants, the polynomial baseline
              from the speed-accuracy section's build/bench-models) rendered with the samples
              it affords in the time the exact lens takes for BUDGET_SPP samples (seed 2). A model's time per sample and fixed cost come from
              two calibration renders (CAL_SPP[0] and CAL_SPP[1] samples; the render time the
              command prints, start-up excluded).
Figures: SSIM (luminance clipped to [0, 1], Gaussian window sigma 1.5) and RMSE of the
Combined pass against the reference. A model's bias (e.g. rays it passes that the real lens
vignettes) shows as error that more samples do not remove; noise as error that they do.
Blender's thin lens is not in this table: it renders another lens (its departure from the
real one is in the speed-accuracy table).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np

from .common import (ROOT, LensRecords, cli_render_seconds, is_position_model, md_table,
                     measured_inputs)

SCENE = ROOT / "presets" / "scenes" / "demo.blend"
RES = "128x72"
REF_SPP = 64
BUDGET_SPP = 8
CAL_SPP = (2, 6)


def _models(lens: str):
    out = [("exact", "exact"), ("neurolens", "learned")]
    for p in sorted((ROOT / "presets" / "models").glob(f"{lens}.*.neurolens")):
        if is_position_model(p.name):        # another lens (a zoom or focus position)
            continue
        out.append((f"neurolens {p.name[len(lens) + 1:-len('.neurolens')]}", str(p)))
    poly = ROOT / "build" / "bench-models" / f"{lens}.poly.neurolens"
    if (poly / "model.json").exists() and not _has_focus_groups(lens):
        out.append(("polynomial", str(poly)))
    return out


def _has_focus_groups(stem: str) -> bool:
    from neurolens_addon.core.lensfile import load_lens
    return load_lens(ROOT / "presets" / "lenses" / f"{stem}.toml").focus_gaps is not None


def _focus_m(lens_path: Path) -> float:
    """1.6 m (1.3 x the closest focus when farther); for a lens with focusing groups the
    tabulated close distance nearest 1.6 m, where its position model renders (elsewhere the
    camera gives a learned lens way to the exact trace: camera.resolve)."""
    from neurolens_addon.core.focus import closest_focus_mm
    from neurolens_addon.core.lensfile import load_lens
    lens = load_lens(lens_path)
    if lens.focus_gaps is not None:
        close = [d for d in lens.focus_gaps.positions if math.isfinite(d)]
        return min(close, key=lambda d: abs(math.log(d / 1600.0))) / 1000.0
    return max(1.6, 1.3 * closest_focus_mm(lens) / 1000.0)


def _zoom_mm(lens_path: Path) -> float | None:
    """A zoom's first tabulated focal length, where its preset models (STEM.neurolens,
    STEM.sparse.neurolens) and the polynomial baseline were trained (else Blender's 50 mm
    clamps to its long end, and those models give way to the exact trace); None for a prime."""
    from neurolens_addon.core.lensfile import load_lens
    zoom = load_lens(lens_path).zoom_gaps
    return None if zoom is None else float(zoom.positions[0])


def render(lens: str, focus: float, fstop: float, model: str, spp: int, seed: int,
           out: Path, zoom_mm: float | None = None) -> float:
    """Render with the CLI; returns the render time it reports (seconds)."""
    zoom = [] if zoom_mm is None else ["--focal-length", f"{zoom_mm:.7g}"]
    return cli_render_seconds(SCENE, [
        "--lens", lens, "--model", model, "--focus", f"{focus:.7g}", "--fstop", f"{fstop:g}",
        "--samples", spp, "--seed", seed, "--resolution", RES, "--engine", "neurolens",
        "--quiet", "--out", out, *zoom])


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


def _one_lens(lens_path: Path, tmp: Path, log) -> tuple[float, dict]:
    from neurolens_addon.core.lensfile import load_lens
    lens = lens_path.stem
    focus, fstop, zoom = _focus_m(lens_path), load_lens(lens_path).f_number, _zoom_mm(lens_path)
    go = lambda model, spp, seed, out: render(lens, focus, fstop, model, spp, seed, out, zoom)
    t_ref = go("exact", REF_SPP, 1, tmp / "ref.exr")
    ref = combined(tmp / "ref.exr")
    cal = {}
    for label, model in _models(lens):
        t0 = go(model, CAL_SPP[0], 3, tmp / "c0.exr")
        t1 = go(model, CAL_SPP[1], 3, tmp / "c1.exr")
        per = max((t1 - t0) / (CAL_SPP[1] - CAL_SPP[0]), 1e-6)
        cal[label] = (model, per, max(t0 - per * CAL_SPP[0], 0.0))
    budget = cal["exact"][2] + cal["exact"][1] * BUDGET_SPP
    figs = {}
    for label, (model, per, fixed) in cal.items():
        spp = max(1, int(round((budget - fixed) / per)))
        out = tmp / f"{label}.exr".replace(" ", "_")
        t = go(model, spp, 2, out)
        img = combined(out)
        s = ssim(luminance(img), luminance(ref))
        rmse = float(np.sqrt(np.mean((img - ref) ** 2)))
        figs[label] = {"samples": spp, "seconds": t, "ms_per_sample_pass": 1000 * per,
                       "ssim": s, "rmse": rmse}
        log(f"  {lens} {label}: {spp} spp in {t:.1f} s, SSIM {s:.4f}, RMSE {rmse:.4f}")
    return t_ref, figs


def _inputs(lens_path: Path) -> str:
    """What a lens's figures depend on: the scene, the lens file and its models."""
    models = [Path(m) for _label, m in _models(lens_path.stem) if m not in ("exact", "learned")]
    shipped = sorted((ROOT / "presets" / "models").glob(f"{lens_path.stem}.*neurolens"))
    return measured_inputs(SCENE, lens_path, *shipped, *models)


def run(resume: bool = False, only=None) -> tuple[str, dict]:
    from .common import preset_paths
    records = LensRecords("render_tradeoff", resume, only)
    figs, rows = {}, []
    with tempfile.TemporaryDirectory() as tmp:
        for lens_path in preset_paths():
            stem = lens_path.stem
            kept = records.get(stem, _inputs(lens_path))
            if kept is None:
                t_ref, f = _one_lens(lens_path, Path(tmp), lambda m: print(m, flush=True))
                kept = records.put(stem, _inputs(lens_path),
                                   {"reference_seconds": t_ref, "models": f})
            else:
                print(f"  {stem}: kept (measured {kept['measured']})", flush=True)
            figs[stem] = kept
            rows += [[stem, kept["measured"], label, r["samples"], f"{r['seconds']:.1f}",
                      f"{r['ms_per_sample_pass']:.0f}", f"{r['ssim']:.4f}", f"{r['rmse']:.4f}"]
                     for label, r in kept["models"].items()]
    text = "\n".join([
        "## Rendered images at equal time (NEUROLENS engine, demo scene, every preset)",
        "",
        f"Design f-number, focus 1.6 m (1.3 x the closest focus when farther), {RES}; "
        f"reference: the exact lens at {REF_SPP} spp. Each model gets the time the exact lens "
        f"needs for {BUDGET_SPP} spp. SSIM and RMSE of the Combined pass against the reference "
        "(noise and model bias together; the exact row is pure noise at that budget). Every "
        "lens with focusing groups is focused at its tabulated close distance nearest 1.6 m, "
        "where its position model renders (no polynomial row: that baseline learned the lens "
        "at infinity). Every "
        "model of a lens is rendered in one run (the date measured; `--resume` renders only "
        "lenses whose file or models changed since).",
        "",
        md_table(["preset", "measured", "model", "samples", "render s", "ms per sample pass",
                  "SSIM", "RMSE"], rows)])
    return text, figs
