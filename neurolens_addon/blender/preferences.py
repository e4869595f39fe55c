"""Add-on preferences: where the user's own lenses and trained models live, and how to run
the trainer.

Both folders default to the extension's user directory (`bpy.utils.extension_path_user`), never
the installed add-on folder, which Blender may replace on update and which may be read-only.
Thumbnails of the lens picker are cached there too ("thumbnails"), and so are scene models
(models/scene-cache, neural.cache).

Training a scene model runs `python -m trainer fit-scene ...` as a separate process:
`trainer_python()` is the Python that runs it (preference "Trainer Python"; default
`sys.executable`, which is right when the add-on runs in the repository's own environment, as
in the tests, but inside a Blender install it is Blender's bundled Python, which has no torch:
point the preference at a Python that has the repository's requirements installed), and
`trainer_root()` the folder it runs in: the add-on's own root when `trainer/` is there (a
repository checkout), else the preference "Trainer Folder" (a checkout of the repository).
"""

from __future__ import annotations

import sys
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


#: why a chosen folder is not used ({kind: one line}); the preferences show it
DIRECTORY_PROBLEMS: dict = {}


def user_directory(kind: str) -> Path:
    """The directory for `kind`: the user's choice in the preferences when it is (or can be
    made) a writable folder outside the add-on, else the default, with the reason kept in
    DIRECTORY_PROBLEMS (a file where a folder should be, no permission, a read-only disk)."""
    prefs = addon_preferences()
    chosen = getattr(prefs, f"{kind}_directory", "") if prefs else ""
    DIRECTORY_PROBLEMS.pop(kind, None)
    if chosen:
        path = Path(bpy.path.abspath(chosen)).resolve()
        problem = _unusable(path)
        if problem is None:
            return path
        DIRECTORY_PROBLEMS[kind] = f"{path}: {problem}; using the default folder"
    return default_directory(kind)


def _unusable(path: Path) -> str | None:
    """Why `path` cannot be a folder the add-on writes to, or None."""
    import os
    if _inside_addon(path):       # never write into the add-on folder, even when asked
        return "inside the installed add-on, which is never written to"
    if path.exists() and not path.is_dir():
        return "is a file, not a folder"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return f"cannot be created ({exc.strerror or exc})"
    if not os.access(path, os.W_OK | os.X_OK):
        return "is not writable"
    return None


def _inside_addon(path: Path) -> bool:
    return path == ADDON_ROOT or ADDON_ROOT in path.parents


def trainer_python() -> str:
    """The Python interpreter that runs the trainer (needs torch and the requirements)."""
    prefs = addon_preferences()
    chosen = getattr(prefs, "trainer_python", "") if prefs else ""
    return bpy.path.abspath(chosen) if chosen else sys.executable


def _has_trainer(folder: Path) -> bool:
    return (folder / "trainer" / "__main__.py").is_file()


def trainer_root() -> Path | None:
    """The folder `python -m trainer` runs in (holding trainer/ and neurolens_addon/), or None
    when neither the add-on's root nor the preference has one."""
    if _has_trainer(ADDON_ROOT):
        return ADDON_ROOT
    prefs = addon_preferences()
    chosen = getattr(prefs, "trainer_directory", "") if prefs else ""
    if chosen:
        path = Path(bpy.path.abspath(chosen)).resolve()
        if _has_trainer(path):
            return path
    return None


def addon_preferences():
    addon = bpy.context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


class NEUROLENS_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    lenses_directory: bpy.props.StringProperty(
        name="User Lenses", subtype="DIR_PATH", default="",
        description="Folder of your own lens files (.toml, .dat, .zmx), listed in the lens picker; "
                    "empty: the extension's user directory")
    models_directory: bpy.props.StringProperty(
        name="Trained Models", subtype="DIR_PATH", default="",
        description="Folder of trained NeuroLens models (*.neurolens) for your lenses; empty: "
                    "the extension's user directory")
    trainer_python: bpy.props.StringProperty(
        name="Trainer Python", subtype="FILE_PATH", default="",
        description="The Python that trains scene models (python -m trainer fit-scene): it "
                    "needs torch and the repository's requirements, which Blender does not "
                    "ship. Empty: the Python running Blender's add-ons (right only when it has "
                    "them)")
    trainer_directory: bpy.props.StringProperty(
        name="Trainer Folder", subtype="DIR_PATH", default="",
        description="A checkout of the NeuroLens repository (the folder holding trainer/), "
                    "used when the installed add-on does not include the trainer")

    def draw(self, context):
        col = self.layout.column()
        col.use_property_split = True
        for kind in ("lenses", "models"):
            col.prop(self, f"{kind}_directory")
            try:
                col.label(text=f"Using: {user_directory(kind)}", icon="FILE_FOLDER")
                if kind in DIRECTORY_PROBLEMS:
                    col.label(text=DIRECTORY_PROBLEMS[kind], icon="ERROR")
            except OSError as exc:
                col.label(text=f"Cannot use this folder: {exc}", icon="ERROR")
        col.label(text="Empty fields use the extension's user directory, never the add-on folder.",
                  icon="INFO")
        col.separator()
        col.prop(self, "trainer_python")
        col.label(text=f"Using: {trainer_python()}", icon="CONSOLE")
        col.label(text="Blender does not ship torch: inside a Blender install, point this at a "
                       "Python with the repository's requirements", icon="INFO")
        col.prop(self, "trainer_directory")
        root = trainer_root()
        col.label(text=f"Trainer: {root}" if root else "No trainer/ folder found: set the "
                  "Trainer Folder to a checkout of the repository",
                  icon="FILE_FOLDER" if root else "ERROR")


CLASSES = (NEUROLENS_AP_preferences,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
