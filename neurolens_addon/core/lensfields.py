"""Values in lens files: reading typed fields with errors that point at the file, the surface
and the field, and writing values back as TOML literals.

Every reader (our TOML format, the pbrt importer, the value checks, each surface kind's own
keys) reports problems through `Where.error`, which builds a LensError whose message starts
with the file, the 1-based surface number and the field, and adds where that surface starts in
the file and, under `scale`, that the lengths shown are scaled. `SurfaceFields` is the same
bound to one surface: what a surface kind receives to read or check its keys.
"""

from __future__ import annotations

import copy
import difflib
import math
import re

from .errors import LensError


_LINE_BREAKS = re.compile("[\r\n\x0b\x0c\x1c-\x1e\x85\u2028\u2029]+")


class Where:
    """Where errors point: the file, how surfaces map to lines, and how fields are spelt."""

    def __init__(self, path, *, surface_lines=None, fields=None, line_word="starts at line",
                 scale=1.0, context=None):
        self.path = None if path is None else str(path)
        self.surface_lines = surface_lines  # 0-based surface index -> 1-based line, or None
        self.fields = fields or {}
        self.line_word = line_word
        self.scale = scale
        self.context = context              # what every message starts with, or None

    def within(self, context: str) -> Where:
        """The same, every message starting with `context` (e.g. "at [focus] position 2")."""
        out = copy.copy(self)
        out.context = context
        return out

    def field(self, name):
        return self.fields.get(name, name)

    def error(self, message, *, surface=None, field=None, scaled=False):
        """A LensError; `surface` is the 0-based index (reported 1-based)."""
        hints = []
        if surface is not None and self.surface_lines and 0 <= surface < len(self.surface_lines):
            hints.append(f"surface {surface + 1} {self.line_word} {self.surface_lines[surface]}")
        if scaled and self.scale != 1.0:
            hints.append(f"lengths shown after scale = {self.scale:g}")
        if hints:
            message = f"{message} ({'; '.join(hints)})"
        if self.context:
            message = f"{self.context}: {message}"
        # one line, whatever a file put in the names and keys it quotes
        message = _LINE_BREAKS.sub(" ", message)
        return LensError(message, path=self.path,
                         surface=None if surface is None else surface + 1,
                         field=None if field is None else self.field(field))


class SurfaceFields:
    """`Where` bound to one surface (0-based `index`): what a surface kind reads and checks its
    keys with. `scale` multiplies the lengths read from the file."""

    def __init__(self, where: Where, index: int):
        self.where = where
        self.index = index

    @property
    def scale(self) -> float:
        return self.where.scale

    def error(self, message, field, *, scaled=False) -> LensError:
        return self.where.error(message, surface=self.index, field=field, scaled=scaled)

    def number(self, value, field, *, allow_inf=False) -> float:
        return number(value, self.where, surface=self.index, field=field, allow_inf=allow_inf)


def describe(value) -> str:
    """A value's TOML type in words, with the value when short."""
    if isinstance(value, bool):
        kind = "a boolean"
    elif isinstance(value, int):
        kind = "an integer"
    elif isinstance(value, float):
        kind = "a float"
    elif isinstance(value, str):
        kind = "a string"
    elif isinstance(value, dict):
        return "a table"
    elif isinstance(value, list):
        return "an array"
    else:
        return f"a {type(value).__name__}"
    text = repr(value) if not isinstance(value, bool) else str(value).lower()
    if len(text) > 40:
        text = text[:37] + "..."
    return f"{kind} ({text})"


def unknown_key_message(key, allowed, what) -> str:
    close = difflib.get_close_matches(str(key), list(allowed), n=1, cutoff=0.6)
    hint = f"; did you mean '{close[0]}'?" if close else ""
    return (f"unknown key '{key}' in {what}{hint} (allowed: {', '.join(allowed)})")


def number(value, where, *, surface=None, field, allow_inf=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise where.error(f"expected a number, got {describe(value)}", surface=surface,
                          field=field)
    try:
        x = float(value)
    except OverflowError:
        # (an integer's digits are not printed: str() of 4300 or more of them raises)
        raise where.error(f"an integer of about {int(value.bit_length() * 0.30103) + 1} digits "
                          "is too large for a number", surface=surface, field=field) from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise where.error(f"expected a finite number, got {x}", surface=surface, field=field)
    return x


def string(value, where, *, field, nonempty=True) -> str:
    if not isinstance(value, str):
        raise where.error(f"expected a string, got {describe(value)}", field=field)
    if nonempty and not value.strip():
        raise where.error("expected a non-empty string", field=field)
    return value


def check_keys(table, allowed, required, where, what, *, surface=None):
    for key in table:
        if key not in allowed:
            raise where.error(unknown_key_message(key, allowed, what), surface=surface,
                              field=str(key))
    for key in required:
        if key not in table:
            raise where.error(f"missing required key '{key}' in {what}", surface=surface,
                              field=key)


# ---- writing ----------------------------------------------------------------------------------
def toml_string(s: str) -> str:
    out = ['"']
    for ch in s:
        o = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ch == "\r":
            out.append("\\r")
        elif o < 0x20 or o == 0x7F:
            out.append(f"\\u{o:04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_float(x) -> str:
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)
