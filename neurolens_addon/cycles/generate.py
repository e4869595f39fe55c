"""generate_osl(spec): the OSL source of one Cycles custom camera, deterministic in the spec."""

from __future__ import annotations

import hashlib

from .spec import CameraSpec, validate


def generate_osl(spec: CameraSpec) -> str:
    """OSL source text of the camera `spec` describes (same spec -> same text).

    Raises the project's errors (core.errors) for specs that cannot be honoured: a lens
    without a stop, an f-number wider than the lens, a model for another lens, etc.
    """
    validate(spec)
    if spec.model == "exact":
        from .exact import generate_exact
        return generate_exact(spec)
    if spec.model == "thin":
        from .thin import generate_thin
        return generate_thin(spec)
    from .learned import generate_learned
    return generate_learned(spec)


def source_hash(source: str) -> str:
    """Short stable digest of a shader source (what the glue stores to skip recompiling)."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()[:16]
