"""`python -m neurolens_addon.render SCENE.blend --lens PRESET --focus M --fstop N --samples S
--engine neurolens|cycles --out FILE.exr [--out FILE.png ...]`: a headless render with the
`bpy` module.

Opens the .blend, registers the add-on (its camera settings and the NEUROLENS engine), sets
the scene camera's lens (custom properties `neurolens_lens` / `neurolens_model`, see
blender/camera_reader.py), focus distance, f-number, focal length (a zoom lens's setting) and
the sample count, resolves the lens set-up exactly as the panel and the engine do
(blender.camera_reader.lens_setup), renders once, and writes every --out through Blender's own image
writer (Image.save_render): `.exr` as multilayer OpenEXR with every pass, `.png` as an 8-bit
PNG of the view-transformed Combined pass. Progress goes to stderr as a bar (a line per 10 %
when stderr is not a terminal). A missing file, camera or lens, or an --out that cannot be
written (a directory, FIFO or device, a missing folder: checked before the render starts)
ends with one line `neurolens.render: error: ...` and exit status 2 (a focus nearer than the
lens reaches is clamped with a note, as in the panel); a render that fails exits with 1, and
so does an output that does not read back whole (a full disk: core.atomic), every --out then
left as it was.

--engine cycles renders the same scene with Cycles on the CPU through the add-on's OSL custom
camera (cycles.CameraSpec.from_setup of the same set-up, applied by
neurolens_addon.blender.cycles_camera.apply_lens_camera).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path

from ..camera.resolve import MAX_GHOST_INTENSITY
from ..core.aperture.f_number import MAX_F_NUMBER
from ..core.arguments import int_in
from ..core.atomic import WriteError, atomic_paths
from ..engine.renderer import STOP_REQUESTED

PROG = "neurolens.render"
#: the most samples per pixel a command asks for (Blender's own properties are 32-bit)
MAX_SAMPLES = 1 << 24


class CliError(Exception):
    """A problem with the command's input (exit status 2)."""


def parse_args(argv):
    p = argparse.ArgumentParser(prog="python -m neurolens_addon.render",
                                description="Render a .blend through a real lens, headless.")
    p.add_argument("scene", help="the .blend file")
    p.add_argument("--lens", help="lens preset name or lens file (default: the camera's Real "
                                  "Lens panel, or its 'neurolens_lens' property)")
    p.add_argument("--model", default=None,
                   help="'auto' (the default, as the panel's: the exact trace or the learned "
                        "model, whichever costs less a camera ray on --engine, within the "
                        "scene's error budget), 'exact', 'learned', 'thin', or a NAME.neurolens "
                        "model directory (default: what the camera's panel says)")
    p.add_argument("--focus", type=float, help="focus distance from the sensor, metres")
    p.add_argument("--fstop", type=float, help="f-number")
    p.add_argument("--focal-length", type=float,
                   help="Blender's focal length, mm: a zoom lens's setting (within its range)")
    p.add_argument("--samples", type=int_in(1, MAX_SAMPLES), help="samples per pixel")
    p.add_argument("--bounces", type=int_in(0, 16),
                   help="Light Paths > Max Bounces > Total of the scene, for either engine")
    p.add_argument("--engine", choices=("neurolens", "cycles"), default="neurolens")
    p.add_argument("--resolution", help="WIDTHxHEIGHT in pixels (default: the scene's)")
    p.add_argument("--percentage", type=int_in(1, 32767), help="resolution percentage")
    p.add_argument("--scene", dest="scene_name",
                   help="scene name (default: the scene the file opens with)")
    p.add_argument("--camera", help="camera object name (default: the scene camera)")
    p.add_argument("--seed", type=int_in(0, 2 ** 31 - 1),
                   help="random seed (either engine: NEUROLENS's, Cycles' Sampling > Seed)")
    p.add_argument("--device", choices=("AUTO", "CPU"), help="onnxruntime device (NEUROLENS)")
    p.add_argument("--colour-rays", type=int, choices=(1, 3),
                   help="lens rays a sample with dispersion: 3 (R, G, B, no colour noise) or 1 "
                        "(as the Cycles camera, three times less work) (NEUROLENS)")
    p.add_argument("--dispersion", action=argparse.BooleanOptionalAction, default=None,
                   help="a wavelength per ray: the lens's chromatic aberration (default: the "
                        "camera's panel)")
    p.add_argument("--diffraction", action=argparse.BooleanOptionalAction, default=None,
                   help="spread rays by the aperture's Fraunhofer pattern: starbursts on "
                        "highlights (default: the camera's panel)")
    p.add_argument("--ghosts", action=argparse.BooleanOptionalAction, default=None,
                   help="render ghosts (light reflected twice inside the lens; default: the "
                        "camera's panel)")
    p.add_argument("--coating", choices=("bare", "single", "multi"),
                   help="coating of every air-glass surface for ghosts (default: the panel's)")
    p.add_argument("--ghost-intensity", type=float, help="multiplier of the ghosts' light")
    p.add_argument("--ghost-count", type=int_in(1, 64), help="brightest ghosts rendered")
    p.add_argument("--ghost-share", type=float, help="share of samples spent on ghosts")
    p.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=None,
                   help="denoise the finished frame: the engine's Open Image Denoise (default: "
                        "on), or Cycles' own denoiser (default: the scene's setting)")
    p.add_argument("--intersector", choices=("auto", "embree", "blender"),
                   help="ray casts (NEUROLENS): Embree when installed (auto), or Blender's BVH")
    p.add_argument("--memory-limit", type=float, metavar="GB",
                   help="refuse a render estimated to need more than GB gigabytes (default: "
                        "the scene's Memory Limit, 0: what the machine has available) (NEUROLENS)")
    p.add_argument("--tile-order", choices=("auto", "progressive", "tiles"),
                   help="progressive passes over the frame, or tile by tile (a film of one "
                        "tile: large frames); auto chooses (NEUROLENS)")
    p.add_argument("--show-setup", action="store_true",
                   help="print the lens set-up the --engine will render as JSON and exit")
    p.add_argument("--overscan", type=float, default=None,
                   help="render F times the frame each way (sensor and pixels; 1 to 4): the "
                        "border a distort ST-map needs; with --stmap, the undistorted "
                        "image's size")
    p.add_argument("--stmap", choices=("undistort", "distort"),
                   help="write the camera's ST-map (its lens, focus, zoom and sensor) to the "
                        "--out .exr, and its lens data beside it (.exr.json), instead of "
                        "rendering")
    p.add_argument("--pass", dest="data_passes", action="append", default=[],
                   choices=("vector", "position", "uv"),
                   help="add a data pass to the .exr: vector (motion, in pixels, through "
                        "the lens), position (world) or uv; repeatable (the view layer's "
                        "switches, as in Cycles)")
    p.add_argument("--out", action="append", default=[],
                   help="output file, .exr (multilayer, all passes) or .png; repeatable")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p.parse_args(argv)


class ProgressBar:
    """A bar on stderr: redrawn in place on a terminal, a line per 10 % otherwise."""

    def __init__(self, stream=sys.stderr, width: int = 30):
        self.stream = stream
        self.width = width
        self.tty = stream.isatty()
        self.last_decile = -1
        self.t0 = time.perf_counter()

    def __call__(self, fraction: float, text: str = ""):
        fraction = min(max(fraction, 0.0), 1.0)
        n = int(round(self.width * fraction))
        line = (f"[{'#' * n}{'.' * (self.width - n)}] {100 * fraction:5.1f}% "
                f"{time.perf_counter() - self.t0:6.1f}s  {text}")
        if self.tty:
            self.stream.write("\r" + line[:160].ljust(160))
        else:
            decile = int(fraction * 10)
            if decile == self.last_decile:
                return
            self.last_decile = decile
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self):
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _resolution(text: str):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CliError(f"--resolution must be WIDTHxHEIGHT, got '{text}'") from None
    if w < 1 or h < 1:
        raise CliError(f"--resolution must be positive, got '{text}'")
    from ..core.film import MAX_SIDE_PX
    if max(w, h) > MAX_SIDE_PX:
        raise CliError(f"--resolution {w}x{h}: at most {MAX_SIDE_PX} pixels a side")
    return w, h


def _check_outputs(outs):
    """Refuse, before anything is rendered, an --out that could not be written: an unknown
    suffix, a directory, FIFO, device or socket, a missing or read-only folder, or two
    --out naming one file (links followed: core.atomic.output_target)."""
    from ..core.atomic import WriteError, output_target
    seen = {}
    for o in outs:
        ext = Path(o).suffix.lower()
        if ext not in (".exr", ".png"):
            raise CliError(f"--out {o}: expected a .exr or .png file name")
        try:
            target = output_target(o)
        except WriteError as exc:
            raise CliError(f"--out {exc}") from None
        if target in seen:
            raise CliError(f"--out {o}: the same file as --out {seen[target]}")
        seen[target] = o


def _open_scene(path: str):
    import bpy
    p = Path(path)
    if not p.is_file():
        raise CliError(f"{path}: no such file")
    try:
        bpy.ops.wm.open_mainfile(filepath=str(p.resolve()), load_ui=False)
    except RuntimeError as e:
        msg = str(e).strip().splitlines()[-1] if str(e).strip() else "cannot open"
        raise CliError(f"{path}: not a readable .blend file ({msg})") from None
    return bpy.context.scene


def _scene(name):
    import bpy
    if not name:
        return bpy.context.scene
    scene = bpy.data.scenes.get(name)
    if scene is None:
        raise CliError(f"no scene named '{name}' (scenes: "
                       f"{', '.join(s.name for s in bpy.data.scenes)})")
    return scene


def _camera(scene, name):
    import bpy
    if name:
        ob = bpy.data.objects.get(name)
        if ob is None or ob.type != "CAMERA":
            raise CliError(f"no camera object named '{name}' in scene '{scene.name}'")
        scene.camera = ob
    if scene.camera is None or scene.camera.type != "CAMERA":
        raise CliError(f"scene '{scene.name}' has no active camera")
    return scene.camera


def _set_lens(args, camera) -> None:
    """--lens and --model change only what they name. A camera set up in the Real Lens panel
    keeps its panel (aperture shape, dispersion, model unless --model names one); any other
    camera gets the custom properties blender/camera_reader.py documents."""
    from ..blender.camera_reader import LENS_PROP, MODEL_PROP, PANEL_MODELS, uses_panel
    from ..camera.lenses import preset_id, preset_names, resolve_lens_path
    cam = camera.data
    path = resolve_lens_path(args.lens) if args.lens else None     # LensError: no such lens
    model = args.model.lower() if args.model and args.model.lower() in PANEL_MODELS.values() \
        else None
    if uses_panel(cam) and not (args.model and model is None):
        props = cam.neurolens
        if path is not None and preset_id(path) is not None:
            props.source, props.lens_id = "LIBRARY", preset_id(path)
        elif path is not None:
            props.source, props.lens_file = "FILE", str(path.resolve())
        if model is not None:
            props.model = model.upper()
        return
    if uses_panel(cam):                 # --model DIR: a model the panel cannot name
        from ..blender.camera_reader import lens_reference
        _lens_id, current, _model, _dir = lens_reference(camera)
        cam[LENS_PROP] = str(path.resolve()) if path is not None else current
        cam.neurolens.enabled = False
    elif path is not None:
        cam[LENS_PROP] = str(args.lens) if not Path(args.lens).is_file() else str(path.resolve())
    elif not cam.get(LENS_PROP):
        raise CliError(f"camera '{camera.name}' names no lens: pass --lens PRESET "
                       f"({', '.join(preset_names()[:4])}, ...) or set it up in the Real Lens "
                       "panel")
    if args.model:
        cam[MODEL_PROP] = args.model


def _set_ghosts(args, cam) -> None:
    """--ghosts and its settings into the panel (or the custom properties without it)."""
    from ..blender.camera_reader import GHOST_PROPS
    values = (args.ghosts, args.coating, args.ghost_intensity, args.ghost_count,
              args.ghost_share)
    if args.ghost_share is not None and not 0.0 < args.ghost_share < 1.0:
        raise CliError(f"--ghost-share must lie between 0 and 1, got {args.ghost_share}")
    if args.ghost_intensity is not None and not 0.0 <= args.ghost_intensity <= \
            MAX_GHOST_INTENSITY:
        raise CliError(f"--ghost-intensity must lie between 0 and {MAX_GHOST_INTENSITY:g}, got "
                       f"{args.ghost_intensity}")
    props = getattr(cam, "neurolens", None)
    names = ("ghosts", "coating", "ghost_intensity", "ghost_count", "ghost_share")
    for name, prop, value in zip(names, GHOST_PROPS, values):
        if value is None:
            continue
        if props is not None:
            setattr(props, name, value.upper() if name == "coating" else value)
        else:
            cam[prop] = int(value) if isinstance(value, bool) else value


def _configure(args, scene, camera):
    """Write the command's settings into the scene and camera; the camera's lens set-up."""
    from ..blender.camera_reader import lens_setup
    cam = camera.data
    _set_lens(args, camera)
    if args.focus is not None:
        if not args.focus > 0:
            raise CliError(f"--focus must be a positive distance in metres, got {args.focus}")
        cam.dof.focus_object = None
        cam.dof.focus_distance = args.focus / scene.unit_settings.scale_length
    from ..blender.camera_reader import DIFFRACTION_PROP, DISPERSION_PROP
    for value, name, prop in ((args.diffraction, "diffraction", DIFFRACTION_PROP),
                              (args.dispersion, "dispersion", DISPERSION_PROP)):
        if value is None:
            continue
        if getattr(cam, "neurolens", None) is not None:
            setattr(cam.neurolens, name, value)
        else:
            cam[prop] = int(value)
    _set_ghosts(args, cam)
    if args.fstop is not None:
        if not 0.0 < args.fstop <= MAX_F_NUMBER:
            raise CliError(f"--fstop must be a positive f-number up to f/{MAX_F_NUMBER:g}, got "
                           f"{args.fstop}")
        cam.dof.aperture_fstop = args.fstop
    if args.focal_length is not None:
        if not (math.isfinite(args.focal_length) and args.focal_length >= 1.0):
            raise CliError(f"--focal-length must be a focal length in mm (>= 1), got "
                           f"{args.focal_length}")
        cam.lens = args.focal_length
    r = scene.render
    if args.resolution:
        r.resolution_x, r.resolution_y = _resolution(args.resolution)
    if args.percentage:
        r.resolution_percentage = args.percentage
    if args.overscan is not None and args.stmap is None:
        _overscan(args.overscan, r, cam)
    if args.samples is not None and args.samples < 1:
        raise CliError(f"--samples must be >= 1, got {args.samples}")
    # the renderer first: model AUTO picks the cheapest model on the one that renders
    r.engine = "CYCLES" if args.engine == "cycles" else "NEUROLENS"
    for name in args.data_passes:
        for each in scene.view_layers:
            setattr(each, f"use_pass_{name}", True)
    layer = scene.view_layers[0]
    layer.update()                  # world matrices of this scene (focus objects, the camera)
    return lens_setup(camera, scene, layer.depsgraph)    # the panel's and the engine's resolver


def _overscan(f: float, render, cam) -> None:
    """F times the frame each way, at the same pixel pitch: the sensor and the resolution
    grown alike (the frame's centre and its pixels stay where they were)."""
    if not (math.isfinite(f) and 1.0 <= f <= 4.0):
        raise CliError(f"--overscan must be a number from 1 to 4, got {f}")
    w, h = round(render.resolution_x * f), round(render.resolution_y * f)
    from ..core.film import MAX_SIDE_PX
    if max(w, h) > MAX_SIDE_PX:
        raise CliError(f"--overscan {f:g}: {w}x{h} exceeds {MAX_SIDE_PX} pixels a side")
    cam.sensor_width *= w / render.resolution_x
    cam.sensor_height *= h / render.resolution_y
    cam.shift_x *= render.resolution_x / w            # shift is a share of the frame
    cam.shift_y *= render.resolution_y / h
    render.resolution_x, render.resolution_y = w, h


def _write_stmap(args, setup) -> None:
    """The camera's ST-map (camera.stmaps) to the --out .exr, its lens data beside it; one
    line of what was written."""
    from ..camera.stmaps import camera_maps
    if len(args.out) != 1 or Path(args.out[0]).suffix.lower() != ".exr":
        raise CliError("--stmap writes one map: give one --out FILE.exr")
    rgba, header, meta = camera_maps(setup, args.stmap,
                                     1.0 if args.overscan is None else args.overscan)
    from ..core.stmap import write_map
    write_map(args.out[0], rgba, header, meta)
    print(f"{PROG}: wrote {args.out[0]}: {rgba.shape[1]}x{rgba.shape[0]} {args.stmap} map of "
          f"{meta['lens']} focused at {setup.focus_m:.3g} m, pinhole focal length "
          f"{meta['pinhole_focal_length_mm']:.4f} mm; the frame needs overscan "
          f"{meta['overscan_needed']:.4f}")


#: the longest metadata note Blender keeps (longer ones are cut)
NOTE_LIMIT = 500


def header_note(data: dict) -> str:
    """The gist of a frame's lens data (frame_lens_data) as compact JSON for its EXR header's
    note, within NOTE_LIMIT characters: the lens, model, f-number, focus, sensor, pinhole
    focal length, entrance pupil and OpenCV's Brown-Conrady coefficients with their
    residual (the sidecar has everything)."""
    from ..core.jsonout import dumps

    def num(v):
        return None if v is None else float(f"{v:.7g}")
    bc = (data.get("distortion") or {}).get("brown_conrady") or {}
    gist = {"lens": str(data.get("lens", ""))[:80], "model": data["model"],
            "f_number": num(data["f_number"]), "focus_mm": num(data["focus_distance_mm"]),
            "sensor_mm": [num(v) for v in data["sensor_mm"]],
            "pinhole_focal_length_mm": num(data.get("pinhole_focal_length_mm")),
            **({"squeeze": num(data["squeeze"])} if "squeeze" in data else {}),
            "entrance_pupil_from_sensor_mm": num(data.get("entrance_pupil_from_sensor_mm")),
            "opencv_k": [num(bc[k]) for k in ("k1", "k2", "k3")] if bc else None,
            "opencv_residual_px": num(bc.get("max_residual_px")) if bc else None}
    text = dumps(gist, separators=(",", ":"))
    return text if len(text) <= NOTE_LIMIT else dumps({"lens": gist["lens"][:NOTE_LIMIT - 20]})


def _setup_neurolens(args, scene):
    scene.render.engine = "NEUROLENS"
    from ..blender.diffraction_compositor import clear_diffraction
    clear_diffraction(scene)          # the engine convolves itself: no compositor pass too
    props = scene.neurolens_engine
    if args.samples is not None:
        props.samples = args.samples
    if args.seed is not None:
        props.seed = args.seed
    if args.device:
        props.device = args.device
    if args.intersector:
        props.intersector = args.intersector.upper()
    if args.denoise is not None:
        props.denoise = args.denoise
    if args.colour_rays is not None:
        props.colour_rays = str(args.colour_rays)
    if args.memory_limit is not None:
        props.memory_limit_gb = args.memory_limit
    if args.tile_order is not None:
        props.tile_order = args.tile_order.upper()


def _setup_cycles(args, scene, camera, setup):
    """Cycles on the CPU with the add-on's OSL camera of the same lens set-up."""
    from ..blender.cycles_camera import apply_lens_camera, use_cycles_cpu
    from ..cycles import CameraSpec
    use_cycles_cpu(scene)
    if args.samples is not None:
        scene.cycles.samples = args.samples
    if args.seed is not None:
        scene.cycles.seed = args.seed
    if args.denoise is not None:
        # Cycles' own denoiser (Render > Sampling > Denoise, on in a new scene): --no-denoise
        # must give the raw estimate in either engine. With dispersion each camera ray is one
        # wavelength, so the raw image carries colour noise, which OIDN smears outwards:
        # a far light's defocus disc came out 5-8 % wider (RMS) at 128-256 samples, and bluer
        scene.cycles.use_denoising = args.denoise
    apply_lens_camera(camera.data, CameraSpec.from_setup(setup))
    from ..blender.diffraction_compositor import sync_diffraction
    message = sync_diffraction(scene, setup)     # Cycles convolves in the compositor
    if message:
        print(f"{PROG}: {message}", file=sys.stderr)
    import bpy
    from ..blender.flare_compositor import sync_flare
    message, seconds = sync_flare(scene, bpy.context.evaluated_depsgraph_get(), camera, setup)
    if message:                                  # the lamps' flare, added in the compositor
        print(f"{PROG}: {message}", file=sys.stderr)
    if seconds is not None and not args.quiet:
        print(f"{PROG}: the lamps' flare traced for the compositor, flare {seconds:.2f} s")


def _write(scene, outs):
    import bpy
    img = bpy.data.images.get("Render Result")
    if img is None:
        raise RuntimeError("the render produced no result")
    s = scene.render.image_settings
    # Blender writes in place, and on a full disk leaves a truncated file without raising:
    # every output goes to a temporary file beside its target, is read back (core.filecheck
    # decodes the PNG or EXR), and only when all of them are whole are they renamed into place
    # together (core.atomic), so the old frames stay unless every new one is complete
    with atomic_paths(outs) as tmps:
        for o, tmp in zip(outs, tmps):
            if o.lower().endswith(".exr"):
                s.media_type = "MULTI_LAYER_IMAGE"
                s.file_format = "OPEN_EXR_MULTILAYER"
                s.color_depth = "32"
            else:
                s.media_type = "IMAGE"
                s.file_format = "PNG"
                s.color_mode = "RGBA"
                s.color_depth = "8"
            img.save_render(filepath=str(tmp), scene=scene)


#: Cycles' progress in its stats line ("... | Rendered 3/12 Tiles, Sample 16/64"), read by the
#: bar: a background render states its samples only as each tile starts and ends
CYCLES_PROGRESS_RE = re.compile(r"(?:Rendered (\d+)/(\d+) Tiles, )?Sample (\d+)/(\d+)")
#: tiles a Cycles render is cut into so that its progress shows (about; tiles >= 64 px)
CYCLES_PROGRESS_TILES = 12


def cycles_progress(bar):
    """A render_stats handler that feeds Cycles' tiles and samples done to the progress bar
    (never backwards)."""
    done = [0.0]

    def on_stats(stats, *_args):
        m = CYCLES_PROGRESS_RE.search(str(stats))
        if m is None or int(m.group(4)) <= 0:
            return
        sample = int(m.group(3)) / int(m.group(4))
        if m.group(1) is not None and int(m.group(2)) > 0:
            k, n = int(m.group(1)), int(m.group(2))
            fraction = (k + (sample if sample < 1.0 else 0.0)) / n
        else:
            fraction = sample
        done[0] = max(done[0], min(fraction, 0.999))
        bar(done[0], "Cycles")
    return on_stats


def cycles_progress_tiles(scene) -> None:
    """Cut a Cycles render into about CYCLES_PROGRESS_TILES tiles: in the background Cycles
    reports its samples only as a tile starts and ends, so one tile shows no progress (the
    image is the same; small tiles cost a little time)."""
    r = scene.render
    w = max(1, r.resolution_x * r.resolution_percentage // 100)
    h = max(1, r.resolution_y * r.resolution_percentage // 100)
    scene.cycles.use_auto_tile = True
    scene.cycles.tile_size = max(64, math.ceil(math.sqrt(w * h / CYCLES_PROGRESS_TILES)))


class _Stopped(Exception):
    """SIGINT or SIGTERM arrived during the render: write nothing."""


_STATE = {"rendering": False, "signal": 0}


def _stop_on_signals() -> None:
    """SIGINT / SIGTERM: before the render, exit at once; during it, stop the engine at its
    next bundle (engine.renderer.STOP_REQUESTED) and write nothing; during the write, finish
    it (outputs are renamed into place whole: core.atomic)."""
    import signal

    def handler(signum, _frame):
        _STATE["signal"] = signum
        STOP_REQUESTED.set()
        if not _STATE["rendering"]:
            raise SystemExit(128 + signum)
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            signal.signal(sig, handler)
        except ValueError:           # not the main thread (an embedding application)
            return


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    _stop_on_signals()
    try:
        if not args.out and not args.show_setup:
            raise CliError("give at least one --out FILE (.exr or .png), or --show-setup")
        _check_outputs(args.out)
        if args.memory_limit is not None and not (math.isfinite(args.memory_limit)
                                                  and args.memory_limit >= 0.0):
            raise CliError(f"--memory-limit must be a size in GB >= 0 (0: what the machine "
                           f"has available), got {args.memory_limit}")
        if not Path(args.scene).is_file():
            raise CliError(f"{args.scene}: no such file")
        import bpy
        from ..core.errors import NeuroLensError
        from ..blender import register
        from ..blender import engine_registration
        from ..blender.render_engine import LAST, REPORTS
        from ..engine.renderer import LISTENERS
        _open_scene(args.scene)
        if not engine_registration.is_registered():
            register()
        scene = _scene(args.scene_name)
        camera = _camera(scene, args.camera)
        try:
            config = _configure(args, scene, camera)
            if args.stmap is not None:
                _write_stmap(args, config)
                return 0
            if args.show_setup:
                from ..camera import traced
                shown = config if args.engine == "cycles" else traced(config)
                from ..core.jsonout import dumps
                print(dumps(shown.as_dict(), indent=1, sort_keys=True))
                return 0
            if args.engine == "cycles":
                _setup_cycles(args, scene, camera, config)
        except NeuroLensError as e:
            raise CliError(str(e)) from None
    except CliError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2

    bar = None if args.quiet else ProgressBar()
    on_stats = None
    if args.bounces is not None and hasattr(scene, "cycles"):
        scene.cycles.max_bounces = args.bounces        # the Light Paths both engines read
    if args.engine == "neurolens":
        _setup_neurolens(args, scene)
        REPORTS["printed_by_caller"] = True        # notes once: ours, not Blender's too
        if bar is not None:
            LISTENERS.append(bar)
    elif bar is not None:
        cycles_progress_tiles(scene)
        on_stats = cycles_progress(bar)
        bpy.app.handlers.render_stats.append(on_stats)
    notes = config.messages + (config.cycles_messages if args.engine == "cycles" else ())
    for _level, note in notes:
        print(f"{PROG}: note: {note}", file=sys.stderr)
    from ..camera.stmaps import frame_lens_data
    from ..core.jsonout import dumps
    lens_data = frame_lens_data(config)
    if not scene.render.use_stamp:
        # the EXR's header carries its gist as the metadata note (a render's stamp is taken
        # as it starts; never burnt into the picture)
        scene.render.use_stamp_note = True
        scene.render.stamp_note_text = header_note(lens_data)
    lens_data = dumps(lens_data)
    t0 = time.perf_counter()
    _STATE["rendering"] = True
    try:
        bpy.ops.render.render(scene=scene.name)
        if STOP_REQUESTED.is_set():
            raise _Stopped()
        stats = LAST.get("stats") if args.engine == "neurolens" else None
        if args.engine == "neurolens" and stats is None:
            raise RuntimeError(LAST.get("error") or "the render failed")
        if bar is not None:
            bar(1.0, "writing")
            bar.close()
        _write(scene, args.out)
        from ..core.atomic import atomic_write_text
        for out in args.out:
            atomic_write_text(f"{out}.json", lens_data + "\n")
    except _Stopped:
        if bar is not None:
            bar.close()
        print(f"{PROG}: stopped by signal {_STATE['signal']}: nothing written (any earlier "
              "output is unchanged)", file=sys.stderr)
        return 128 + _STATE["signal"]
    except WriteError as e:           # one line naming the file; the old files are unchanged
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    except (RuntimeError, OSError) as e:
        if bar is not None:
            bar.close()
        msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
        print(f"{PROG}: error: render failed: {msg}", file=sys.stderr)
        return 1
    finally:
        if bar is not None and bar in LISTENERS:
            LISTENERS.remove(bar)
        if on_stats in bpy.app.handlers.render_stats:
            bpy.app.handlers.render_stats.remove(on_stats)
    dt = time.perf_counter() - t0
    w, h = config.film.width_px, config.film.height_px
    line = f"{PROG}: {w}x{h}, {config.describe()}, {dt:.1f} s"
    if args.engine == "neurolens":
        line += f" | {stats.summary()}"
        for note in stats.notes:        # what the engine met in the scene (set-up notes above)
            print(f"{PROG}: note: {note}", file=sys.stderr)
    print(line, file=sys.stderr)
    for o in args.out:
        print(f"{PROG}: wrote {o}", file=sys.stderr)
    return 0
