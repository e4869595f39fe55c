"""Cost of the lens effects against renders without them (issue 17 figures).

Diffraction (core.diffraction): the shipped demo scene through the double Gauss (the scene
camera's aperture shape; the cost does not depend on it), focused at 1.6 m, at f/2.8 and f/16
(the kernel grows with the working f-number), rendered headless (`python -m
neurolens_addon.render`, one process per render, the render time the command prints) by the
NEUROLENS engine and by Cycles, each with and without `--diffraction`, in one run: the
difference is the kernel (built once per process: the pattern's two FFTs and 21 wavelengths on
the film's grid) and the frame's FFT convolution (the engine's own, after denoising; Cycles'
compositor Convolve node). In-process timings of the kernel and of the convolution of a
1920 x 1080 frame are given beside them.

Ghosts (core.ghosts; the NEUROLENS engine and the Cycles exact camera): a flare scene made
here (a large bright ball off axis before a grey wall, black sky) through the uncoated double
Gauss at f/2.8, eight ghosts, a quarter of the samples on them: render time with and without
ghosts at the same samples, the frame's light with and without (the ghosts take theirs from
the image), and convergence: the RMS difference from a many-sample reference with ghosts of
the same renderer against the samples (an unbiased estimator's error falls as
1 / sqrt(samples)).

Anamorphic presets: the out-of-focus shape of a small far light (engine), and the flare of a
bright light with ghosts on (Cycles), whose frame is written to docs/images.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from testdata.light_shape import spread_px

from .common import ROOT, cli_render_seconds, md_table

SCENE = ROOT / "presets" / "scenes" / "demo.blend"
LENS = "double_gauss_50mm_f2"
RES = "480x270"
SAMPLES = {"neurolens": 8, "cycles": 32}
F_NUMBERS = (2.8, 16.0)


def _render(engine: str, fstop: float, diffraction: bool, out: Path) -> float:
    return cli_render_seconds(SCENE, [
        "--lens", LENS, "--model", "exact", "--focus", "1.6", "--fstop", f"{fstop:g}",
        "--samples", SAMPLES[engine], "--resolution", RES, "--engine", engine, "--seed", 1,
        "--quiet", "--out", out, "--diffraction" if diffraction else "--no-diffraction"])


def _in_process() -> dict:
    from neurolens_addon.core.aperture import PolygonAperture
    from neurolens_addon.core.diffraction import build_pattern, convolve, film_kernel
    ap = PolygonAperture(6)
    t0 = time.perf_counter()
    pattern = build_pattern(ap)
    t_pattern = time.perf_counter() - t0
    out = {"pattern_s": t_pattern}
    img = np.random.default_rng(0).random((1080, 1920, 4)).astype(np.float32)
    for n in F_NUMBERS:
        t0 = time.perf_counter()
        k = film_kernel(pattern, pixel_mm=36.0 / 1920, working_f_number=n, dispersion=True,
                        max_radius_px=1920)
        t_kernel = time.perf_counter() - t0
        t0 = time.perf_counter()
        convolve(img, k)
        out[f"f{n:g}"] = {"kernel_s": t_kernel, "convolve_1080p_s": time.perf_counter() - t0,
                          "kernel_px": int(k.kernels.shape[1])}
    return out


FLARE_RES = "160x90"
#: samples per engine (the engine's and Cycles' costs per sample differ a hundredfold)
FLARE_SAMPLES = {"neurolens": (16, 64, 256), "cycles": (64, 256, 1024)}
FLARE_REFERENCE = {"neurolens": 1024, "cycles": 4096}


def _flare_scene(path: Path) -> None:
    """A bright ball (radius 0.15 m, 3 m away, off axis) before a grey wall, black sky."""
    _dark_scene(path, (0.35, 0.2, -3.0), 0.15, 60.0, sensor_width=36.0, focus=3.0, fstop=2.8,
                lens=LENS, wall=(-6.0, 12.0, 0.4))


def _flare_render(scene: Path, engine: str, ghosts: bool, samples: int,
                  out: Path) -> tuple[float, object]:
    from .render_tradeoff import combined
    seconds = cli_render_seconds(scene, [
        "--model", "exact", "--samples", samples, "--resolution", FLARE_RES, "--engine", engine,
        "--seed", samples, "--quiet", "--no-denoise", "--out", out, "--coating", "bare",
        "--ghost-count", 8, "--ghost-share", 0.25, "--ghosts" if ghosts else "--no-ghosts"])
    return seconds, combined(out)


def _ghost_figures(tmp: Path) -> dict:
    scene = tmp / "flare.blend"
    _flare_scene(scene)
    out = {}
    for engine in ("neurolens", "cycles"):
        t_ref, ref = _flare_render(scene, engine, True, FLARE_REFERENCE[engine],
                                   tmp / "ref.exr")
        fig = out[engine] = {"reference_samples": FLARE_REFERENCE[engine], "reference_s": t_ref,
                             "runs": []}
        for n in FLARE_SAMPLES[engine]:
            t_off, off = _flare_render(scene, engine, False, n, tmp / "off.exr")
            t_on, on = _flare_render(scene, engine, True, n, tmp / "on.exr")
            rms = float(np.sqrt(np.mean((on - ref) ** 2)))
            fig["runs"].append({"samples": n, "without_s": t_off, "with_s": t_on,
                                "light_with_over_without": float(on.sum() / off.sum()),
                                "rms_against_reference": rms})
            print(f"  ghosts {engine} {n} spp: {t_off:.1f} s without, {t_on:.1f} s with, "
                  f"RMS {rms:.4g}", flush=True)
    return out


ANAMORPHIC = ("anamorphic_2x_60mm_f1_9", "anamorphic_attachment_speed_panchro_50mm_f2")
#: the spherical prime the attachment preset is mounted on: the round-bokeh control
PRIME = "cinema_speed_panchro_50mm_f2"
BOKEH_RES, BOKEH_SAMPLES = "96x96", 256
STREAK_RES, STREAK_SAMPLES = "384x170", 1024
#: half the height in rows of the band through the light's image the streak is sought in
BAND_PX = 6


def _dark_scene(path: Path, light, radius: float, strength: float, *, sensor_width: float,
                focus: float, fstop: float, lens: str, wall=None) -> None:
    """A glowing ball on black, optionally before a grey wall `wall` = (z, size, grey level),
    one camera on the axis looking down -Z."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    # Cycles: every pixel its samples, no denoiser (the convergence is the estimator's own)
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    world = bpy.data.worlds.new("black")
    world.color = (0.0, 0.0, 0.0)
    scene.world = world
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=light)
    glow = bpy.data.materials.new("glow")
    glow.use_nodes = True
    bsdf = glow.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.95, 0.85, 1.0)
    bsdf.inputs["Emission Strength"].default_value = strength
    bpy.context.object.data.materials.append(glow)
    if wall is not None:
        wall_z, size, level = wall
        bpy.ops.mesh.primitive_plane_add(size=size, location=(0.0, 0.0, wall_z))
        grey = bpy.data.materials.new("grey")
        grey.use_nodes = True
        grey.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (
            level, level, level, 1.0)
        bpy.context.object.data.materials.append(grey)
    bpy.ops.object.camera_add(location=(0.0, 0.0, 0.0))
    cam = bpy.context.object
    scene.camera = cam
    cam.data.sensor_fit = "HORIZONTAL"
    cam.data.sensor_width = sensor_width
    cam.data.dof.use_dof = True
    cam.data.dof.focus_distance = focus
    cam.data.dof.aperture_fstop = fstop
    cam.data["neurolens_lens"] = lens
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def _anamorphic_figures(tmp: Path) -> dict:
    return {"bokeh": _bokeh_figures(tmp), "streak": _streak_figures(tmp)}


def _bokeh_figures(tmp: Path) -> dict:
    """A light 20 m away, focus 1 m, f/2: the out-of-focus light's shape (engine, exact)."""
    from .render_tradeoff import combined
    out = {}
    for lens in ANAMORPHIC + (PRIME,):
        scene = tmp / f"bokeh_{lens}.blend"
        _dark_scene(scene, (0.0, 0.0, -20.0), 0.05, 400.0, sensor_width=8.0, focus=1.0,
                    fstop=2.0, lens=lens)
        seconds = cli_render_seconds(scene, [
            "--model", "exact", "--samples", BOKEH_SAMPLES, "--resolution", BOKEH_RES,
            "--engine", "neurolens", "--seed", 1, "--quiet", "--no-denoise",
            "--out", tmp / "bokeh.exr"])
        sx, sy = spread_px(combined(tmp / "bokeh.exr").sum(axis=-1))
        out[lens] = {"sigma_x_px": sx, "sigma_y_px": sy, "height_over_width": sy / sx,
                              "seconds": seconds}
        print(f"  bokeh {lens}: height / width {sy / sx:.2f}", flush=True)
    return out


def _streak_figures(tmp: Path) -> dict:
    """A bright light off axis with ghosts on: where the ghosts' light goes (Cycles, exact)."""
    from .render_tradeoff import combined
    out = {}
    lens = ANAMORPHIC[0]
    scene = tmp / "streak.blend"
    _dark_scene(scene, (0.9, 0.35, -8.0), 0.08, 1250.0, sensor_width=42.1, focus=8.0,
                fstop=2.8, lens=lens)
    images = {}
    for ghosts in (False, True):
        seconds = cli_render_seconds(scene, [
            "--model", "exact", "--samples", STREAK_SAMPLES, "--resolution", STREAK_RES,
            "--engine", "cycles", "--seed", 1, "--quiet", "--no-denoise", "--coating", "bare",
            "--ghost-count", 16, "--ghost-share", 0.5,
            "--out", tmp / f"streak{ghosts}.exr", "--ghosts" if ghosts else "--no-ghosts"])
        images[ghosts] = combined(tmp / f"streak{ghosts}.exr")
        out[f"{'with' if ghosts else 'without'}_s"] = seconds
    # the ghosts' light: the frame with ghosts less the frame without, off the light's image
    # (which dims with ghosts on); its share in the band of rows through the light's image
    # against the band's share of the frame: a streak concentrates it there
    light = images[False].sum(axis=-1)
    ghost = np.clip(images[True] - images[False], 0.0, None).sum(axis=-1)
    ghost[light > 1e-3 * light.max()] = 0.0
    row = int(round(float((light.sum(axis=1) * np.arange(light.shape[0])).sum() / light.sum())))
    band = slice(max(row - BAND_PX, 0), row + BAND_PX + 1)
    share = float(ghost[band].sum() / ghost.sum())
    band_rows = band.stop - band.start
    out.update({"band_rows": band_rows, "ghost_share_in_band": share,
                "concentration": share / (band_rows / ghost.shape[0])})
    print(f"  streak: {share:.2f} of the ghosts' light in the {band_rows} rows through the "
          f"light ({out['concentration']:.1f}x uniform)", flush=True)
    _save_png(images[True], ghost, ROOT / "docs" / "images" / "anamorphic_flare.png")
    return out


def _save_png(img: np.ndarray, ghost: np.ndarray, path: Path) -> None:
    """A view of a linear frame exposed for its ghosts (their 99.5th percentile at 2), the
    light's image rolled off by x / (1 + x), gamma 2.2; written atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from neurolens_addon.core.atomic import atomic_write_bytes
    import io
    v = img * (2.0 / max(float(np.percentile(ghost[ghost > 0], 99.5)), 1e-12))
    buf = io.BytesIO()
    plt.imsave(buf, np.clip(v / (1.0 + v), 0.0, 1.0) ** (1 / 2.2), format="png")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())


def run() -> tuple[str, dict]:
    import subprocess
    import sys
    # the engine's compiled kernels built (or loaded) before any timed render: a fresh tree
    # compiles them once, inside the first render's time
    subprocess.run([sys.executable, "-m", "neurolens_addon.engine.kernel_warmup"], cwd=ROOT,
                   check=True, capture_output=True)
    figs = {"in_process": _in_process()}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for engine in ("neurolens", "cycles"):
            for n in F_NUMBERS:
                off = _render(engine, n, False, Path(tmp) / "off.exr")
                on = _render(engine, n, True, Path(tmp) / "on.exr")
                figs[f"{engine} f{n:g}"] = {"without_s": off, "with_s": on}
                rows.append([engine, f"f/{n:g}", SAMPLES[engine], f"{off:.2f}", f"{on:.2f}",
                             f"{on - off:+.2f}", f"{on / off:.2f}"])
                print(f"  {engine} f/{n:g}: {off:.2f} s without, {on:.2f} s with diffraction",
                      flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        figs["ghosts"] = g = _ghost_figures(Path(tmp))
    with tempfile.TemporaryDirectory() as tmp:
        figs["anamorphic"] = a = _anamorphic_figures(Path(tmp))
    ghost_rows = [[engine, r["samples"], f"{r['without_s']:.1f}", f"{r['with_s']:.1f}",
                   f"{r['with_s'] / max(r['without_s'], 0.05):.2f}",
                   f"{r['light_with_over_without']:.3f}", f"{r['rms_against_reference']:.4g}"]
                  for engine, e in g.items() for r in e["runs"]]
    ip = figs["in_process"]
    inproc = [[f"f/{n:g}", ip[f"f{n:g}"]["kernel_px"], f"{ip[f'f{n:g}']['kernel_s']:.2f}",
               f"{ip[f'f{n:g}']['convolve_1080p_s']:.2f}"] for n in F_NUMBERS]
    text = "\n".join([
        "## Lens effects: the cost of diffraction and ghosts (same run)",
        "",
        f"Demo scene, {LENS}, focus 1.6 m, {RES}, exact lens; render time the "
        "command prints (one process per render: the kernel is built in each).",
        "",
        md_table(["engine", "f-number", "samples", "without s", "with s", "difference s",
                  "ratio"], rows),
        "",
        f"In process (hexagon): the pattern's two FFTs {ip['pattern_s']:.2f} s once per "
        "aperture shape; per film and f-number (1920 x 1080 on 36 mm, dispersion: 21 "
        "wavelengths):",
        "",
        md_table(["f-number", "kernel side px", "kernel s", "convolution of a 1080p frame s"],
                 inproc),
        "",
        f"Ghosts (flare scene made by the section, {FLARE_RES}, uncoated double Gauss at f/2.8, "
        "eight ghosts, a quarter of the samples on them, no denoising, exact lens); RMS against "
        "a reference render with ghosts of the same engine (NEUROLENS "
        f"{FLARE_REFERENCE['neurolens']} spp, Cycles {FLARE_REFERENCE['cycles']} spp):",
        "",
        md_table(["engine", "samples", "without s", "with s", "ratio", "light with / without",
                  "RMS against the reference"], ghost_rows),
        "",
        f"Anamorphic presets: a small light 20 m away, focus 1 m, f/2, NEUROLENS engine, exact "
        f"lens, {BOKEH_RES}, {BOKEH_SAMPLES} spp: the spread of its out-of-focus image in the "
        "desqueezed frame (a vertical oval: height over width above 1; the prime alone, round):",
        "",
        md_table(["lens", "sigma x px", "sigma y px", "height / width"],
                 [[k, f"{v['sigma_x_px']:.2f}", f"{v['sigma_y_px']:.2f}",
                   f"{v['height_over_width']:.2f}"] for k, v in a["bokeh"].items()]),
        "",
        f"Flare of {ANAMORPHIC[0]} (Cycles, exact lens, {STREAK_RES}, {STREAK_SAMPLES} spp, "
        "uncoated, 16 ghosts, half the samples on them, a bright ball off axis on black): of "
        "the ghosts' light (the frame with ghosts less the frame without, off the ball's "
        f"image) {a['streak']['ghost_share_in_band']:.2f} lies in the "
        f"{a['streak']['band_rows']} rows through the ball, "
        f"{a['streak']['concentration']:.1f}x their share of the frame: a horizontal streak; "
        "render "
        f"{a['streak']['without_s']:.1f} s without ghosts, {a['streak']['with_s']:.1f} s with. "
        "The frame: docs/images/anamorphic_flare.png."])
    return text, figs
