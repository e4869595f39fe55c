"""Tools for transcribing a lens prescription into our TOML format (a developer's aid, not shipped).

    python scripts/lens_tool.py check FILE...        first-order data against the stated figures
    python scripts/lens_tool.py apertures FILE [--write] [--margin 1.02] [--vignette 0]
    python scripts/lens_tool.py glasses FILE         catalogue glasses matching { nd, vd } media
    python scripts/lens_tool.py anamorphic-focus FILE --gaps A B --distances D1 D2 ...
    python scripts/lens_tool.py zoom-stops FILE --f-numbers N0 N1 ...

`check` prints, per file, the paraxial EFL, BFD and F/# beside the stated `focal_length_mm`,
`back_focus_mm` and `f_number` (deviation in %), the share of a real ray beam that passes at
half and full field, and per tabulated focus / zoom position its EFL and BFD.

`glasses` lists, for each glass given by n_d and V_d, the catalogue glasses within 0.0003 in
n_d and 0.3 in V_d (a patent's n_d / V_d pair is almost always a catalogue glass; naming it
gives the maker's dispersion curve instead of the Abbe model).

`anamorphic-focus` prints the [focus] table of an anamorphic lens that focuses by two gaps (a
front attachment's focusing gap A and the back gap B, surface numbers): per object distance D
(mm from the sensor) the two thicknesses that put the paraxial images of the axial point in
both meridians on the design image plane (Newton on the two residuals), after the infinity
row of the file's own thicknesses. A front anamorphic attachment is afocal for infinity only:
focused by the back gap alone, its powered meridian would focus elsewhere (astigmatism).

`zoom-stops` solves the stop's semi-diameter per zoom position for the stated f-numbers (one per
tabulated focal length; a constant-aperture zoom's iris opens as it zooms): the paraxial
f-number at infinity focus is N_k at position k, and as the entrance pupil scales with the stop,
r_k = r * P_k / N_k (P_k the paraxial f-number there with the file's stop r). It prints the
rows for the [zoom] table (`f_numbers`, `stop_semi_diameter`; r_0 is the stop surface's own
semi_diameter, which it names when that changes), and per position, with the solved stop, the
share of the axial beam the other apertures let through (1: only the stop limits it) and
whether the stop is wider than the surfaces next to it.

`apertures` finds clear semi-diameters where a source gives none: with every other aperture
opened as far as its shape allows, the stop set to the stated f-number (paraxially, at the
first zoom position; at the others as the [zoom] table's stop column opens it, when it has
one), it traces real beams from 0 to the half field (every tabulated focus and zoom position)
and takes, per surface, the largest height of a ray that passes the stop, times `--margin`.
`--vignette V` lets the outermost field lose up to a share V of its beam (the apertures of the
edge field are those of the beam's inner 1 - V by height spread). `--write` rewrites the
`semi_diameter` lines of the file in place (its other text is kept).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neurolens_addon.core.field import half_field_deg  # noqa: E402
from neurolens_addon.core.lensfile import load_lens  # noqa: E402
from neurolens_addon.core.lensfile.toml_reader import loads_lens  # noqa: E402
from neurolens_addon.core.paraxial import paraxial_data  # noqa: E402
from neurolens_addon.core.prescription import WAVELENGTH_D_NM  # noqa: E402
from neurolens_addon.core.rays import Rays  # noqa: E402
from neurolens_addon.core.trace import trace, trace_path  # noqa: E402
from neurolens_addon.core.variable_gaps import lens_at  # noqa: E402


def positions(lens):
    """Every tabulated (focus, zoom) position of the lens as lens_at arguments."""
    fs = [None] if lens.focus_gaps is None else list(range(lens.focus_gaps.count))
    zs = [None] if lens.zoom_gaps is None else list(range(lens.zoom_gaps.count))
    return [(f, z) for z in zs for f in fs]


def at(lens, f, z):
    return lens if f is None and z is None else lens_at(lens, focus=f, zoom=z)


def pct(value, stated):
    return f"{value:9.3f} (stated {stated:g}, {100.0 * (value / stated - 1.0):+.2f} %)"


def beam(lens, field_deg, xs, ys):
    """Parallel rays from the field angle (in the y-z plane) through the points (xs, ys) of a
    plane 5 mm in front of the lens."""
    th = math.radians(field_deg)
    z0 = lens.front_vertex_z + 5.0
    o = np.stack([xs, ys, np.full_like(xs, z0)])
    d = np.repeat(np.array([[0.0], [-math.sin(th)], [-math.cos(th)]]), xs.size, axis=1)
    return Rays(o, d, np.full(xs.size, WAVELENGTH_D_NM))


def passing_range(lens, field_deg, n=20001):
    """The y range (on the start plane) of the meridional rays from the field that reach the
    sensor, found by widening fans; None if none passes."""
    pd = paraxial_data(lens)
    th = math.radians(field_deg)
    z0 = lens.front_vertex_z + 5.0
    y_c = math.tan(th) * (z0 - pd.entrance_pupil.z_mm) if field_deg < 60.0 else 0.0
    widest = max(s.semi_diameter_mm for s in lens.surfaces) * 3.0 + abs(y_c)
    span = 2.0 * pd.entrance_pupil.diameter_mm
    while True:
        ys = y_c + np.linspace(-span, span, n)
        ok = trace(lens, beam(lens, field_deg, np.zeros(n), ys), from_sensor=False).valid
        if ok.sum() >= 20:
            return ys[ok].min(), ys[ok].max(), ok.sum() * (ys[1] - ys[0])
        if span > widest:
            return None
        span *= 4.0


def pass_share(lens, field_deg):
    """Width of the meridional beam from the field that reaches the sensor, relative to the
    axial beam's (a pupil fan's share: vignetting, and the pupil's own growth or shrinkage)."""
    axial = passing_range(lens, 0.0)
    edge = passing_range(lens, field_deg)
    if axial is None:
        return float("nan")
    return 0.0 if edge is None else edge[2] * math.cos(math.radians(field_deg)) / axial[2]


def check(path):
    lens = load_lens(path)
    pd = paraxial_data(lens)
    print(f"{path}: {lens.name}")
    print(f"  EFL {pct(pd.efl_mm, lens.focal_length_mm)}")
    print(f"  F/# {pct(pd.f_number, lens.f_number)}")
    if lens.back_focus_mm is not None:
        print(f"  BFD {pct(pd.bfd_mm, lens.back_focus_mm)}")
    else:
        print(f"  BFD {pd.bfd_mm:9.3f} (not stated)")
    print(f"  design image plane at paraxial focus: rear focal z {pd.rear_focal_z_mm:+.4f} mm")
    hf = half_field_deg(lens)
    print(f"  half field {hf:.2f} deg; beam passing at half / full field: "
          f"{100 * pass_share(lens, 0.5 * hf):.0f} % / {100 * pass_share(lens, 0.98 * hf):.0f} %")
    print(f"  RMS spot at full aperture (d line, design image plane): axis "
          f"{rms_spot_um(lens, 0.0):.1f} um, 0.7 field {rms_spot_um(lens, 0.7 * hf):.1f} um")
    for f, z in positions(lens):
        if f is None and z is None:
            continue
        moved = at(lens, f, z)
        p = paraxial_data(moved)
        label = []
        if z is not None:
            label.append(f"zoom {lens.zoom_gaps.positions[z]:g} mm")
        if f is not None:
            label.append(f"focus {lens.focus_gaps.positions[f]:g} mm")
        print(f"  {', '.join(label)}: EFL {p.efl_mm:.3f}  BFD {p.bfd_mm:.3f}  F/# {p.f_number:.3f}"
              f"  total track {moved.total_track_mm:.3f}")


def rms_spot_um(lens, field_deg):
    """RMS radius (um) of the spot of a full-aperture beam at d on the design image plane."""
    found = passing_range(lens, field_deg)
    if found is None:
        return float("nan")
    lo, hi, _ = found
    g = np.linspace(lo, hi, 41)
    gx, gy = np.meshgrid(g - 0.5 * (lo + hi), g)
    res = trace(lens, beam(lens, field_deg, gx.ravel(), gy.ravel()), from_sensor=False)
    p = res.rays.o[:2, res.valid]
    return 1000.0 * float(np.sqrt(((p - p.mean(axis=1, keepdims=True)) ** 2).sum(axis=0).mean()))


def glasses(path):
    from neurolens_addon.core.glass import default_catalog
    cat = default_catalog()
    lens = load_lens(path)
    seen = set()
    for i, s in enumerate(lens.surfaces):
        m = s.material
        if m.is_air or m.nd is None or m.name in seen:
            continue
        seen.add(m.name)
        hits = [g for g in cat if abs(g.nd - m.nd) <= 3e-4
                and (m.vd is None or abs(g.vd - m.vd) <= 0.3)]
        hits.sort(key=lambda g: abs(g.nd - m.nd) + abs(g.vd - (m.vd or g.vd)) / 100.0)
        found = ", ".join(f"{g.name} ({g.manufacturer} {g.nd:.5f}/{g.vd:.2f})" for g in hits[:4])
        print(f"  surface {i + 1:2d} {m.name}: {found or 'no catalogue glass'}")


def shape_limit(surface):
    """The largest semi-diameter the surface's shape allows (conic square root, finite sag)."""
    c, k = surface.curvature, surface.conic
    if c == 0.0:
        return 1e4
    q = (1.0 + k) * c * c
    return 0.999 / math.sqrt(q) if q > 0 else 1e4


def opened(lens, stop_sd):
    surfs = []
    for s in lens.surfaces:
        sd = stop_sd if s.stop else min(shape_limit(s), 20.0 * abs(lens.focal_length_mm) + 50.0)
        surfs.append(dataclasses.replace(s, semi_diameter_mm=sd))
    return lens.with_surfaces(surfs)


def stop_for_f_number(lens):
    """The stop semi-diameter that gives the stated f-number paraxially."""
    pd = paraxial_data(lens)
    return lens.stop_radius_mm * (pd.efl_mm / lens.f_number) / pd.entrance_pupil.diameter_mm


def beam_heights(lens, field_deg, keep):
    """Per surface, the height (mm) a beam from the field needs, over the rays that pass the
    stop (the inner `keep` share by height spread for a vignetted edge field)."""
    found = passing_range(lens, field_deg)
    if found is None:
        return None
    lo, hi, _ = found
    yc, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    xr = passing_range_x(lens, field_deg, yc, half)
    g = np.linspace(-1.0, 1.0, 241)
    gx, gy = np.meshgrid(g * 1.05 * xr, yc + g * 1.05 * half)
    rays = beam(lens, field_deg, gx.ravel(), gy.ravel())
    path, _ = trace_path(lens, rays, from_sensor=False)
    alive = path[-1][1]
    if keep < 1.0:
        y = rays.o[1]
        lo, hi = np.quantile(y[alive], [0.5 - keep / 2, 0.5 + keep / 2])
        alive = alive & (y >= lo) & (y <= hi)
    return [float(np.hypot(p[0, alive], p[1, alive]).max()) for p, _ in path[1:]]


def passing_range_x(lens, field_deg, yc, half, n=4001):
    """Half width in x of the passing beam through the line y = yc (sagittal fan)."""
    xs = np.linspace(-4.0 * half, 4.0 * half, n)
    ok = trace(lens, beam(lens, field_deg, xs, np.full(n, yc)), from_sensor=False).valid
    return float(np.abs(xs[ok]).max()) if ok.any() else half


def apertures(path, write, margin, vignette):
    lens = load_lens(path)
    hf = half_field_deg(lens)
    need = np.zeros(len(lens.surfaces))
    first = at(lens, *positions(lens)[0])
    stop_sd = stop_for_f_number(first)
    efl0 = paraxial_data(first).efl_mm
    for f, z in positions(lens):
        # a zoom table's stop column opens the iris per position (zoom-stops)
        m = at(lens, f, z)
        moved = opened(m, m.stop_radius_mm * stop_sd / lens.stop_radius_mm)
        # a zoom position sees the image circle of the first: its own, narrower field
        hf = math.degrees(math.atan(math.tan(math.radians(half_field_deg(lens))) * efl0
                                    / paraxial_data(moved).efl_mm))
        for frac in np.linspace(0.0, 1.0, 9):
            keep = 1.0 - vignette * frac ** 2
            h = beam_heights(moved, frac * hf, keep)
            if h is None:
                print(f"  no ray passes at {frac * hf:.1f} deg (focus {f}, zoom {z})")
                continue
            need = np.maximum(need, h[:len(need)])
    sds = []
    for i, s in enumerate(lens.surfaces):
        sd = stop_sd if s.stop else min(math.ceil(need[i] * margin * 100.0) / 100.0,
                                        0.995 * shape_limit(s))
        sds.append(sd)
        print(f"  surface {i + 1:2d}: beam {need[i]:8.3f} mm -> semi_diameter {sd:.3f}"
              f"{'  STOP' if s.stop else ''}")
    if write:
        text = Path(path).read_text(encoding="utf-8")
        scale = _scale(text)
        values = iter(sds)
        out, count = [], 0
        for line in text.splitlines(keepends=True):
            if re.match(r"\s*semi_diameter\s*=", line):
                out.append(f"semi_diameter = {round(next(values) / scale, 4)}\n")
                count += 1
            else:
                out.append(line)
        assert count == len(sds), "one semi_diameter line per surface expected"
        new = "".join(out)
        loads_lens(new, path)           # refuse to write a file that does not load
        Path(path).write_text(new, encoding="utf-8")
        print(f"  wrote {count} semi-diameters into {path}")


def _scale(text):
    m = re.search(r"^scale\s*=\s*([0-9.eE+-]+)", text, re.M)
    return float(m.group(1)) if m else 1.0


def anamorphic_focus(path, gaps, distances):
    """The [focus] table keeping both meridians of an anamorphic lens on the image plane."""
    from neurolens_addon.core.paraxial import paraxial_image_z
    lens = load_lens(path)
    idx = [g - 1 for g in gaps]

    def moved(t):
        surfaces = list(lens.surfaces)
        for i, ti in zip(idx, t):
            surfaces[i] = dataclasses.replace(surfaces[i], thickness_mm=float(ti))
        return dataclasses.replace(lens, surfaces=tuple(surfaces), focus_gaps=None)

    def residual(t, d):
        m = moved(t)
        return np.array([paraxial_image_z(m, d, meridian=k) for k in ("y", "x")])

    t = np.array([lens.surfaces[i].thickness_mm for i in idx])
    rows = [t.copy()]
    for d in distances:
        for _ in range(50):                 # Newton, finite-difference Jacobian
            r = residual(t, d)
            if np.abs(r).max() < 1e-9:
                break
            jac = np.stack([(residual(t + h, d) - r) / 1e-6 for h in np.eye(2) * 1e-6], axis=1)
            t = t - np.linalg.solve(jac, r)
        else:
            sys.exit(f"{path}: no focus found for {d:g} mm (paraxial residuals {r} mm)")
        rows.append(t.copy())
    cols = np.array(rows).T
    print("[focus]")
    print("distances_mm = [inf, " + ", ".join(f"{d:.1f}" for d in distances) + "]")
    print("thickness = { " + ", ".join(
        f"{g} = [" + ", ".join(f"{v:.4f}" for v in col) + "]" for g, col in zip(gaps, cols))
        + " }")


def _axial_grid(lens, n):
    half = 0.6 * paraxial_data(lens).entrance_pupil.diameter_mm
    g = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(g, g)
    return beam(lens, 0.0, gx.ravel(), gy.ravel())


def axial_pass_fraction(lens, n=301):
    """Share of the on-axis beam the stop admits that also passes every other aperture: rays
    parallel to the axis on a grid over the entrance pupil, traced with the lens's apertures
    and with every aperture but the stop opened (1.0: only the stop limits the axial beam)."""
    rays = _axial_grid(lens, n)
    ours = trace(lens, rays, from_sensor=False).valid
    free = trace(opened(lens, lens.stop_radius_mm), rays, from_sensor=False).valid
    return float(ours.sum()) / max(float(free.sum()), 1.0)


def axial_heights(lens, n=201):
    """Per surface, the largest height (mm) of the axial beam the stop admits (every other
    aperture opened)."""
    path, _ = trace_path(opened(lens, lens.stop_radius_mm), _axial_grid(lens, n),
                         from_sensor=False)
    alive = path[-1][1]
    return [float(np.hypot(p[0, alive], p[1, alive]).max()) for p, _ in path[1:]]


def zoom_stops(path, f_numbers, decimals=4):
    """The stop semi-diameter per zoom position for the stated f-numbers (module docstring)."""
    lens = load_lens(path)
    table = lens.zoom_gaps
    if table is None:
        sys.exit(f"{path}: no [zoom] table")
    if len(f_numbers) != table.count:
        sys.exit(f"{path}: {table.count} zoom positions, {len(f_numbers)} f-numbers given")
    r_file = lens.stop_radius_mm
    fixed = dataclasses.replace(lens, zoom_gaps=dataclasses.replace(
        table, stop_semi_diameter_mm=None, f_numbers=None))
    radii = []
    for k, n_k in enumerate(f_numbers):
        p_k = paraxial_data(lens_at(fixed, zoom=float(k), design_f_number=False)).f_number
        radii.append(round(r_file * p_k / n_k, decimals))
        print(f"  zoom {table.positions[k]:g} mm: F/{p_k:.4f} with the file's stop "
              f"{r_file:g} mm -> stop {radii[-1]:.{decimals}f} mm for F/{n_k:g}")
    solved = dataclasses.replace(lens, f_number=float(f_numbers[0]), surfaces=tuple(
        dataclasses.replace(sf, semi_diameter_mm=radii[0]) if sf.stop else sf
        for sf in lens.surfaces), zoom_gaps=dataclasses.replace(
        table, stop_semi_diameter_mm=tuple(radii), f_numbers=tuple(map(float, f_numbers))))
    stop = lens.stop_index
    need = np.zeros(len(lens.surfaces))
    for k in range(table.count):
        moved = lens_at(solved, zoom=float(k))
        pd = paraxial_data(moved)
        r = moved.stop_radius_mm
        near = [moved.surfaces[j].semi_diameter_mm for j in (stop - 1, stop + 1)
                if 0 <= j < len(moved.surfaces)]
        wider = "  (wider than its neighbours' " + " / ".join(f"{v:g}" for v in near) + \
            " mm)" if near and r > min(near) else ""
        print(f"  zoom {table.positions[k]:g} mm: paraxial F/{pd.f_number:.4f}, design "
              f"f_number {moved.f_number:.4f}; axial beam passing {axial_pass_fraction(moved):.4f}"
              f"{wider}")
        need = np.maximum(need, axial_heights(moved))
    for i, sf in enumerate(lens.surfaces):
        if not sf.stop and need[i] > sf.semi_diameter_mm:
            print(f"  surface {i + 1}: the axial beam needs {need[i]:.3f} mm (semi_diameter "
                  f"{sf.semi_diameter_mm:g}; with a 2 % margin "
                  f"{math.ceil(need[i] * 1.02 * 100.0) / 100.0:.2f})")
    if radii[0] != r_file:
        print(f"  the stop surface (surface {stop + 1}): semi_diameter = {radii[0]:g} "
              f"(was {r_file:g})")
    if float(f_numbers[0]) != lens.f_number:
        print(f"  f_number = {f_numbers[0]:g} (was {lens.f_number:g})")
    print("[zoom]")
    print("f_numbers = [" + ", ".join(f"{n:g}" for n in f_numbers) + "]")
    print("stop_semi_diameter = [" + ", ".join(f"{r:.{decimals}f}" for r in radii) + "]")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("check")
    c.add_argument("files", nargs="+")
    a = sub.add_parser("apertures")
    a.add_argument("file")
    a.add_argument("--write", action="store_true")
    a.add_argument("--margin", type=float, default=1.02)
    a.add_argument("--vignette", type=float, default=0.0)
    g = sub.add_parser("glasses")
    g.add_argument("file")
    f = sub.add_parser("anamorphic-focus")
    f.add_argument("file")
    f.add_argument("--gaps", type=int, nargs=2, required=True)
    f.add_argument("--distances", type=float, nargs="+", required=True)
    z = sub.add_parser("zoom-stops")
    z.add_argument("file")
    z.add_argument("--f-numbers", type=float, nargs="+", required=True)
    args = ap.parse_args(argv)
    if args.cmd == "zoom-stops":
        zoom_stops(args.file, args.f_numbers)
    elif args.cmd == "check":
        for f in args.files:
            check(f)
    elif args.cmd == "glasses":
        glasses(args.file)
    elif args.cmd == "anamorphic-focus":
        anamorphic_focus(args.file, args.gaps, args.distances)
    else:
        apertures(args.file, args.write, args.margin, args.vignette)


if __name__ == "__main__":
    main()
