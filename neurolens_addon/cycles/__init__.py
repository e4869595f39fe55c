"""Cycles custom camera (OSL) generation: the exact, learned and thin lenses as shader source.

Pure Python (no bpy): `generate_osl(CameraSpec(...))` returns the text that
neurolens_addon.blender.cycles_camera puts into a text datablock for Cycles' Custom camera.
"""

from .generate import generate_osl, source_hash
from .spec import CameraSpec, CameraSpecError

__all__ = ["CameraSpec", "CameraSpecError", "generate_osl", "source_hash"]
