"""The registry of surface kinds: kind name -> SurfaceShape subclass.

A kind registers itself with the `@register` class decorator; lens files name it with
`kind = "..."` in a [[surface]] table (a table without `kind` is read as DEFAULT_KIND, which
covers the rotationally symmetric surfaces of the first file format).
"""

from __future__ import annotations

import difflib

from ..errors import LensError
from ..lensfields import describe

#: the kind a [[surface]] table without `kind` is read as
DEFAULT_KIND = "even_asphere"

_KINDS: dict = {}


def register(cls):
    """Class decorator: make `cls` (a SurfaceShape subclass with a unique `kind`) known."""
    name = cls.kind
    if not name or not isinstance(name, str):
        raise TypeError(f"{cls.__name__} has no kind name")
    if name in _KINDS and _KINDS[name] is not cls:
        raise ValueError(f"surface kind '{name}' is registered twice "
                         f"({_KINDS[name].__name__} and {cls.__name__})")
    _KINDS[name] = cls
    return cls


def kinds() -> tuple[str, ...]:
    """The registered kind names, in registration order."""
    return tuple(_KINDS)


def kind_classes() -> tuple:
    """The registered classes, in registration order."""
    return tuple(_KINDS.values())


def kind_class(name, *, error=None, path=None, surface=None):
    """The class registered as `name`. An unknown name (or not a string) raises LensError with
    field 'kind': from `error(message, "kind")` when given (a lensfields.SurfaceFields.error,
    which knows the file and surface), else naming `path` and the 1-based `surface`."""
    cls = _KINDS.get(name) if isinstance(name, str) else None
    if cls is not None:
        return cls
    known = ", ".join(sorted(_KINDS))
    if isinstance(name, str):
        close = difflib.get_close_matches(name, list(_KINDS), n=1, cutoff=0.6)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        message = f"unknown surface kind '{name}'{hint} (known kinds: {known})"
    else:
        message = f"expected a string naming a surface kind ({known}), got {describe(name)}"
    if error is not None:
        raise error(message, "kind")
    raise LensError(message, path=None if path is None else str(path), surface=surface,
                    field="kind")
