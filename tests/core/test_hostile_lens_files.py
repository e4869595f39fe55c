"""Hostile lens files (issue 27): every reader a lens file meets is fed every file of the
hostile corpus (testdata/hostile_lens_files.py) and either loads it or refuses it with the
project's own error, in one line naming the file; nothing hangs or allocates without end (the
corpus is read in a child process with bounded memory and time). Lenses built in code pass the
same checks: every tabulated position validated, (n_d, V_d) bounded, tables bounded."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import LensError

ROOT = Path(__file__).resolve().parents[2]
#: the child reading the corpus may use this much memory (the largest hostile counts asked
#: for gigabytes) and this long (it takes seconds; a reader that hangs is cut at 20 s per case
#: by the child itself, this is the guard around the guard)
CHILD_MEMORY_BYTES = 3 << 30
CHILD_TIMEOUT_S = 600


def _bounded_child():
    import resource
    resource.setrlimit(resource.RLIMIT_AS, (CHILD_MEMORY_BYTES, CHILD_MEMORY_BYTES))


@pytest.fixture(scope="module")
def corpus_read(tmp_path_factory):
    """(rows, expectations, folder): every (file, reader) outcome of the corpus, read in a
    child process."""
    folder = tmp_path_factory.mktemp("hostile") / "corpus"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1",
               OMP_NUM_THREADS="1")
    try:
        done = subprocess.run([sys.executable, "-m", "testdata.hostile_lens_files", str(folder)],
                              cwd=ROOT, env=env, capture_output=True, text=True,
                              timeout=CHILD_TIMEOUT_S, check=False,
                              preexec_fn=_bounded_child if os.name == "posix" else None)
        out, err, code = done.stdout, done.stderr, done.returncode
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err, code = f"timed out after {CHILD_TIMEOUT_S} s", None
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    expect = json.loads((folder / "expect.json").read_text()) \
        if (folder / "expect.json").exists() else {}
    return rows, expect, folder, code, err


def test_01_every_reader_loads_or_refuses_every_hostile_file_with_its_own_error(corpus_read):
    """Each corpus file through each reader (TOML, .zmx, pbrt .dat, .zmx system lines, gap
    tables, model.json, model header, the library's entry): loaded, or refused with the
    project's error; never another exception (a traceback in Blender, a broken picker) nor a
    hang. The reader of a file's own format does what the case says (the hostile ones are
    refused, naming the file, in one line; the good ones load), and the whole corpus reads
    within the child's bounds of memory and time."""
    from testdata.hostile_lens_files import OWN_READER, READERS
    rows, expect, _folder, code, err = corpus_read
    last = rows[-1]["file"] + " / " + rows[-1]["reader"] if rows else "nothing"
    assert code == 0, f"the corpus reader did not finish ({err[-2000:]}); last read: {last}"
    assert len(expect) > 100 and len(rows) == len(expect) * len(READERS)
    bad = [f"{r['file']} / {r['reader']}: {r['outcome']}: {r['message'][:200]}"
           for r in rows if r["outcome"] not in ("loaded", "refused")]
    assert not bad, "\n".join(bad)
    wrong = []
    for r in rows:
        if OWN_READER[Path(r["file"]).suffix] != r["reader"]:
            continue
        want = expect[r["file"]]
        if want == "load" and r["outcome"] != "loaded":
            wrong.append(f"{r['file']}: refused: {r['message'][:200]}")
        elif want == "refuse":
            if r["outcome"] != "refused":
                wrong.append(f"{r['file']}: loaded, but it is hostile")
            elif "\n" in r["message"] or r["file"].rsplit(".", 1)[0] not in r["message"]:
                wrong.append(f"{r['file']}: not one line naming the file: {r['message']!r}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("name,match", [
    ("mnum_20_digits.zmx", r"field 'MNUM': line \d+: MNUM: .* from 1 to 64"),
    ("mnum_100000_one_thic.zmx", r"field 'MNUM'"),
    ("focus_rows_40000.toml", r"field 'focus.distances_mm': 40000 positions; .* at most 64"),
    ("note_gaps_deep_list.zmx", r"field 'focus_gaps': line \d+: .* nests deeper than 4"),
    ("note_focal_length_mm_true.zmx", r"field 'focal_length_mm': expected a number, got a "
                                      r"boolean"),
    ("note_closest_focus_mm_NaN.zmx", r"field 'closest_focus_mm': line \d+: .*NaN"),
    ("focus_key_3_and_03.toml", r"field 'focus.thickness.06': '06' and '6' are both surface 6"),
    ("focus_key_superscript.toml", r"is not a surface number"),
    ("control_nul.zmx", r"line \d+: control character U\+0000"),
    ("material_vd_tiny.toml", r"surface 1, field 'material': Abbe number vd must be in "
                              r"\[5, 150\]"),
    ("focus_crosses_later.toml", r"at the \[focus\] table's position 2 \(2000 mm\): surfaces "
                                 r"6 and 7 cross"),
    ("zoom_crosses_later.zmx", r"field 'DISZ': at the \[zoom\] table's position 2 \(60 mm\): "
                               r"surfaces 5 and 6 cross"),
])
def test_02_the_refusals_name_the_field_and_say_why(corpus_read, name, match):
    """Issue 27's own cases, each refused by its format's reader naming the field (and the
    line where the format has lines)."""
    import re

    from testdata.hostile_lens_files import OWN_READER
    rows = corpus_read[0]
    row = next(r for r in rows if r["file"] == name
               and r["reader"] == OWN_READER[Path(name).suffix])
    assert row["outcome"] == "refused" and re.search(match, row["message"]), row


def _focusing():
    from testdata.focusing_lenses import rear_focusing_double_gauss
    return rear_focusing_double_gauss()


def test_03_a_lens_built_in_code_passes_the_same_checks():
    """validate_lens (the checks every loaded lens passes) on lenses built in code: a focus
    table whose second position crosses two surfaces, a V_d of 1e-10 (n = 1e10 at 380 nm), a
    closest focus of NaN and a focal length given as True are refused, each naming its
    field; the lens at every tabulated position of a good table passes."""
    from neurolens_addon.core.lensfile import validate_lens
    from neurolens_addon.core.prescription import Material
    lens = _focusing()
    validate_lens(lens)
    table = lens.focus_gaps
    cols = [list(c) for c in table.thickness_mm]
    cols[0][1] = 0.3                                  # the gap behind the stop, at 2 m
    crossing = dataclasses.replace(lens, focus_gaps=dataclasses.replace(
        table, thickness_mm=tuple(tuple(c) for c in cols)))
    with pytest.raises(LensError, match=r"at the \[focus\] table's position 2 .* cross"):
        validate_lens(crossing)
    glass = dataclasses.replace(lens.surfaces[0], material=Material.from_abbe(1.67, 1e-10))
    with pytest.raises(LensError, match=r"surface 1, field 'material': Abbe number vd"):
        validate_lens(lens.with_surfaces((glass,) + lens.surfaces[1:]))
    with pytest.raises(LensError, match=r"field 'closest_focus_mm'"):
        validate_lens(dataclasses.replace(lens, closest_focus_mm=math.nan))
    with pytest.raises(LensError, match=r"field 'focal_length_mm': expected a number"):
        validate_lens(dataclasses.replace(lens, focal_length_mm=True))


def test_04_tables_are_bounded_and_read_position_by_position():
    """A [focus] table of 40,000 rows (issue 27: over 10 minutes of a quadratic loop when a
    model is named) cannot be made, in a file or in code (core.variable_gaps.MAX_POSITIONS);
    at the cap, each tabulated position's lens stands at exactly its tabulated gaps, and the
    interpolant, now evaluated from a position's neighbours alone, is bit for bit the
    Fritsch-Carlson one computed from every slope of the table."""
    from neurolens_addon.core.variable_gaps import VariableGaps, pchip, position_lenses
    lens = _focusing()
    t5, t10 = lens.surfaces[5].thickness_mm, lens.surfaces[10].thickness_mm
    with pytest.raises(LensError, match="at most 64"):
        VariableGaps((math.inf,) + tuple(1e7 - k for k in range(1, 40_000)), (5,),
                     ((t5,) * 40_000,))
    from neurolens_addon.core.variable_gaps import MAX_POSITIONS
    n = MAX_POSITIONS
    rng = np.random.default_rng(27)
    steps = rng.uniform(0.0, 0.02, n - 1) * rng.choice([-1.0, 1.0, 0.0], n - 1)
    col5 = tuple(np.concatenate([[t5], t5 + np.cumsum(steps)]).tolist())
    col10 = tuple(t10 + (t5 - c) for c in col5)
    table = VariableGaps((math.inf,) + tuple(1e6 / (k + 1) for k in range(1, n)), (5, 10),
                         (col5, col10))
    moved = list(position_lenses(dataclasses.replace(lens, focus_gaps=table)))
    assert [k for _kind, k, _lens in moved] == list(range(1, n))
    for _kind, k, m in moved:
        assert m.surfaces[5].thickness_mm == col5[k] and m.surfaces[10].thickness_mm == col10[k]

    def reference(y, s):                 # the full-table Fritsch-Carlson of the original code
        y = np.asarray(y, dtype=np.float64)
        delta = np.diff(y)
        d = np.zeros(y.size)
        for k in range(1, y.size - 1):
            a, b = delta[k - 1], delta[k]
            d[k] = 0.0 if a * b <= 0.0 else 2.0 * a * b / (a + b)
        for k, (a, b) in ((0, (delta[0], delta[1])), (y.size - 1, (delta[-1], delta[-2]))):
            e = (3.0 * a - b) / 2.0
            if e * a <= 0.0:
                e = 0.0
            elif a * b <= 0.0 and abs(e) > abs(3.0 * a):
                e = 3.0 * a
            d[k] = e
        s = min(max(float(s), 0.0), y.size - 1.0)
        k = min(int(math.floor(s)), y.size - 2)
        t = s - k
        h = (2 * t ** 3 - 3 * t ** 2 + 1, t ** 3 - 2 * t ** 2 + t, -2 * t ** 3 + 3 * t ** 2,
             t ** 3 - t ** 2)
        return float(h[0] * y[k] + h[1] * d[k] + h[2] * y[k + 1] + h[3] * d[k + 1])
    for s in np.linspace(0.0, n - 1.0, 1001):
        assert pchip(col5, s) == reference(col5, s)
