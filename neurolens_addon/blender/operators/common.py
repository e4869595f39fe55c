"""What the operators share: the camera they work on, and their on/off options.

The camera is the active object when it is a camera, else the scene's camera; an operator on
camera data uses the context's camera data first (the Properties editor's camera).
"""

from __future__ import annotations

from bpy.props import BoolProperty


def camera_object(context):
    """The camera the operator works on: the active object if it is a camera, else the
    scene's camera."""
    obj = getattr(context, "object", None) or getattr(context, "active_object", None)
    if obj is not None and obj.type == "CAMERA":
        return obj
    scene = getattr(context, "scene", None)
    cam = scene.camera if scene is not None else None
    return cam if cam is not None and cam.type == "CAMERA" else None


def camera_data(context):
    """The camera data the operator works on: the context's (the Properties editor's camera),
    else camera_object's."""
    cam = getattr(context, "camera", None)
    if cam is not None:
        return cam
    obj = camera_object(context)
    return obj.data if obj is not None else None


def option(name: str, description: str, **keywords):
    """An operator option that is off unless asked for (a BoolProperty, default False)."""
    return BoolProperty(name=name, default=False, description=description, **keywords)
