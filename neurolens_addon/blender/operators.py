"""Operators: load a user's lens file (checked first), focus on a picked point, train a model
for the scene (and cancel that).

The work is done by plain functions (`load_lens_file`, `focus_on_point`, `pick_point`) that
the operators call, so scripts and tests can use them without a window.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import bpy
from bpy.props import BoolProperty, FloatVectorProperty, IntProperty, StringProperty

from ..core.errors import FocusError, NeuroLensError
from ..camera.lenses import LensEntry, load_lens_entry
from . import camera_reader, library, sync, training


def _camera_object(context):
    """The camera the operator works on: the active object if it is a camera, else the
    scene's camera."""
    obj = getattr(context, "object", None) or getattr(context, "active_object", None)
    if obj is not None and obj.type == "CAMERA":
        return obj
    scene = getattr(context, "scene", None)
    cam = scene.camera if scene is not None else None
    return cam if cam is not None and cam.type == "CAMERA" else None


def _camera_data(context):
    cam = getattr(context, "camera", None)
    if cam is not None:
        return cam
    obj = _camera_object(context)
    return obj.data if obj is not None else None


# =============================================================================================
# loading a lens file
# =============================================================================================
def _library_copy(src: Path, entry) -> Path:
    """Copy a checked lens file into the user's lens folder (never overwriting another lens);
    the same content already there is reused."""
    folder = library.user_lenses_dir()
    stem, suffix = src.stem, src.suffix.lower()
    for n in range(1, 1000):
        dest = folder / (f"{stem}{suffix}" if n == 1 else f"{stem}_{n}{suffix}")
        if not dest.exists():
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
    """Check a lens file (.toml or pbrt .dat) and use it for this camera"""

    bl_idname = "neurolens.load_lens_file"
    bl_label = "Load Lens File"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Lens File", subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default="*.toml;*.dat", options={"HIDDEN"})
    add_to_library: BoolProperty(
        name="Add to My Lenses", default=False,
        description="Copy the file into your lens folder, so that the lens picker lists it")

    @classmethod
    def poll(cls, context):
        return _camera_data(context) is not None

    def invoke(self, context, _event):
        if not self.filepath:
            self.filepath = str(library.user_lenses_dir()) + "/"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        cam = _camera_data(context)
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
        self.report({"INFO"}, f"Lens '{entry.name}': designed {entry.focal_length_mm:.4g} mm "
                    f"f/{entry.f_number:.3g}")
        return {"FINISHED"}


# =============================================================================================
# focusing on a picked point
# =============================================================================================
def focus_on_point(context, camera_obj, world_point, *, hit_object=None,
                   track_object: bool = False) -> float:
    """Focus `camera_obj` at the depth of `world_point` (along its view axis, as Blender's own
    focus distance is measured) and return that distance in scene units.

    track_object with a hit_object: make it the focus object instead (focus follows its
    origin). Raises FocusError, changing nothing, for a point behind the camera or nearer
    than the lens's closest focus.
    """
    from mathutils import Vector

    from ..camera.focusing import refuse_nearer_than_closest

    scene = context.scene
    mw = camera_obj.matrix_world
    axis = camera_reader.view_axis(mw)
    target = hit_object.original if (track_object and hit_object is not None) else None
    point = target.matrix_world.translation if target is not None else Vector(world_point)
    depth = float((point - mw.translation).dot(axis))
    if track_object and target is not None:
        depth = max(abs(depth), 1e-5)         # Blender measures a focus object this way
    if not depth > 0.0:
        raise FocusError("the picked point is behind the camera: focus unchanged")
    cam = camera_obj.data
    try:
        settings = camera_reader.read_camera(camera_obj, scene, include_disabled=True)
        entry = load_lens_entry(settings.lens_path)
    except NeuroLensError:
        entry = None            # no lens yet: Blender's own focus distance is all there is
    if entry is not None:
        refuse_nearer_than_closest(entry, depth * settings.metres_per_unit * 1000.0,
                                   "the picked point")
    dof = cam.dof
    if target is not None:
        dof.focus_object = target
    else:
        if dof.focus_object is not None:
            dof.focus_object = None
        dof.focus_distance = depth
        if scene.tool_settings.use_keyframe_insert_auto:
            dof.keyframe_insert("focus_distance")
    return depth


def pick_point(context, mouse_x: int, mouse_y: int):
    """(location, object) of the first surface under a window position in a 3D Viewport, or
    None when there is no 3D Viewport there or nothing is hit."""
    from bpy_extras import view3d_utils

    window = context.window
    if window is None:
        return None
    for area in window.screen.areas:
        if area.type != "VIEW_3D":
            continue
        for region in area.regions:
            if region.type != "WINDOW" or region.data is None:
                continue
            if not (region.x <= mouse_x < region.x + region.width
                    and region.y <= mouse_y < region.y + region.height):
                continue
            coord = (mouse_x - region.x, mouse_y - region.y)
            origin = view3d_utils.region_2d_to_origin_3d(region, region.data, coord)
            direction = view3d_utils.region_2d_to_vector_3d(region, region.data, coord)
            depsgraph = context.evaluated_depsgraph_get()
            hit, location, _normal, _index, obj, _matrix = context.scene.ray_cast(
                depsgraph, origin, direction)
            return (location, obj) if hit else None
    return None


class NEUROLENS_OT_focus_pick(bpy.types.Operator):
    """Click a point in a 3D Viewport: the camera focuses at its depth"""

    bl_idname = "neurolens.focus_pick"
    bl_label = "Focus on Picked Point"
    bl_options = {"REGISTER", "UNDO"}

    location: FloatVectorProperty(
        name="Location", subtype="XYZ", size=3, options={"SKIP_SAVE"},
        description="World position to focus on (scripts; interactive use picks it)")
    use_location: BoolProperty(
        name="Use Location", default=False, options={"HIDDEN", "SKIP_SAVE"},
        description="Focus on `location` instead of picking in a 3D Viewport")
    track_object: BoolProperty(
        name="Track Object", default=False,
        description="Make the picked object the focus object: focus then follows its origin")

    @classmethod
    def poll(cls, context):
        return _camera_object(context) is not None

    def _focus(self, context, location, obj):
        cam_obj = bpy.data.objects.get(self._camera_name) if getattr(
            self, "_camera_name", None) else _camera_object(context)
        if cam_obj is None:
            self.report({"ERROR"}, "No camera: select a camera object")
            return {"CANCELLED"}
        try:
            depth = focus_on_point(context, cam_obj, location, hit_object=obj,
                                   track_object=self.track_object)
        except FocusError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        what = f"'{obj.name}'" if obj is not None else "the point"
        self.report({"INFO"}, f"{cam_obj.name} focuses on {what} at {depth:.3f}")
        return {"FINISHED"}

    def execute(self, context):
        self._camera_name = None
        return self._focus(context, self.location, None)

    def invoke(self, context, event):
        if self.use_location:
            return self.execute(context)
        cam_obj = _camera_object(context)
        screen = context.window.screen if context.window else None
        if screen is None or not any(a.type == "VIEW_3D" for a in screen.areas):
            self.report({"ERROR"}, "Focus picking needs a 3D Viewport in this window")
            return {"CANCELLED"}
        self._camera_name = cam_obj.name
        context.window.cursor_modal_set("EYEDROPPER")
        context.workspace.status_text_set("Click a surface in a 3D Viewport to focus on it; "
                                          "Esc or right click cancels")
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _finish(self, context):
        context.window.cursor_modal_restore()
        context.workspace.status_text_set(None)

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            self._finish(context)
            return {"CANCELLED"}
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            hit = pick_point(context, event.mouse_x, event.mouse_y)
            if hit is None:
                self.report({"WARNING"}, "Nothing under the cursor: click a surface in a 3D "
                            "Viewport (Esc cancels)")
                return {"RUNNING_MODAL"}
            self._finish(context)
            return self._focus(context, hit[0], hit[1])
        return {"RUNNING_MODAL"}


# =============================================================================================
# training a model for the scene
# =============================================================================================
def _redraw_properties(context) -> None:
    wm = getattr(context, "window_manager", None)
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type == "PROPERTIES":
                area.tag_redraw()


def training_outcome(job, camera_obj, scene) -> tuple[str, str]:
    """(report level, message) for a job that ended; a finished job re-syncs the camera
    first, so that a camera on Auto picks up the new model."""
    if job.state == training.CANCELLED:
        if job.written and (Path(job.written) / "model.json").is_file():
            return "INFO", ("Scene model training cancelled while the model was evaluated: "
                            f"the model is kept in the cache ({Path(job.written).name}); "
                            "training again evaluates it without retraining")
        return "INFO", ("Scene model training cancelled: nothing was added to the model "
                        "cache")
    if job.state != training.FINISHED:
        return "ERROR", f"Scene model training failed: {job.error or job.status}"
    model = Path(job.result["model"])
    how = "trained" if job.result.get("trained") else "found in the cache"
    if camera_obj is None or bpy.data.objects.get(camera_obj.name) is None:
        return "INFO", f"Scene model {how}: {model}"
    state = sync.sync_camera(camera_obj, scene)
    choice = state.choice
    if choice is not None and choice.path and Path(choice.path).resolve() == model.resolve():
        return "INFO", (f"Scene model {how}: expected error p99 {choice.error_um_p99:.3g} "
                        f"\u00b5m within the budget {choice.budget_um:.3g} \u00b5m; Auto uses "
                        "it now")
    if choice is None:
        return "INFO", (f"Scene model {how}: {model.name} (set the lens model to Auto to use "
                        "it where it meets the budget)")
    return "WARNING", (f"Scene model {how} ({model.name}), but Auto does not use it: "
                       f"{choice.reason}")


class NEUROLENS_OT_train_scene_model(bpy.types.Operator):
    """Train a NeuroLens model for just what this scene renders (resolution, sensor, the
    f-numbers and focus distances its frames use, dispersion), to the scene's error budget.
    The model is cached in your models folder and never trained twice"""

    bl_idname = "neurolens.train_scene_model"
    bl_label = "Train a Model for This Scene"
    bl_options = {"REGISTER"}

    camera: StringProperty(
        name="Camera", default="", options={"SKIP_SAVE"},
        description="The camera object to train for; empty: the active camera, else the "
                    "scene's camera")
    rays: IntProperty(
        name="Training Rays", default=200_000, min=1_000, max=20_000_000,
        description="Exact rays traced to train on")
    max_depth: IntProperty(
        name="Maximum Depth", default=2, min=0, max=8,
        description="How many times the ray space may be split into smaller cells")

    _job = None
    _timer = None

    @classmethod
    def poll(cls, context):
        if training.active_job() is not None:
            cls.poll_message_set("A scene model is being trained")
            return False
        return _camera_object(context) is not None

    def _camera(self, context):
        if self.camera:
            obj = bpy.data.objects.get(self.camera)
            return obj if obj is not None and obj.type == "CAMERA" else None
        return _camera_object(context)

    def _start(self, context):
        from ..core.scene_needs import SceneNeedsError
        obj = self._camera(context)
        if obj is None:
            self.report({"ERROR"}, f"No camera '{self.camera}'" if self.camera else
                        "No camera: select a camera object")
            return None
        try:
            command = training.trainer_command(obj, context.scene, rays=self.rays,
                                               max_depth=self.max_depth)
            job = training.TrainingJob(command.argv, command.cwd,
                                       label=command.lens_name).start()
        except (training.TrainingError, SceneNeedsError) as exc:
            self.report({"ERROR"}, f"Cannot train a scene model: {exc}")
            return None
        except OSError as exc:
            self.report({"ERROR"}, f"Cannot run the trainer's Python ({exc}): set Preferences "
                        "> Add-ons > NeuroLens > Trainer Python to a Python with the "
                        "repository's requirements (torch)")
            return None
        self._camera_name, self._scene_name = obj.name, context.scene.name
        training.set_active(job)
        return job

    def _finish(self, context, job):
        training.set_active(None)
        obj = bpy.data.objects.get(self._camera_name)
        scene = bpy.data.scenes.get(self._scene_name) or context.scene
        level, text = training_outcome(job, obj, scene)
        self.report({level}, text)
        return {"FINISHED"} if job.state == training.FINISHED else {"CANCELLED"}

    def execute(self, context):
        """Synchronous: scripts (EXEC_DEFAULT) and background mode. Ctrl-C cancels."""
        job = self._start(context)
        if job is None:
            return {"CANCELLED"}
        job.on_line = lambda line: print(f"NeuroLens trainer: {line}", flush=True)
        try:
            job.wait()
        except KeyboardInterrupt:
            job.cancel()
            job.wait()
        return self._finish(context, job)

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        job = self._start(context)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 100)
        self._status(context)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _status(self, context):
        job = self._job
        text = (f"Training a model for '{job.label}': {int(100 * job.progress)} %  "
                f"{job.status}  (Esc cancels)")
        if context.workspace is not None:
            context.workspace.status_text_set(text)
        context.window_manager.progress_update(int(100 * job.progress))
        _redraw_properties(context)

    def _end_modal(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        _redraw_properties(context)

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job.poll()
        if job.running:
            self._status(context)
            return {"PASS_THROUGH"}
        self._end_modal(context)
        return self._finish(context, job)

    def cancel(self, context):
        """Blender cancels the operator (the window closes): stop the trainer too."""
        if self._job is not None and self._job.running:
            self._job.cancel()
            self._job.wait(timeout=3 * training.TrainingJob.GRACE_S + 1.0)
        self._end_modal(context)
        training.set_active(None)


class NEUROLENS_OT_cancel_scene_training(bpy.types.Operator):
    """Stop training the scene model (nothing half-written is left in the model cache)"""

    bl_idname = "neurolens.cancel_scene_training"
    bl_label = "Cancel Training"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return training.active_job() is not None

    def execute(self, context):
        job = training.active_job()
        if job is None:
            return {"CANCELLED"}
        job.cancel()
        self.report({"INFO"}, "Cancelling the scene model training")
        return {"FINISHED"}


CLASSES = (NEUROLENS_OT_load_lens_file, NEUROLENS_OT_focus_pick,
           NEUROLENS_OT_train_scene_model, NEUROLENS_OT_cancel_scene_training)


register, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def unregister():
    training.cancel_all()
    _unregister_classes()
