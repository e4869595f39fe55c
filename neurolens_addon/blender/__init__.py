"""bpy glue only: preferences, properties, panels, operators, registration."""

from . import preferences

_MODULES = (preferences,)


def register():
    for module in _MODULES:
        module.register()


def unregister():
    for module in reversed(_MODULES):
        module.unregister()
