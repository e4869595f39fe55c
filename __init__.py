"""Blender extension entry point: re-exports register/unregister (nothing else)."""

from .neurolens_addon import register, unregister  # noqa: F401
