"""Command line for the optics core: `python -m neurolens_addon.core COMMAND ...`.

    info LENS [--json]            first-order data and the surface table
    index GLASS WAVELENGTH_NM     refractive index of a catalog glass (or "nd=1.5,vd=60")
    trace LENS --in RAYS.npy --out OUT.npy [--from sensor|scene] [--sensor-z MM]
    diagram LENS --out FILE.png   cross-section with ray fans at several field angles
    spot LENS --out FILE.png      spot diagrams across the field, coloured by wavelength
    convert LENS --out FILE       the lens as our TOML (.toml) or a Zemax file (.zmx)

Errors in the user's input print one line naming the file and problem, and exit with status 2.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from .errors import NeuroLensError
from .prescription import WAVELENGTH_D_NM, Material


def _load(path):
    from .lensfile import load_lens
    return load_lens(path)


def lens_info(lens) -> dict:
    """The `info` record: first-order data plus one row per surface."""
    from .glass import resolve_medium
    from .paraxial import paraxial_data
    pd = paraxial_data(lens)
    wl = np.array([WAVELENGTH_D_NM])
    rows = []
    for s in lens.surfaces:
        rows.append({
            "radius_mm": None if math.isinf(s.radius_mm) else s.radius_mm,
            "thickness_mm": s.thickness_mm,
            "material": s.material.name,
            "n_d": float(resolve_medium(s.material).index(wl)[0]),
            "semi_diameter_mm": s.semi_diameter_mm,
            "conic": s.conic,
            "aspheric": {f"a{p}": a for p, a in s.aspheric},
            "stop": s.stop,
        })
    return {
        "name": lens.name, "source": lens.source,
        "efl_mm": pd.efl_mm, "bfd_mm": pd.bfd_mm, "ffd_mm": pd.ffd_mm,
        "f_number": pd.f_number,
        "designed": {"focal_length_mm": lens.focal_length_mm, "f_number": lens.f_number,
                     "field_of_view_deg": lens.field_of_view_deg},
        "entrance_pupil": {"z_mm": pd.entrance_pupil.z_mm,
                           "diameter_mm": pd.entrance_pupil.diameter_mm},
        "exit_pupil": {"z_mm": pd.exit_pupil.z_mm, "diameter_mm": pd.exit_pupil.diameter_mm},
        "principal_planes_z_mm": {"front": pd.front_principal_z_mm,
                                  "rear": pd.rear_principal_z_mm},
        "total_track_mm": lens.total_track_mm,
        "content_hash": lens.content_hash(),
        "surfaces": rows,
    }


def _print_info(info: dict) -> None:
    print(f"{info['name']}")
    print(f"  source: {info['source']}")
    print(f"  EFL {info['efl_mm']:.4f} mm   BFD {info['bfd_mm']:.4f} mm   F/{info['f_number']:.3f}")
    ep, xp = info["entrance_pupil"], info["exit_pupil"]
    print(f"  entrance pupil z {ep['z_mm']:.3f} mm, diameter {ep['diameter_mm']:.3f} mm")
    print(f"  exit pupil     z {xp['z_mm']:.3f} mm, diameter {xp['diameter_mm']:.3f} mm")
    print(f"  {'#':>3} {'radius':>10} {'thickness':>10} {'n_d':>8} {'semi-d':>8} {'conic':>7}")
    for i, s in enumerate(info["surfaces"], 1):
        r = "flat" if s["radius_mm"] is None else f"{s['radius_mm']:.4f}"
        stop = "  STOP" if s["stop"] else ""
        asph = "  asph" if s["aspheric"] else ""
        print(f"  {i:>3} {r:>10} {s['thickness_mm']:>10.4f} {s['n_d']:>8.5f} "
              f"{s['semi_diameter_mm']:>8.3f} {s['conic']:>7.3g}{stop}{asph}")


def _parse_material(text: str) -> Material:
    if text.lower().startswith("nd="):
        parts = dict(p.split("=", 1) for p in text.split(","))
        return Material.from_abbe(float(parts["nd"]), float(parts["vd"]) if "vd" in parts else None)
    return Material(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m neurolens_addon.core",
                                 description="NeuroLens optics core: exact lens data and traces")
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("info", help="first-order data and surfaces of a lens")
    p.add_argument("lens")
    p.add_argument("--json", action="store_true")
    p = sub.add_parser("index", help="refractive index of a glass at a wavelength")
    p.add_argument("glass")
    p.add_argument("wavelength_nm", type=float)
    p = sub.add_parser("trace", help="trace an N x 7 ray array through a lens")
    p.add_argument("lens")
    p.add_argument("--in", dest="inp", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--from", dest="origin", choices=["sensor", "scene"], default="sensor")
    p.add_argument("--sensor-z", type=float, default=0.0,
                   help="sensor plane z (mm); scene rays land on it, sensor rays' z is measured from it")
    p.add_argument("--f-number", type=float, default=None)
    p = sub.add_parser("diagram", help="cross-section with ray fans")
    p.add_argument("lens")
    p.add_argument("--out", required=True)
    p = sub.add_parser("spot", help="spot diagrams across the field")
    p.add_argument("lens")
    p.add_argument("--out", required=True)
    p.add_argument("--focus", type=float, default=math.inf, help="focus distance in mm (default inf)")
    p = sub.add_parser("convert", help="write a lens as .toml (ours) or .zmx (Zemax)")
    p.add_argument("lens")
    p.add_argument("--out", required=True)
    p = sub.add_parser("stmap", help="an ST-map (Nuke STMap) of a lens's distortion, as EXR")
    p.add_argument("lens")
    p.add_argument("--resolution", required=True, help="WxH of the lens's image (the plate)")
    p.add_argument("--sensor-width", type=float, required=True, help="mm")
    p.add_argument("--focus", type=float, default=math.inf,
                   help="focus distance from the sensor, metres (default infinity)")
    p.add_argument("--zoom", type=float, default=None, help="a zoom lens's focal length, mm")
    p.add_argument("--overscan", type=float, default=1.0,
                   help="the undistorted image's size over the sensor's (>= 1)")
    p.add_argument("--wavelength", type=float, default=587.5618, help="nm")
    p.add_argument("--direction", choices=["undistort", "distort"], required=True)
    p.add_argument("--out", required=True)
    args = ap.parse_args(argv)
    from .atomic import exit_on_sigterm
    exit_on_sigterm()

    try:
        if getattr(args, "out", None) is not None:
            # an output that cannot be written (a directory, FIFO or device, a missing folder)
            # is refused before the lens is loaded or anything traced (core.atomic)
            from .atomic import output_target
            output_target(_trace_out(args.out) if args.cmd == "trace" else args.out)
        if args.cmd == "info":
            info = lens_info(_load(args.lens))
            if args.json:
                from .jsonout import dumps
                print(dumps(info, indent=2))
            else:
                _print_info(info)
        elif args.cmd == "index":
            from .glass import resolve_medium
            n = resolve_medium(_parse_material(args.glass)).index(np.array([args.wavelength_nm]))[0]
            if not np.isfinite(n):
                raise NeuroLensError(f"no index for {args.glass} at {args.wavelength_nm} nm")
            print(f"{n:.6f}")
        elif args.cmd == "trace":
            _cmd_trace(args)
        elif args.cmd == "diagram":
            from .plots import lens_diagram
            lens_diagram(_load(args.lens), args.out)
            print(f"wrote {args.out}")
        elif args.cmd == "convert":
            _cmd_convert(args)
        elif args.cmd == "stmap":
            _cmd_stmap(args)
        elif args.cmd == "spot":
            from .plots import spot_diagram
            spot_diagram(_load(args.lens), args.out, focus_mm=args.focus)
            print(f"wrote {args.out}")
    except BrokenPipeError:
        raise                  # the reader went away: run_command ends quietly
    except (NeuroLensError, OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def _cmd_stmap(args) -> None:
    """Write the ST-map the arguments ask for (core.stmap), its lens data in the header and in
    a JSON sidecar beside it (MAP.exr.json: core.stmap.lens_metadata); print the overscan the
    frame needs."""
    from .stmap import MapFrame, lens_at_setting, lens_map, write_map
    try:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
    except ValueError:
        raise ValueError(f"--resolution: expected WxH, got {args.resolution!r}") from None
    frame = MapFrame.checked(w, h, args.sensor_width, args.overscan)
    lens, sensor_z, table = lens_at_setting(_load(args.lens), focus_mm=1000.0 * args.focus,
                                            zoom_mm=args.zoom, wavelength_nm=args.wavelength,
                                            film_radius_mm=frame.film_radius_mm, frame=frame)
    rgba, header, meta = lens_map(lens, table, frame, args.direction,
                                  focus_mm=1000.0 * args.focus, sensor_z=sensor_z,
                                  wavelength_nm=args.wavelength)
    write_map(args.out, rgba, header, meta)
    need = header["neurolens/overscan_needed"]
    print(f"wrote {args.out}: {rgba.shape[1]}x{rgba.shape[0]} {args.direction} map of "
          f"{lens.name}, pinhole focal length {meta['pinhole_focal_length_mm']:.4f} mm"
          + (f" (x {meta['pinhole_focal_length_x_mm']:.4f} mm, squeeze {meta['squeeze']:.4f})"
             if "squeeze" in meta else "") + "; the frame needs "
          f"overscan {need:.4f}" + ("" if args.overscan >= need else
                                   f" (asked {args.overscan:g}: the distorted frame's edge "
                                   "would sample beyond the CG)"))


def _cmd_convert(args) -> None:
    """Write the lens in the format the output's extension names; the file is either the old
    one or the complete new one (core.atomic)."""
    from pathlib import Path

    from .atomic import atomic_write_text
    from .lensfile import dump_lens, dump_zmx
    suffix = Path(args.out).suffix.lower()
    writers = {".toml": dump_lens, ".zmx": dump_zmx}
    if suffix not in writers:
        raise NeuroLensError(f"{args.out}: the output must end in .toml or .zmx, not "
                             f"'{suffix}'")
    atomic_write_text(args.out, writers[suffix](_load(args.lens)))
    print(f"wrote {args.out}")


#: ray arrays larger than this are refused before they are read (x 7 float64 columns)
MAX_RAY_ROWS = 50_000_000


def load_ray_rows(path) -> np.ndarray:
    """An N x 7 float array from a .npy file, its header checked before anything is read: a
    regular file (core.safe_io), a plain float or integer dtype (no objects, no structured
    records), at most MAX_RAY_ROWS rows, and as many bytes as the header claims."""
    from .filecheck import npy_header
    from .safe_io import UnreadableFile, check_regular
    try:
        st = check_regular(path, ".npy ray array")
    except UnreadableFile as exc:
        raise NeuroLensError(str(exc)) from None
    try:
        with open(path, "rb") as fh:
            shape, dtype, offset = npy_header(fh)
    except (OSError, ValueError) as exc:
        raise NeuroLensError(f"{path}: not a .npy ray array ({exc})") from None
    if dtype.kind not in "fiu" or dtype.fields is not None or dtype.subdtype is not None:
        raise NeuroLensError(f"{path}: ray arrays hold plain numbers; this one's dtype is "
                             f"{dtype.descr if dtype.fields else dtype}")
    if len(shape) != 2 or shape[1] != 7:
        raise NeuroLensError(f"{path}: expected an N x 7 array (x y z dx dy dz wavelength_nm), "
                             f"got shape {tuple(shape)}")
    if shape[0] < 1:
        raise NeuroLensError(f"{path}: the ray array is empty (0 rows)")
    if shape[0] > MAX_RAY_ROWS:
        raise NeuroLensError(f"{path}: {shape[0]} rays; at most {MAX_RAY_ROWS} are traced at "
                             "once (split the array)")
    need = offset + shape[0] * 7 * dtype.itemsize
    if st.st_size < need:
        raise NeuroLensError(f"{path}: the header claims {shape[0]} rows but the file holds "
                             f"{st.st_size} of the {need} bytes they need (truncated?)")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise NeuroLensError(f"{path}: not a readable .npy ray array ({exc})") from None


def _trace_out(out) -> str:
    """The file `trace --out` writes: np.save's name (.npy added unless given)."""
    return out if str(out).endswith(".npy") else f"{out}.npy"


def _cmd_trace(args) -> None:
    from .rays import Rays
    from .trace import trace
    lens = _load(args.lens)
    rows = load_ray_rows(args.inp)
    if rows.ndim != 2 or rows.shape[1] != 7:
        raise NeuroLensError(f"{args.inp}: expected an N x 7 array (x y z dx dy dz wavelength_nm), "
                             f"got shape {rows.shape}")
    rays = Rays.from_rows(rows.astype(np.float64))
    from_sensor = args.origin == "sensor"
    if from_sensor:
        rays.o[2] += args.sensor_z
    stop_radius = None
    if args.f_number is not None:
        from .aperture import stop_radius_of
        stop_radius = stop_radius_of(lens, args.f_number)
    res = trace(lens, rays, from_sensor=from_sensor, sensor_z=args.sensor_z,
                stop_radius=stop_radius)
    from .atomic import atomic_path
    with atomic_path(_trace_out(args.out)) as tmp:
        np.save(tmp, res.rays.to_rows(res.valid), allow_pickle=False)
    print(f"traced {rays.n} rays, {int(res.valid.sum())} valid ({100 * res.valid_fraction:.1f} %)")
