"""Loading a user's lens file: checked completely before the camera changes.

`load_lens_file` (used by the operator, scripts and tests) makes a checked .toml, pbrt .dat or Zemax .zmx
file (or the model of a lens known only from a ray table: its model.json picks its directory)
the lens of a camera, either in place (source FILE) or copied into the user's lens folder
(source LIBRARY, under a name that never overwrites another lens).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy
from bpy.props import StringProperty

from ...core.errors import NeuroLensError, debug_traceback
from ...camera.lenses import MODEL_SUFFIX, LensEntry, load_lens_entry
from .. import library
from .common import camera_data, option


def _library_copy(src: Path, entry) -> Path:
    """Copy a checked lens file into the user's lens folder (never overwriting another lens);
    the same content already there is reused."""
    folder = library.user_lenses_dir()
    stem, suffix = src.stem, src.suffix.lower()
    for n in range(1, 1000):
        dest = folder / (f"{stem}{suffix}" if n == 1 else f"{stem}_{n}{suffix}")
        if not dest.exists():
            if src.is_dir():                 # a ray table's lens: its model directory
                shutil.copytree(src, dest)
            else:
                shutil.copyfile(src, dest)
            return dest
        try:
            if load_lens_entry(dest).file_hash == entry.file_hash:
                return dest
        except NeuroLensError:
            continue
    raise OSError(f"too many lens files named {stem}* in {folder}")


def load_lens_file(camera_data, path, *, add_to_library: bool = False) -> LensEntry:
    """Check the lens file at `path` and make it the lens of `camera_data`.

    Raises LensError (naming the file, the surface and the field) for a bad file; the camera
    is then left exactly as it was.
    """
    path = Path(bpy.path.abspath(str(path)))
    if path.name == "model.json" and path.parent.name.endswith(MODEL_SUFFIX):
        path = path.parent                 # a ray table's lens is its model directory
    entry = load_lens_entry(path)          # checks everything before any change
    props = camera_data.neurolens
    if add_to_library:
        dest = _library_copy(path, entry)
        props.lens_id = library.USER_PREFIX + dest.name
        props.source = "LIBRARY"
    else:
        props.lens_file = str(path)
        props.source = "FILE"
    props.enabled = True
    return entry


class NEUROLENS_OT_load_lens_file(bpy.types.Operator):
    """Check a lens file (.toml, pbrt .dat or Zemax .zmx, or the model.json of a lens known only
    from a ray table) and use it for this camera"""

    bl_idname = "neurolens.load_lens_file"
    bl_label = "Load Lens File"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Lens File", subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default="*.toml;*.dat;*.zmx;model.json", options={"HIDDEN"})
    add_to_library: option(
        "Add to My Lenses",
        "Copy the file into your lens folder, so that the lens picker lists it")

    @classmethod
    def poll(cls, context):
        return camera_data(context) is not None

    def invoke(self, context, _event):
        if not self.filepath:
            self.filepath = str(library.user_lenses_dir()) + "/"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        cam = camera_data(context)
        if cam is None:
            self.report({"ERROR"}, "No camera: select a camera object")
            return {"CANCELLED"}
        try:
            entry = load_lens_file(cam, self.filepath, add_to_library=self.add_to_library)
        except NeuroLensError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except OSError as exc:
            self.report({"ERROR"}, f"Could not add the lens to your folder: {exc}")
            return {"CANCELLED"}
        except Exception as exc:  # noqa: BLE001 - one line for the user, not a traceback
            # (the readers raise only LensError: anything else is a bug, reported in one line)
            debug_traceback()
            text = " ".join(f"{self.filepath}: unexpected {type(exc).__name__}: {exc}".split())
            self.report({"ERROR"}, f"{text[:300]} (please report it)")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Lens '{entry.name}': designed {entry.focal_length_mm:.4g} mm "
                    f"f/{entry.f_number:.3g}")
        return {"FINISHED"}


CLASSES = (NEUROLENS_OT_load_lens_file,)
