"""Add-on preferences: where the user's own lenses and trained models live.

Both default to the extension's user directory (`bpy.utils.extension_path_user`), never the
installed add-on folder, which Blender may replace on update and which may be read-only.
Thumbnails of the lens picker are cached there too ("thumbnails").
"""

from __future__ import annotations

from pathlib import Path

import bpy

#: The add-on's top-level package as Blender knows it, e.g. "bl_ext.user_default.neurolens"
#: (this module is ADDON_PACKAGE.neurolens_addon.blender.preferences).
ADDON_PACKAGE = __package__.rsplit(".", 2)[0]
#: The installed add-on folder: nothing is ever written below it at run time.
ADDON_ROOT = Path(__file__).resolve().parents[2]

KINDS = ("lenses", "models", "thumbnails")


def default_directory(kind: str) -> Path:
    """The extension's own user directory for `kind`, created on first use.

    Outside the extension system (a legacy add-on install) Blender has no extension user
    directory; the add-on then uses Blender's user config folder, still never its own folder.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown user directory kind {kind!r}: expected one of {KINDS}")
    try:
        path = Path(bpy.utils.extension_path_user(ADDON_PACKAGE, path=kind, create=True))
    except ValueError:   # "The package does not name an extension"
        path = Path(bpy.utils.user_resource("CONFIG", path=f"neurolens/{kind}", create=True))
    return path


def user_directory(kind: str) -> Path:
    """The directory for `kind`: the user's choice in the preferences, else the default."""
    prefs = addon_preferences()
    chosen = getattr(prefs, f"{kind}_directory", "") if prefs else ""
    if chosen:
        path = Path(bpy.path.abspath(chosen)).resolve()
        if not _inside_addon(path):   # never write into the add-on folder, even when asked
            path.mkdir(parents=True, exist_ok=True)
            return path
    return default_directory(kind)


def _inside_addon(path: Path) -> bool:
    return path == ADDON_ROOT or ADDON_ROOT in path.parents


def addon_preferences():
    addon = bpy.context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


class NEUROLENS_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    lenses_directory: bpy.props.StringProperty(
        name="User Lenses", subtype="DIR_PATH", default="",
        description="Folder of your own lens files (.toml, .dat), listed in the lens picker; "
                    "empty: the extension's user directory")
    models_directory: bpy.props.StringProperty(
        name="Trained Models", subtype="DIR_PATH", default="",
        description="Folder of trained NeuroLens models (*.neurolens) for your lenses; empty: "
                    "the extension's user directory")

    def draw(self, context):
        col = self.layout.column()
        col.use_property_split = True
        for kind in ("lenses", "models"):
            col.prop(self, f"{kind}_directory")
            try:
                col.label(text=f"Using: {user_directory(kind)}", icon="FILE_FOLDER")
            except OSError as exc:
                col.label(text=f"Cannot use this folder: {exc}", icon="ERROR")
        col.label(text="Empty fields use the extension's user directory, never the add-on folder.",
                  icon="INFO")


CLASSES = (NEUROLENS_AP_preferences,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
