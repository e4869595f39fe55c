"""Lines and numbers of the line-based lens formats (Zemax `.zmx`, pbrt `.dat`).

Both formats are read a line at a time and a token at a time, so what counts as a line and as
a number is decided here, once:
- a line may not hold a control character (C0 but tab, DEL, C1) nor a Unicode line or
  paragraph separator: Python's splitlines() breaks lines at some of them (\\v, \\f, \\x1c,
  \\x85, U+2028) where an editor shows none, and a NUL in place of a line break merges two
  lines (two .zmx surfaces into one). `check_lines` refuses the first, naming its line.
- a number is ASCII: `[+-]digits[.digits][e[+-]digits]` (float() would also take Arabic,
  full-width and other Unicode digits, `1_000`, `nan` and `infinity`); `INFINITY` / `inf` only
  where the caller allows it.
- an integer (a count, an index) is `[+-]` and at most MAX_INTEGER_DIGITS ASCII digits, so no
  conversion of a 5000-digit token is tried and every count is bounded before it is used.
"""

from __future__ import annotations

import math
import re

#: integers (counts, indices) in a line-based lens file have at most this many digits
MAX_INTEGER_DIGITS = 9

_BAD_CHARACTER = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u2028\u2029]")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z", re.ASCII)
_INTEGER = re.compile(rf"[+-]?[0-9]{{1,{MAX_INTEGER_DIGITS}}}\Z", re.ASCII)
_INFINITY = ("inf", "+inf", "infinity", "+infinity")


def check_lines(text: str, where) -> None:
    """LensError at the first control character in `text`, naming its line (module
    docstring); \\r and \\n end lines, tabs separate tokens."""
    m = _BAD_CHARACTER.search(text)
    if m is None:
        return
    line = text.count("\n", 0, m.start()) + 1
    raise where.error(f"line {line}: control character U+{ord(m.group()):04X} inside the "
                      "line; a lens file's lines hold printable text (was the file damaged?)")


def to_float(token: str, *, allow_inf: bool = False) -> float | None:
    """The number an ASCII token writes (an overflow reads as infinity), or None."""
    if _NUMBER.match(token):
        return float(token)
    if allow_inf and token.lower() in _INFINITY:
        return math.inf
    return None


def to_int(token: str) -> int | None:
    """The integer an ASCII token of at most MAX_INTEGER_DIGITS digits writes, or None."""
    return int(token) if _INTEGER.match(token) else None


def shown(token: str) -> str:
    """A token as an error message quotes it: printable, at most 20 characters."""
    s = "".join(c if c.isprintable() else "?" for c in token)
    return s if len(s) <= 20 else s[:17] + "..."
