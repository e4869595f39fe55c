"""Add-on preferences: where the user's own lenses and trained models live.

Both default to the extension's user directory (`bpy.utils.extension_path_user`), never the
installed add-on folder, which Blender may replace on update and which may be read-only.
"""

from __future__ import annotations

from pathlib import Path

import bpy

ADDON_PACKAGE = __package__.rsplit(".", 2)[0]


def user_directory(kind: str) -> Path:
    """The user directory for `kind` ("lenses" or "models"), created on first use."""
    prefs = addon_preferences()
    chosen = getattr(prefs, f"{kind}_directory", "") if prefs else ""
    if chosen:
        path = Path(bpy.path.abspath(chosen))
    else:
        path = Path(bpy.utils.extension_path_user(ADDON_PACKAGE, path=kind, create=True))
    path.mkdir(parents=True, exist_ok=True)
    return path


def addon_preferences():
    addon = bpy.context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


class NEUROLENS_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    lenses_directory: bpy.props.StringProperty(
        name="User lenses", subtype="DIR_PATH", default="",
        description="Folder of your own lens files (.toml, .dat); empty: the extension's user "
                    "directory")
    models_directory: bpy.props.StringProperty(
        name="Trained models", subtype="DIR_PATH", default="",
        description="Folder where trained NeuroLens models are cached; empty: the extension's "
                    "user directory")

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "lenses_directory")
        col.prop(self, "models_directory")
        col.label(text="Empty fields use the extension's user directory, never the add-on folder.")


def register():
    bpy.utils.register_class(NEUROLENS_AP_preferences)


def unregister():
    bpy.utils.unregister_class(NEUROLENS_AP_preferences)
