"""JSON the project prints or writes is JSON: no NaN, no Infinity.

Python's json module writes NaN, Infinity and -Infinity by default, which JSON does not have
(other readers refuse the file). `dumps` writes every non-finite float as null (a printout:
"not finite" is what null says there); `dumps_strict` refuses one (a file the project reads
back, such as model.json, must never hold one).
"""

from __future__ import annotations

import json
import math


def _finite(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def dumps(value, **kw) -> str:
    """JSON text with non-finite floats written as null."""
    return json.dumps(_finite(value), allow_nan=False, **kw)


def dumps_strict(value, **kw) -> str:
    """JSON text; ValueError naming the problem if any float is not finite."""
    try:
        return json.dumps(value, allow_nan=False, **kw)
    except ValueError:
        raise ValueError("refusing to write NaN or Infinity into a JSON file") from None
