"""The (n_d, V_d) glass model's error over the whole shipped catalogue, for docs/measurements.md.

    python scripts/glass_model_doc.py            print the figures, rewrite the paragraph
    python scripts/glass_model_doc.py --check    exit 1 when the paragraph is out of date

For every glass of the shipped catalogue (core/data/glass), the model AbbeGlass(n_d, V_d) built
from the glass's own listed n_d and V_d is compared with the glass's catalogue formula at
WAVELENGTHS_NM (400-700 nm, every nm); a glass's error is the largest |n_model - n_catalogue|
there. The paragraph gives the largest over the catalogue, the mean, median and 90th
percentile of the per-glass errors, how many glasses exceed 2e-3 and 5e-3 (and their V_d),
the five worst, and the glasses the docs name (tests/core/test_glass.py keeps it current).
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from neurolens_addon.core.glass import AbbeGlass, default_catalog  # noqa: E402

DOC = ROOT / "docs" / "measurements.md"
BEGIN = "<!-- glass-model figures: scripts/glass_model_doc.py -->"
END = "<!-- end of glass-model figures -->"
WAVELENGTHS_NM = np.linspace(400.0, 700.0, 301)
#: glasses the docs quote by name (docs/glass-catalog.md)
NAMED = ("N-BK7", "N-LAK9", "N-SF6", "N-SF57")


def errors(catalog=None):
    """[(error, wavelength nm of it, glass)] for every glass, largest error first."""
    catalog = default_catalog() if catalog is None else catalog
    rows = []
    for g in catalog:
        e = np.abs(AbbeGlass(g.nd, g.vd).index(WAVELENGTHS_NM) - g.index(WAVELENGTHS_NM))
        k = int(np.argmax(e))
        rows.append((float(e[k]), float(WAVELENGTHS_NM[k]), g))
    rows.sort(key=lambda r: -r[0])
    return rows


def _e(x: float) -> str:
    return f"{x:.1e}".replace("e-0", "e-")


def paragraph(rows, catalog=None) -> str:
    catalog = default_catalog() if catalog is None else catalog
    e = np.array([r[0] for r in rows])
    worst_e, worst_w, worst = rows[0]
    over2 = [r for r in rows if r[0] > 2e-3]
    over5 = [r for r in rows if r[0] > 5e-3]
    at = {r[2]: r for r in rows}
    named = ", ".join(f"{n} {_e(at[catalog.get(n)][0])}" for n in NAMED)
    five = ", ".join(f"{g.name} ({g.manufacturer}) {_e(x)}" for x, _, g in rows[:5])
    blue = sum(1 for r in over2 if r[1] == WAVELENGTHS_NM[0])
    vds = [r[2].vd for r in over2]
    kind = "all dense flints" if vds and max(vds) < 30.0 else "the largest"
    where = "all" if blue == len(over2) else f"{blue} of them"
    text = (
        f"Over the shipped catalogue ({len(rows)} glasses), the model built from each glass's own "
        f"n_d and V_d stays within {_e(worst_e)} of the catalogue formula over 400-700 nm "
        f"(largest: {worst.name}, {worst.manufacturer}, n_d {worst.nd:.4f}, V_d "
        f"{worst.vd:.2f}, at {worst_w:.0f} nm). Per glass (its largest error): mean "
        f"{_e(e.mean())}, median {_e(float(np.median(e)))}, 90th percentile "
        f"{_e(float(np.percentile(e, 90)))}; {len(over2)} glasses exceed 2e-3 and "
        f"{len(over5)} exceed 5e-3, {kind} (V_d {min(vds):.1f} to {max(vds):.1f}; {where} at "
        f"400 nm). The five largest: "
        f"{five}. Glasses the docs name: {named}.")
    wrapped = textwrap.fill(text, width=100, break_on_hyphens=False, break_long_words=False)
    return "\n".join([BEGIN, wrapped, END])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when docs/measurements.md's paragraph is out of date")
    args = ap.parse_args(argv)
    new_block = paragraph(errors())
    text = DOC.read_text(encoding="utf-8")
    if BEGIN not in text or END not in text:
        print(f"{DOC}: the markers {BEGIN} ... {END} are missing", file=sys.stderr)
        return 1
    new = text[:text.index(BEGIN)] + new_block + text[text.index(END) + len(END):]
    if args.check:
        if new != text:
            print(f"{DOC} is out of date: run python scripts/glass_model_doc.py")
            return 1
        return 0
    print(new_block)
    if new != text:
        DOC.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
