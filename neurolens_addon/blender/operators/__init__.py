"""Operators: load a user's lens file (checked first), focus on a picked point, train a model
for the scene (and cancel that), write a camera's ST-maps; one module each, sharing `common`.

The work is done by plain functions (`load_lens_file`, `focus_on_point`, `pick_point`,
`training_outcome`) that the operators call, so scripts and tests can use them without a
window; they are importable from here.
"""

from __future__ import annotations

import bpy

from .. import training
from . import focus, lens_file, scene_training, st_maps
from .focus import focus_on_point, pick_point
from .lens_file import load_lens_file
from .scene_training import training_outcome
from .st_maps import write_st_maps

__all__ = ["CLASSES", "focus_on_point", "load_lens_file", "pick_point", "register",
           "training_outcome", "unregister", "write_st_maps"]

CLASSES = lens_file.CLASSES + focus.CLASSES + scene_training.CLASSES + st_maps.CLASSES


register, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def unregister():
    training.cancel_all()
    _unregister_classes()
