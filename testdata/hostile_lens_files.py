"""A hostile corpus of lens files (issue 27), and every reader run over it.

`cases()` makes the corpus in memory from the repository's own writers (nothing large is
committed: the biggest case, a 40,000-row [focus] table, is ~0.8 MB and made when asked):
good files (a rear-focusing double Gauss in TOML, .zmx with our notes and .zmx read from its
configurations, a zoom in both, a pbrt .dat) and hostile variations of them: huge counts
(MNUM 1e8, 1e9, 20 and 5000 digits, 100,000 configurations with one THIC), deep JSON and TOML,
20-digit and 5000-digit numbers, NUL and other control characters inside lines, non-ASCII
digits, duplicate keys ("3" and "03", a NOTE key twice, a JSON key twice), booleans as
numbers, NaN and infinities, V_d near 0, every [focus] and [zoom] table (TOML, .zmx notes, .zmx
configurations) crossing at a later position, rows over the caps. Each case says what the
reader of its own suffix must do: "load" or "refuse" (a LensError naming the file).

`READERS` are every reader a lens file meets: the three formats by path (a copy of the file
under each suffix, as the picker meets a misnamed file), the .zmx system lines, the gap tables
(fed the document the file parses to, TOML or JSON), model.json, and the library's entry
(camera.lenses.load_lens_entry, what the picker lists). `read_corpus` runs each reader on each
file and records the outcome: "loaded", "refused" (the project's own error), "crash" (any
other exception: a traceback for a user) or "hang" (still running after the deadline, under
SIGALRM where there is one).

Run as `python -m testdata.hostile_lens_files FOLDER` it writes the corpus into FOLDER, reads
it and prints one JSON line per (file, reader) (tests/core/test_hostile_lens_files.py runs it
in a child process with bounded memory and time, so a reader that hangs or allocates without
end fails the test instead of the test run).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import shutil
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

#: a case (one reader on one file) still running after this many seconds is a hang
DEADLINE_S = 20.0


@dataclass(frozen=True)
class Case:
    name: str           # the file name, its suffix the format
    data: bytes
    expect: str         # "load" or "refuse", by the reader of its suffix


# ---------------------------------------------------------------- the good files

def _lenses():
    from neurolens_addon.camera.lenses import PRESETS_DIR
    from neurolens_addon.core.lensfile import load_lens
    from testdata.focusing_lenses import rear_focusing_double_gauss, zooming_double_gauss
    return (rear_focusing_double_gauss(), zooming_double_gauss(),
            load_lens(PRESETS_DIR / "double_gauss_50mm_f2.toml"))


def _pbrt(lens) -> str:
    rows = ["# the double Gauss as a pbrt RealisticCamera file",
            "# radius thickness index aperture_diameter"]
    for s in lens.surfaces:
        r = 0.0 if math.isinf(s.radius_mm) else s.radius_mm
        n = 1.0 if s.material.is_air else s.material.nd
        rows.append(f"{r!r} {s.thickness_mm!r} {n!r} {2.0 * s.semi_diameter_mm!r}")
    return "\n".join(rows) + "\n"


def _without_notes(zmx: str) -> str:
    """A .zmx of ours as another tool writes it: no NOTE lines, so the configurations are
    read (zemax_configs)."""
    return "\n".join(line for line in zmx.splitlines() if not line.startswith("NOTE")) + "\n"


def _sub(text: str, pattern: str, repl, count: int = 1) -> str:
    """The first match of `pattern` (multi-line) replaced: `repl` is literal text unless it
    refers to a group (\\1) or is a function."""
    if isinstance(repl, str) and "\\1" not in repl:
        literal = repl

        def repl(_m):
            return literal
    out, n = re.subn(pattern, repl, text, count=count, flags=re.MULTILINE)
    if n == 0:
        raise ValueError(f"corpus: no match for {pattern!r}")
    return out


def _note(zmx: str, key: str, value: str) -> str:
    """The .zmx text with its NOTE line of `key` set to the raw JSON text `value` (added when
    the file has none)."""
    line = f"NOTE 9 neurolens {key} {value}"
    if re.search(rf"^NOTE \d+ neurolens {key} ", zmx, flags=re.MULTILINE):
        return re.sub(rf"^NOTE \d+ neurolens {key} .*$", lambda _m: line, zmx, count=1,
                      flags=re.MULTILINE)
    return _sub(zmx, r"^SURF 0$", lambda _m: line + "\nSURF 0")


def _crossing_gap(lens, table):
    """(index in table.surfaces, a thickness) that makes its gap cross at the first position
    (checked with the first position's own check), for a table made to cross later."""
    from neurolens_addon.core.errors import LensError
    from neurolens_addon.core.lensfile import validate_lens
    for j, i in enumerate(table.surfaces):
        for t in (1e-3, 0.3, 1.0):
            surfaces = list(lens.surfaces)
            surfaces[i] = dataclasses.replace(surfaces[i], thickness_mm=t)
            try:
                validate_lens(dataclasses.replace(lens.with_surfaces(surfaces), focus_gaps=None,
                                                  zoom_gaps=None))
            except LensError as exc:
                if "cross" in str(exc):
                    return j, t
    raise ValueError(f"corpus: no gap of {lens.name} can be made to cross")


def _crossing_later(lens, key: str):
    """The lens with its `key` table's last position crossing (the first untouched)."""
    table = getattr(lens, key)
    j, t = _crossing_gap(lens, table)
    cols = [list(c) for c in table.thickness_mm]
    cols[j][-1] = t
    return dataclasses.replace(lens, **{key: dataclasses.replace(
        table, thickness_mm=tuple(tuple(c) for c in cols))})


def _focus_rows(toml: str, n: int) -> str:
    """The focusing lens's TOML with an n-row [focus] table (distances nearer and nearer, the
    columns holding their first value): n = 40,000 is issue 27's 785 KB file."""
    head = toml[:toml.index("[focus]")]
    m = re.search(r"thickness = \{ 6 = \[([^,]+),[^\]]*\], 11 = \[([^,]+),", toml)
    a, b = m.group(1), m.group(2)
    dist = ", ".join(["inf"] + [f"{1e7 - k:.1f}" for k in range(1, n)])
    return (head + f"[focus]\ndistances_mm = [{dist}]\n"
            + f"thickness = {{ 6 = [{', '.join([a] * n)}], 11 = [{', '.join([b] * n)}] }}\n")


def _deep(opening: str, closing: str, depth: int) -> str:
    return opening * depth + "1" + closing * depth


# ---------------------------------------------------------------- the corpus

def cases() -> list[Case]:
    """The corpus (module docstring)."""
    from neurolens_addon.core.lensfile import dump_lens, dump_zmx
    focus, zoom, plain = _lenses()
    toml_f, toml_z = dump_lens(focus), dump_lens(zoom)
    zmx_f, zmx_z = dump_zmx(focus), dump_zmx(zoom)
    cfg_f, cfg_z = _without_notes(zmx_f), _without_notes(zmx_z)
    dat = _pbrt(plain)
    out: list[Case] = []

    def add(name, text, expect="refuse"):
        out.append(Case(name, text if isinstance(text, bytes) else text.encode("utf-8"),
                        expect))

    # good files: each reader must load these
    add("good_focus.toml", toml_f, "load")
    add("good_zoom.toml", toml_z, "load")
    add("good_focus.zmx", zmx_f, "load")
    add("good_zoom.zmx", zmx_z, "load")
    add("good_focus_configs.zmx", cfg_f, "load")
    add("good_zoom_configs.zmx", cfg_z, "load")
    add("good_utf16.zmx", b"\xff\xfe" + zmx_f.encode("utf-16-le"), "load")
    add("good_plain.dat", dat, "load")
    add("good_64_rows.toml", _focus_rows(toml_f, 64), "load")
    # a name with control characters (TOML escapes them) is written to .zmx so that it loads
    odd = dataclasses.replace(plain, name="two\x00lines\nand\x1b[31m colour")
    add("good_odd_name.toml", dump_lens(odd), "load")
    add("good_odd_name.zmx", dump_zmx(odd), "load")

    # item 2: counts that allocate or loop before any check
    one_thic = _sub(cfg_f, r"^THIC 0 2 .*\n", "")
    for name, count in (("mnum_1e8", "100000000"), ("mnum_1e9", "1000000000"),
                        ("mnum_20_digits", "9" * 20), ("mnum_5000_digits", "9" * 5000),
                        ("mnum_100000_one_thic", "100000"), ("mnum_65", "65"),
                        ("mnum_negative", "-3"), ("mnum_zero", "0"),
                        ("mnum_arabic_digit", "\u0663"), ("mnum_superscript", "\u00b3"),
                        ("mnum_fraction", "2.5"), ("mnum_underscore", "1_0")):
        add(f"{name}.zmx", _sub(one_thic if "thic" in name else cfg_f, r"^MNUM \S+",
                                f"MNUM {count}"))
    add("thic_config_20_digits.zmx", _sub(cfg_f, r"^THIC 6 2 ", "THIC 6 " + "9" * 20 + " "))
    add("thic_surface_arabic.zmx", _sub(cfg_f, r"^THIC 6 2 ", "THIC \u0666 2 "))
    add("thic_value_nan.zmx", _sub(cfg_f, r"^THIC 6 2 \S+", "THIC 6 2 nan"))
    add("sdia_20_digits.zmx", _sub(cfg_z, r"^MNUM", "SDIA 6 " + "9" * 20 + " 9.0 0 0\nMNUM"))
    add("surf_300_blocks.zmx", zmx_f + "".join(f"SURF {k}\n  DIAM 1\n" for k in range(300)))
    add("parm_20_digits.zmx", _sub(zmx_f, r"^  TYPE STANDARD\n(  CURV 0.03)",
                                   r"  TYPE EVENASPH\n  PARM " + "9" * 20 + r" 1\n\1"))
    add("ftyp_20_digits.zmx", _sub(zmx_f, r"^FTYP .*$", "FTYP 0 0 " + "9" * 20 + " 3 0 0 0"))
    add("wavm_20_digits.zmx", _sub(zmx_f, r"^WAVM 1 ", "WAVM " + "9" * 20 + " "))
    add("pwav_huge.zmx", _sub(zmx_f, r"^PWAV .*$", "PWAV 1e30"))
    add("focus_rows_40000.toml", _focus_rows(toml_f, 40_000))
    add("focus_rows_65.toml", _focus_rows(toml_f, 65))
    rows = [float(x) for x in (1e6 - k for k in range(1, 100))]
    add("note_positions_100.zmx", _note(zmx_f, "focus_gaps", json.dumps(
        {"positions": ["inf"] + rows, "surfaces": [5],
         "thickness_mm": [[focus.surfaces[5].thickness_mm] * 100]})))

    # item 3: what used to escape as TypeError, OverflowError, RecursionError, ValueError
    for name, value in (
            ("note_gaps_string", '"abc"'),
            ("note_gaps_list", "[1, 2, 3]"),
            ("note_gaps_positions_string",
             '{"positions": "abc", "surfaces": [5], "thickness_mm": [[4.5, 3.0, 1.0]]}'),
            ("note_gaps_positions_dict",
             '{"positions": ["inf", {"a": 1}], "surfaces": [5], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_infinite",
             '{"positions": ["inf", 2000], "surfaces": [1e999], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_huge",
             '{"positions": ["inf", 2000], "surfaces": [1e300], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_20_digits", '{"positions": ["inf", 2000], "surfaces": ['
             + "9" * 20 + '], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_true",
             '{"positions": ["inf", 2000], "surfaces": [true], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_float",
             '{"positions": ["inf", 2000], "surfaces": [5.0], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surface_negative",
             '{"positions": ["inf", 2000], "surfaces": [-1], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_surfaces_twice",
             '{"positions": ["inf", 2000], "surfaces": [5, 5], '
             '"thickness_mm": [[4.5, 3.0], [4.5, 2.0]]}'),
            ("note_gaps_columns_missing",
             '{"positions": ["inf", 2000], "surfaces": [5, 10], "thickness_mm": [[4.5, 3]]}'),
            ("note_gaps_thickness_true", '{"positions": ["inf", 2000], "surfaces": [5], '
             '"thickness_mm": [[4.5, true]]}'),
            ("note_gaps_position_true", '{"positions": ["inf", true], "surfaces": [5], '
             '"thickness_mm": [[4.5, 3.0]]}'),
            ("note_gaps_position_nan", '{"positions": ["inf", NaN], "surfaces": [5], '
             '"thickness_mm": [[4.5, 3.0]]}'),
            ("note_gaps_position_huge_int", '{"positions": ["inf", ' + "9" * 400
             + '], "surfaces": [5], "thickness_mm": [[4.5, 3.0]]}'),
            ("note_gaps_position_5000_digits", '{"positions": ["inf", ' + "9" * 5000
             + '], "surfaces": [5], "thickness_mm": [[4.5, 3.0]]}'),
            ("note_gaps_key_twice", '{"positions": ["inf", 2000], "positions": ["inf", 900], '
             '"surfaces": [5], "thickness_mm": [[4.5, 3.0]]}'),
            ("note_gaps_deep_list", _deep("[", "]", 100_000)),
            ("note_gaps_deep_dict", _deep('{"a": ', "}", 50_000)),
            ("note_gaps_deep_in_column", '{"positions": ["inf", 2000], "surfaces": [5], '
             '"thickness_mm": [' + _deep("[", "]", 5000) + ']}')):
        add(f"{name}.zmx", _note(zmx_f, "focus_gaps", value))
    add("note_zoom_gaps_stop_string.zmx", _note(zmx_z, "zoom_gaps", json.dumps(
        {**json.loads(re.search(r"neurolens zoom_gaps (.*)$", zmx_z, re.MULTILINE).group(1)),
         "stop_semi_diameter": "wide"})))

    # item 5: the same value checks as the TOML reader
    for key, value in (("focal_length_mm", "true"), ("focal_length_mm", '"50"'),
                       ("focal_length_mm", "1e999"), ("focal_length_mm", "9" * 400),
                       ("focal_length_mm", "-50"), ("f_number", "false"),
                       ("f_number", "NaN"), ("f_number", "[2.0]"),
                       ("closest_focus_mm", "NaN"), ("closest_focus_mm", "-Infinity"),
                       ("closest_focus_mm", "0"), ("closest_focus_mm", "true"),
                       ("field_of_view_deg", "400"), ("field_of_view_deg", '"wide"'),
                       ("back_focus_mm", "{}"), ("name", "42"), ("name", '""'),
                       ("source", "[1]"), ("notes", "{\"a\": 1}")):
        tag = re.sub(r"\W", "", value)[:12] or "empty"
        add(f"note_{key}_{tag}.zmx", _note(zmx_f, key, value))
    add("note_key_twice.zmx", _sub(zmx_f, r"^(NOTE 3 neurolens focal_length_mm .*)$",
                                   r"\1\nNOTE 3 neurolens focal_length_mm 85.0"))
    add("note_value_control_character.zmx",
        _sub(zmx_f, r"^NOTE 0 neurolens name .*$", 'NOTE 0 neurolens name "a\\u0000b"'),
        "load")
    # a NUL (or another control character) in place of a line break merges two surfaces: the
    # double Gauss's surfaces 2 and 3 read as one gave a lens of EFL 189 mm, not 50.36
    zmx_p = dump_zmx(plain)
    for name, char in (("nul", "\x00"), ("vertical_tab", "\x0b"), ("form_feed", "\x0c"),
                       ("file_separator", "\x1c"), ("c1_next_line", "\x85"),
                       ("line_separator", "\u2028"), ("escape", "\x1b"), ("delete", "\x7f")):
        add(f"control_{name}.zmx", _sub(zmx_p, r"\nSURF 3\n", f"{char}SURF 3\n"))
    add("control_nul_in_dat.dat", _sub(dat, r"\n(\S+ 4\.5 )", "\x00" + r"\1"))
    add("control_vertical_tab.dat", _sub(dat, r"\n(\S+ 4\.5 )", "\x0b" + r"\1"))
    add("nul_in_toml.toml", _sub(toml_f, r"\nf_number", "\x00f_number"))
    for name, token in (("arabic", "\u0664.\u0665"), ("fullwidth", "\uff14.\uff15"),
                        ("underscore", "4_5.0"), ("superscript", "\u00b3")):
        add(f"disz_{name}_digits.zmx", _sub(zmx_f, r"^  DISZ 4\.5$", f"  DISZ {token}"))
        add(f"dat_{name}_digits.dat", _sub(dat, r" 4\.5 ", f" {token} "))
    for name, token in (("20_digits", "9" * 20), ("400_digits", "9" * 400),
                        ("5000_digits", "9" * 5000)):
        add(f"curv_{name}.zmx", _sub(zmx_f, r"^  CURV 0\.0339\S*", f"  CURV {token}"))
        add(f"dat_{name}.dat", _sub(dat, r" 4\.5 ", f" {token} "))
        # (f/1e20 is a number: a 20-digit TOML integer loads; 400 digits overflow a float)
        add(f"toml_{name}.toml", _sub(toml_f, r"^f_number = .*$", f"f_number = {token}"),
            "load" if name == "20_digits" else "refuse")
    add("glas_vd_tiny.zmx", _sub(zmx_f, r"GLAS ___BLANK 1 0 1\.67 47\.1",
                                 "GLAS ___BLANK 1 0 1.67 1e-10"))
    add("glas_nd_huge.zmx", _sub(zmx_f, r"GLAS ___BLANK 1 0 1\.67 47\.1",
                                 "GLAS ___BLANK 1 0 45871 47.1"))
    for name, material in (("vd_tiny", "{ nd = 1.67, vd = 1e-10 }"),
                           ("vd_one", "{ nd = 1.67, vd = 1.0 }"),
                           ("vd_huge", "{ nd = 1.67, vd = 1e6 }"),
                           ("nd_huge", "{ nd = 45871.0, vd = 47.1 }"),
                           ("named_vd_tiny", '{ name = "XQ-1", nd = 1.67, vd = 1e-10 }')):
        add(f"material_{name}.toml", _sub(toml_f, r"^material = \{ nd = 1\.67, vd = 47\.1 \}",
                                          f"material = {material}"))
    add("material_vd_tiny.dat", dat)   # (pbrt has no V_d: the good file under another name)
    out[-1] = dataclasses.replace(out[-1], expect="load")

    # item 5: tables checked at every position; duplicate surface keys
    later_f = _crossing_later(focus, "focus_gaps")
    later_z = _crossing_later(zoom, "zoom_gaps")
    add("focus_crosses_later.toml", dump_lens(later_f))
    add("zoom_crosses_later.toml", dump_lens(later_z))
    add("focus_crosses_later.zmx", dump_zmx(later_f))
    add("zoom_crosses_later.zmx", dump_zmx(later_z))
    add("focus_crosses_later_configs.zmx", _without_notes(dump_zmx(later_f)))
    add("zoom_crosses_later_configs.zmx", _without_notes(dump_zmx(later_z)))
    for name, keys in (("3_and_03", "6 = [4.5, 2.93], 06 = [4.5, 2.0]"),
                       ("superscript", '"\u00b3" = [4.5, 2.93]'),
                       ("arabic", '"\u0666" = [4.5, 2.93]'),
                       ("fullwidth", '"\uff16" = [4.5, 2.93]'),
                       ("20_digits", '"' + "9" * 20 + '" = [4.5, 2.93]'),
                       ("zero", "0 = [4.5, 2.93]"), ("signed", '"+6" = [4.5, 2.93]'),
                       ("spaced", '" 6" = [4.5, 2.93]')):
        add(f"focus_key_{name}.toml", _sub(toml_f, r"^thickness = \{ 6 = .*$",
                                           f"thickness = {{ {keys} }}"))
    for name, dist in (("true", "[inf, true]"), ("nan", "[inf, nan]"), ("zero", "[inf, 0]"),
                       ("rising", "[inf, 900.0, 2000.0]"), ("no_inf", "[3000.0, 2000.0]"),
                       ("one", "[inf]"), ("string", '"inf, 2000"'),
                       ("20_digits", "[inf, " + "9" * 20 + "]"),   # (1e20 mm: a number)
                       ("5000_digits", "[inf, " + "9" * 5000 + "]"),
                       ("deep", "[inf, " + _deep("[", "]", 5000) + "]")):
        add(f"focus_distances_{name}.toml", _sub(toml_f, r"^distances_mm = .*$",
                                                 f"distances_mm = {dist}"),
            "load" if name == "20_digits" else "refuse")
    add("deep_toml_array.toml", toml_f + "extra = " + _deep("[", "]", 100_000) + "\n")
    add("deep_toml_table.toml", toml_f.replace("[focus]", "x = " + _deep("{a=", "}", 20_000)
                                               + "\n[focus]"))
    add("deep_dotted_key.toml", "a" + ".a" * 10_000 + " = 1\n" + toml_f)
    add("dat_rows_300.dat", dat + "10.0 1.0 1.5 5.0\n" * 300)
    # a first element of air 4e22 mm long: the entrance pupil's size underflows to 0 (a
    # ZeroDivisionError in the paraxial data, found by fuzzing)
    add("dat_first_gap_4e22.dat", _sub(dat, r"^29\.475 \S+ \S+ (\S+)\n\S+ \S+ \S+ \S+\n",
                                       r"29.475 39999999999999999999912 1.0 \1\n"))

    # JSON files: model.json's reader meets them (the lens readers refuse the suffix)
    add("deep_list.json", _deep("[", "]", 100_000))
    add("deep_dict.json", _deep('{"a": ', "}", 50_000))
    add("int_5000_digits.json", '{"format": ' + "9" * 5000 + "}")
    add("nan.json", '{"format": NaN}')
    add("not_json.json", b"\xff\xfe\x00garbage")
    return out


def write_corpus(folder) -> list[Path]:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for case in cases():
        p = folder / case.name
        p.write_bytes(case.data)
        paths.append(p)
    (folder / "expect.json").write_text(json.dumps({c.name: c.expect for c in cases()}))
    return paths


# ---------------------------------------------------------------- the readers

def _as(path: Path, scratch: Path, suffix: str) -> Path:
    p = scratch / (path.stem + suffix)
    shutil.copyfile(path, p)
    return p


def _lens_reader(suffix):
    def read(path: Path, scratch: Path):
        from neurolens_addon.core.lensfile import load_lens
        return load_lens(path if path.suffix == suffix else _as(path, scratch, suffix))
    return read


def _zmx_system(path: Path, _scratch):
    from neurolens_addon.core.lensfields import Where
    from neurolens_addon.core.lensfile import loads_zmx_system
    from neurolens_addon.core.lensfile.source import read_bytes
    from neurolens_addon.core.lensfile.zemax import decode_zmx
    return loads_zmx_system(decode_zmx(read_bytes(path), Where(path)), path=str(path))


def _gap_tables(path: Path, _scratch):
    """The document the file parses to (TOML through the TOML reader's own prechecks and
    parser, else JSON: a .zmx NOTE value) as a [focus] and a [zoom] table of the double Gauss;
    a file that parses as neither has nothing to feed."""
    from neurolens_addon.camera.lenses import PRESETS_DIR
    from neurolens_addon.core.errors import LensError
    from neurolens_addon.core.lensfields import Where
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.lensfile.gap_tables import read_gap_table
    from neurolens_addon.core.lensfile.toml_reader import _parse_toml, _precheck_text
    from neurolens_addon.core.lensfile.zemax import _gaps
    surfaces = list(load_lens(PRESETS_DIR / "double_gauss_50mm_f2.toml").surfaces)
    where = Where(path)
    text = path.read_bytes().decode("utf-8", "replace")
    try:
        _precheck_text(text, where)
        doc = _parse_toml(text, where)
    except LensError:
        doc = None
    if doc is not None:
        for kind in ("focus", "zoom"):
            read_gap_table(doc, kind, where, surfaces)
        return "toml"
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        return "neither"
    for key in ("focus_gaps", "zoom_gaps"):
        _gaps(value, where, key, surfaces)
    return "json"


def _model_folder(path: Path, scratch: Path) -> Path:
    folder = scratch / f"{path.stem}.neurolens"
    folder.mkdir(exist_ok=True)
    shutil.copyfile(path, folder / "model.json")
    return folder


def _model_json(path: Path, scratch: Path):
    from neurolens_addon.neural.modelfile import read_model_json
    return read_model_json(_model_folder(path, scratch))


def _model_header(path: Path, scratch: Path):
    from neurolens_addon.neural.modelfile import clear_header_cache, read_header
    clear_header_cache()
    return read_header(_model_folder(path, scratch))


def _library_entry(path: Path, _scratch):
    from neurolens_addon.camera.lenses import load_lens_entry
    return load_lens_entry(path)


READERS = {
    "toml": _lens_reader(".toml"),
    "zmx": _lens_reader(".zmx"),
    "dat": _lens_reader(".dat"),
    "zmx_system": _zmx_system,
    "gap_tables": _gap_tables,
    "model_json": _model_json,
    "model_header": _model_header,
    "library_entry": _library_entry,
}
#: the reader that must do what a case expects, by suffix
OWN_READER = {".toml": "toml", ".zmx": "zmx", ".dat": "dat", ".json": "model_json"}


class _Hang(BaseException):
    """Raised by SIGALRM in a case that runs past its deadline."""


def _alarm(_signum, _frame):
    raise _Hang()


def read_one(reader: str, path: Path, scratch: Path, deadline_s: float = DEADLINE_S) -> dict:
    """One reader on one file: {file, reader, outcome, seconds, message} (module docstring)."""
    from neurolens_addon.core.errors import NeuroLensError
    timed = hasattr(signal, "setitimer")
    t0 = time.perf_counter()
    if timed:
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, deadline_s)
    try:
        READERS[reader](path, scratch)
        outcome, message = "loaded", ""
    except _Hang:
        outcome, message = "hang", f"still running after {deadline_s:g} s"
    except NeuroLensError as exc:
        outcome, message = "refused", str(exc)
    except BaseException as exc:      # (a crash is what is counted)
        if isinstance(exc, KeyboardInterrupt):
            raise
        outcome, message = "crash", f"{type(exc).__name__}: {exc}"
    finally:
        if timed:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
    return {"file": path.name, "reader": reader, "outcome": outcome,
            "seconds": time.perf_counter() - t0, "message": message[:2000]}


def read_corpus(folder, scratch, deadline_s: float = DEADLINE_S, report=None) -> list[dict]:
    """Every reader on every corpus file in `folder` (scratch: a folder for copies)."""
    out = []
    for path in sorted(Path(folder).iterdir()):
        if path.name == "expect.json":
            continue
        for reader in READERS:
            row = read_one(reader, path, Path(scratch), deadline_s)
            out.append(row)
            if report is not None:
                report(row)
    return out


def main(argv=None) -> int:
    import tempfile
    argv = sys.argv[1:] if argv is None else argv
    folder = Path(argv[0])
    write_corpus(folder)
    with tempfile.TemporaryDirectory() as scratch:
        read_corpus(folder, scratch, report=lambda row: print(json.dumps(row), flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
