"""The figures the prose docs quote cannot drift from what was measured.

A measured figure in README.md and docs/*.md (a speed in rays, samples, casts or frames per
second, a ratio "N x" to something, a time "N s on / for / at ..."; the benchmark outputs
docs/BENCHMARKS.md and docs/bench/ are the measurements themselves, docs/presets.md is
generated) must stand in a paragraph that either cites the benchmark section it comes from
(`docs/bench/NAME.md` or `benchmarks.run NAME`), whose text holds that very number, or says
when it was measured (a date, YYYY-MM-DD): a figure that changes with the code is then found
by rerunning its section, and an old one says that it is old.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "docs" / "bench"
PROSE = [ROOT / "README.md"] + sorted(
    p for p in (ROOT / "docs").glob("*.md") if p.name not in ("BENCHMARKS.md", "presets.md"))

NUMBER = r"(\d+(?:\.\d+)?)"
FIGURE = re.compile(
    NUMBER + r"(?:-\d+(?:\.\d+)?)?\s?(?:M |k )?(?:camera )?(?:rays|samples|casts|frames)/s"
    r"|" + NUMBER + r"(?:-\d+(?:\.\d+)?)?\s?x (?:the|faster|slower|a |as |Cycles|numpy)"
    r"|" + NUMBER + r"(?:-\d+(?:\.\d+)?)?\s?(?:s|ms|min) (?:on|for|at|to|a|per) ")
CITATION = re.compile(r"docs/bench/([a-z_]+)\.md|benchmarks\.run[^`]*?\b([a-z_]+)`")
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


def paragraphs(text: str):
    """Blocks of a markdown text between blank lines (a list goes with the sentence that
    introduces it)."""
    block: list[str] = []
    for line in text.splitlines() + [""]:
        if line.strip():
            block.append(line.strip())
        elif block:
            yield " ".join(block)
            block = []


def undocumented_figures(text: str, bench_texts: dict) -> list[str]:
    """The figures of `text` that neither a cited section's text holds nor a date covers."""
    bad = []
    for para in paragraphs(text):
        found = [m for m in FIGURE.finditer(para)]
        if not found or DATE.search(para):
            continue
        cited = [a or b for a, b in CITATION.findall(para)]
        pool = " ".join(bench_texts.get(name, "") for name in cited)
        for m in found:
            number = next(g for g in m.groups() if g is not None)
            if not re.search(rf"(?<![\d.]){re.escape(number)}(?![\d])", pool):
                bad.append(f"{m.group(0)!r} in: {para[:120]}")
    return bad


def test_every_measured_figure_in_the_docs_is_sourced_or_dated():
    bench = {p.stem: p.read_text(encoding="utf-8") for p in BENCH.glob("*.md")}
    bad = {p.name: undocumented_figures(p.read_text(encoding="utf-8"), bench) for p in PROSE}
    assert {k: v for k, v in bad.items() if v} == {}


@pytest.mark.parametrize("text, flagged", [
    ("The exact trace runs at 4.2 M rays/s on two cores.", True),
    ("The exact trace runs at 4.2 M rays/s (measured 2026-11-25).", False),
    ("The exact trace runs at 4.2 M rays/s (`docs/bench/speed.md`).", False),
    ("The exact trace runs at 9.9 M rays/s (`docs/bench/speed.md`).", True),
    ("It is 3.5x the exact trace (`python -m benchmarks.run speed`).", False),
    ("A 36 x 24 mm frame at f/2.8.", False),
])
def test_the_check_sees_an_unsourced_figure(text, flagged):
    """The check flags a figure with neither source nor date, or whose cited section lacks it;
    a dated one, one its section holds, and a sensor size pass."""
    bench = {"speed": "| double Gauss | 4.2 | 3.5 |"}
    assert bool(undocumented_figures(text, bench)) == flagged
