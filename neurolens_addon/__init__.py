"""NeuroLens for Blender: real camera lenses, exact and learned.

The package imports nothing from Blender at module level, so that `core` (pure numpy) and the
trainer can use it outside Blender; `register`/`unregister` load the bpy glue on demand.
"""


def register():
    from .blender import register as _register
    _register()


def unregister():
    from .blender import unregister as _unregister
    _unregister()
