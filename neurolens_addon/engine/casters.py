"""The scene caster a frame uses: Intel Embree (embree_cast) or Blender's own BVH
(scene_cast), as the render settings name it."""

from __future__ import annotations

from .embree_cast import EmbreeCaster, EmbreeUnavailable
from .scene_cast import SceneCaster

INTERSECTORS = ("AUTO", "BLENDER", "EMBREE")


def make_caster(scene, depsgraph, intersector: str = "AUTO", should_stop=None, notes=None):
    """The caster `intersector` names: BLENDER, EMBREE, or AUTO (Embree when `embreex` is
    installed). Without embreex, or for a scene Embree cannot take, Blender's BVH is used and
    a note says why (appended to `notes`)."""
    choice = str(intersector).upper()
    if choice not in INTERSECTORS:
        raise ValueError(f"intersector must be one of {', '.join(INTERSECTORS)}, got "
                         f"{intersector!r}")
    if choice != "BLENDER":
        try:
            return EmbreeCaster(depsgraph, should_stop=should_stop)
        except EmbreeUnavailable as exc:
            if notes is not None:
                notes.append(f"Ray casts through Blender's BVH: {exc}")
    return SceneCaster(scene, depsgraph, should_stop=should_stop)
