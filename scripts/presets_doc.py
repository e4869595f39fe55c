"""Regenerate the presets table of docs/presets.md and the cross-sections in docs/lenses/.

    python scripts/presets_doc.py            rewrite both (the text outside the table is kept)
    python scripts/presets_doc.py --check    exit 1 when either is out of date

Every figure in the table is computed from the files (tests/core/test_presets_doc.py keeps it
current): EFL, BFD and F/# from the paraxial trace at n_d beside what the file states, the
share of a real meridional beam that passes at half and full field (relative to the axial
beam), surfaces, aspheres and moving groups (a zoom's paraxial F/# at each tabulated focal
length, its iris opened per position where its [zoom] table has a stop column).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from lens_tool import pass_share  # noqa: E402
from neurolens_addon.camera.lens_kinds import lens_kind, picker_order  # noqa: E402
from neurolens_addon.core import crosssection  # noqa: E402
from neurolens_addon.core.field import half_field_deg  # noqa: E402
from neurolens_addon.core.lensfile import load_lens  # noqa: E402
from neurolens_addon.core.paraxial import paraxial_data  # noqa: E402
from neurolens_addon.core.variable_gaps import lens_at  # noqa: E402

DOC = ROOT / "docs" / "presets.md"
PICTURES = ROOT / "docs" / "lenses"
BEGIN, END = "<!-- presets table: scripts/presets_doc.py -->", "<!-- end of presets table -->"
PICTURE_SIZE = (360, 150)


def _stated(value, stated, digits):
    return f"{value:.{digits}f}" + ("" if stated is None else f" ({stated:g})")


def _moving(lens):
    parts = []
    if lens.focus_gaps is not None:
        g = lens.focus_gaps
        parts.append(f"focus: {len(g.surfaces)} gaps, to {g.positions[-1] / 1000.0:.2f} m")
    if lens.zoom_gaps is not None:
        g = lens.zoom_gaps
        fs = " / ".join(f"{paraxial_data(lens_at(lens, zoom=float(k))).f_number:.2f}"
                        for k in range(g.count))
        parts.append(f"zoom {g.positions[0]:g}-{g.positions[-1]:g} mm, F/# {fs}")
    return "; ".join(parts) or "unit focusing"


def rows():
    lenses = [load_lens(p) for p in sorted((ROOT / "presets" / "lenses").glob("*.toml"))]
    lenses.sort(key=picker_order)
    out = []
    for lens in lenses:
        stem = Path(lens.path).stem
        pd = paraxial_data(lens)
        hf = half_field_deg(lens)
        share = f"{100 * pass_share(lens, 0.5 * hf):.0f} % / {100 * pass_share(lens, 0.98 * hf):.0f} %"
        asph = sum(1 for s in lens.surfaces if s.is_aspheric)
        field = lens.field_of_view_deg if lens.field_of_view_deg else 2.0 * hf
        out.append((lens, stem, "| " + " | ".join([
            f"![{stem}](lenses/{stem}.png)",
            f"`{stem}`<br>{lens.name}",
            lens_kind(lens),
            _stated(pd.efl_mm, lens.focal_length_mm, 2),
            _stated(pd.bfd_mm, lens.back_focus_mm, 2),
            _stated(pd.f_number, lens.f_number, 2),
            f"{field:.1f}",
            str(len(lens.surfaces)),
            str(asph) if asph else "-",
            _moving(lens),
            share]) + " |"))
    return out


def table(rows_):
    head = ["| cross-section | file / name | kind | EFL mm (stated) | BFD mm (stated) | "
            "F/# (stated) | field deg | surfaces | aspheric | moving groups | beam at half / "
            "full field |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    return "\n".join([BEGIN, f"{len(rows_)} presets, in the picker's order (kind, then focal "
                      "length).", ""] + head + [r for _, _, r in rows_] + [END])


def picture(lens) -> bytes:
    return crosssection.png_bytes(crosssection.cross_section_rgba(lens, *PICTURE_SIZE))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args(argv)
    rs = rows()
    text = DOC.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        print(f"{DOC}: the markers {BEGIN} ... {END} are missing", file=sys.stderr)
        return 1
    new = text[:text.index(BEGIN)] + table(rs) + text[text.index(END) + len(END):]
    stale = [] if new == text else [str(DOC)]
    PICTURES.mkdir(exist_ok=True)
    wanted = set()
    for lens, stem, _ in rs:
        path = PICTURES / f"{stem}.png"
        wanted.add(path.name)
        png = picture(lens)
        if not path.is_file() or path.read_bytes() != png:
            stale.append(str(path))
            if not args.check:
                path.write_bytes(png)
    extra = [p for p in PICTURES.glob("*.png") if p.name not in wanted]
    stale += [str(p) for p in extra]
    if args.check:
        for s in stale:
            print(f"out of date: {s}")
        return 1 if stale else 0
    for p in extra:
        p.unlink()
    if new != text:
        DOC.write_text(new, encoding="utf-8")
    print(f"{len(rs)} presets; rewrote {len(stale)} file(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
