"""OSL source text helpers: float32 literals, constant arrays, indented blocks.

Cycles evaluates OSL in float32, so every constant is written as the float32 nearest to the
float64 value, in the shortest decimal form that reads back as that float32 (numpy's
round-trip repr). Formatting is a pure function of the values, so the same camera always
produces byte-identical source (the Blender glue compares the text to skip recompiling).
"""

from __future__ import annotations

import math

import numpy as np

LINE_WIDTH = 100


def flt(x) -> str:
    """A float32 OSL literal for x (always with '.' or an exponent, so OSL reads a float)."""
    v = float(x)
    if not math.isfinite(v):
        raise ValueError(f"cannot write a non-finite constant ({v!r}) into OSL source")
    s = str(np.float32(v))
    if s in ("inf", "-inf", "nan"):
        raise ValueError(f"constant {v!r} overflows float32")
    if "." not in s and "e" not in s:
        s += ".0"
    return s


def integer(x) -> str:
    return str(int(x))


def _wrap(items: list[str], indent: str) -> list[str]:
    lines, line = [], indent
    for i, it in enumerate(items):
        piece = it + ("," if i < len(items) - 1 else "")
        if len(line) + len(piece) + 1 > LINE_WIDTH and line.strip():
            lines.append(line.rstrip())
            line = indent
        line += piece + " "
    if line.strip():
        lines.append(line.rstrip())
    return lines


def _array(kind: str, name: str, vals: list[str], comment: str | None) -> list[str]:
    if not vals:
        raise ValueError(f"OSL array {name} would be empty")
    out = [f"// {comment}"] if comment else []
    out.append(f"{kind} {name}[{len(vals)}] = {{")
    out += _wrap(vals, "    ")
    out.append("};")
    return out


def float_array(name: str, values, comment: str | None = None) -> list[str]:
    """`float NAME[n] = { ... };` lines (OSL folds never-written initialised arrays to
    constants)."""
    vals = [flt(v) for v in np.asarray(values, dtype=np.float64).ravel()]
    return _array("float", name, vals, comment)


def int_array(name: str, values, comment: str | None = None) -> list[str]:
    return _array("int", name, [integer(v) for v in np.asarray(values).ravel()], comment)


def indent(lines, level: int = 1) -> list[str]:
    pad = "    " * level
    return [(pad + ln) if ln else ln for ln in lines]


def comment_block(text: str) -> list[str]:
    return ["// " + ln if ln else "//" for ln in text.splitlines()]


def comment_text(text) -> str:
    """`text` made safe inside a `//` comment of generated code: printable ASCII only. A
    newline, carriage return, NUL or Unicode line break would end the comment and let a file's
    text (a lens name, a model's stage name) into the code; a backslash at a line's end would
    continue the comment over the next line of code. Other characters become '?', backslashes
    '/'."""
    return "".join(c if " " <= c <= "~" and c != "\\" else ("/" if c == "\\" else "?")
                   for c in str(text))
