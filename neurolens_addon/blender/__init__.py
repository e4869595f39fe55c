"""bpy glue only: preferences, properties, panel, operators, sync handlers, registration.

A camera's settings are read in one place (camera_reader) and resolved by the pure
neurolens_addon.camera package; camera_state is the panel's view of the result, sync keeps the
Cycles camera in step, render_engine and engine_registration are the NEUROLENS engine's glue.

register() / unregister() are symmetric and idempotent per cycle: every class, the Camera
pointer property, the preview collection and the handlers added by register() are removed
by unregister(), and module-level caches are emptied, so the add-on can be enabled and
disabled any number of times in one Blender session.
"""

from ..camera import lru, models
from . import (camera_reader, engine_registration, library, operators, panel, preferences,
               properties, sync, thumbnails)

# Registration order: what others refer to first (preferences, the property group), handlers
# last; unregister() runs it backwards.
_MODULES = (preferences, thumbnails, properties, operators, panel, sync)


def register():
    done = []
    try:
        for module in _MODULES:
            module.register()
            done.append(module)
    except Exception:
        for module in reversed(done):   # leave nothing half-registered behind
            try:
                module.unregister()
            except Exception as exc:  # noqa: BLE001 - the first error is the one to raise
                print(f"NeuroLens: while undoing a failed register: {exc}")
        raise
    engine_registration.register()


def unregister():
    engine_registration.unregister()
    errors = []
    for module in reversed(_MODULES):
        try:
            module.unregister()
        except Exception as exc:  # noqa: BLE001 - unregister all we can, then report
            errors.append(f"{module.__name__}: {exc}")
    lru.clear_all()
    models.forget()
    camera_reader.forget()
    library.clear_cache()
    if errors:
        raise RuntimeError("NeuroLens did not unregister cleanly: " + "; ".join(errors))
