"""Writing a camera's ST-maps from the panel: the undistort and distort maps of its lens as it
stands (camera.stmaps), as 32-bit float EXR written by Blender (the OpenEXR package is the
command line's, not Blender's), each with its lens data beside it (.exr.json).

`write_st_maps(camera_obj, scene, folder, overscan)` does the work (scripts and tests); the
operator asks for the folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import bpy
import numpy as np
from bpy.props import FloatProperty, StringProperty

from ...core.errors import NeuroLensError
from .common import camera_object


def _save_exr(rgba: np.ndarray, path: Path) -> None:
    """A map (H, W, 3: R G A, rows from the bottom) as a float EXR at `path`, written beside
    it and renamed onto it (the old file stays if anything fails)."""
    h, w = rgba.shape[:2]
    px = np.zeros((h, w, 4), dtype=np.float32)
    px[..., 0], px[..., 1], px[..., 3] = rgba[..., 0], rgba[..., 1], rgba[..., 2]
    img = bpy.data.images.new(f".neurolens-stmap-{path.stem}", w, h, alpha=True,
                              float_buffer=True)
    tmp = path.with_name(f".{path.name}.tmp.exr")
    try:
        img.colorspace_settings.name = "Non-Color"     # data, not colour: no transform
        img.pixels.foreach_set(px.ravel())
        img.file_format = "OPEN_EXR"
        img.use_half_precision = False
        img.filepath_raw = str(tmp)
        img.save()
        if not tmp.is_file() or tmp.stat().st_size == 0:
            raise OSError(f"{path}: Blender wrote no EXR")
        os.replace(tmp, path)
    finally:
        bpy.data.images.remove(img)
        if tmp.exists():
            tmp.unlink()


def write_st_maps(camera_obj, scene, folder, overscan: float = 1.0) -> list[Path]:
    """Write CAMERA_undistort.exr and CAMERA_distort.exr (and their .exr.json) of the camera's
    lens into `folder`; the maps written. The project's error (one line) where the camera
    has no map."""
    from ...camera.stmaps import camera_maps
    from ...core.atomic import atomic_write_text
    from ...core.jsonout import dumps
    from ..camera_state import evaluate_camera
    state = evaluate_camera(camera_obj, scene)
    if state.setup is None:
        raise state.error
    folder = Path(bpy.path.abspath(str(folder)))
    if not folder.is_dir():
        raise NeuroLensError(f"{folder}: no such folder")
    written = []
    for direction in ("undistort", "distort"):
        rgba, _header, meta = camera_maps(state.setup, direction, overscan)
        path = folder / f"{bpy.path.clean_name(camera_obj.name)}_{direction}.exr"
        _save_exr(rgba, path)
        atomic_write_text(f"{path}.json", dumps({**meta, "direction": direction,
                                                 "overscan": overscan}, indent=1) + "\n")
        written.append(path)
    return written


class NEUROLENS_OT_write_st_maps(bpy.types.Operator):
    """Write the undistort and distort ST-maps (Nuke STMap EXR) of this camera's lens at its
    focus and sensor, with its lens data beside them"""

    bl_idname = "neurolens.write_st_maps"
    bl_label = "Write ST-Maps"
    bl_options = {"REGISTER"}

    directory: StringProperty(name="Folder", subtype="DIR_PATH", options={"SKIP_SAVE"})
    overscan: FloatProperty(name="Overscan", default=1.0, min=1.0, max=4.0,
                            description="The undistorted image's size over the frame's "
                                        "(the border the distorted CG needs)")

    @classmethod
    def poll(cls, context):
        return camera_object(context) is not None

    def invoke(self, context, _event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        cam = camera_object(context)
        try:
            paths = write_st_maps(cam, context.scene, self.directory, self.overscan)
        except (NeuroLensError, OSError) as exc:
            self.report({"ERROR"}, " ".join(str(exc).split())[:300])
            return {"CANCELLED"}
        self.report({"INFO"}, f"Wrote {', '.join(p.name for p in paths)}")
        return {"FINISHED"}


CLASSES = (NEUROLENS_OT_write_st_maps,)
