"""The project's own error types.

Every error raised for bad input names where the problem is (file, line or surface, field) and
what was expected, so a user can fix the file without reading our code.
"""

from __future__ import annotations


class NeuroLensError(Exception):
    """Base class of every error this project raises on purpose."""


class LensError(NeuroLensError, ValueError):
    """A lens prescription is malformed or unphysical.

    `path` is the file (or None for an in-memory lens), `surface` the 1-based surface number in
    the file (None when the problem is not about one surface), `field` the offending key.
    """

    def __init__(self, message: str, *, path: str | None = None, surface: int | None = None,
                 field: str | None = None):
        self.path = path
        self.surface = surface
        self.field = field
        where = []
        if path:
            where.append(str(path))
        if surface is not None:
            where.append(f"surface {surface}")
        if field:
            where.append(f"field '{field}'")
        prefix = ": ".join([", ".join(where)]) + ": " if where else ""
        super().__init__(prefix + message)


class GlassError(NeuroLensError, KeyError):
    """An unknown glass name, or a glass catalog entry that cannot be used."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0]) if self.args else ""


class FocusError(NeuroLensError, ValueError):
    """A focus distance the lens cannot reach (nearer than its closest focus, or behind it)."""


class ApertureError(NeuroLensError, ValueError):
    """An aperture setting that cannot be used (f-number wider than the lens, bad blade count,
    unreadable mask image)."""


class ModelError(NeuroLensError, ValueError):
    """A learned-lens model that cannot be used: unreadable or incomplete model.json, wrong
    shapes, ONNX files that are truncated, foreign or not the graph model.json describes, or a
    model trained for another lens. `path` is the offending file, `field` the key inside it."""

    def __init__(self, message: str, *, path: str | None = None, field: str | None = None):
        self.path = None if path is None else str(path)
        self.field = field
        where = [w for w in (self.path, f"field '{field}'" if field else None) if w]
        super().__init__((", ".join(where) + ": " if where else "") + message)
