"""Training a model for the scene: the operator that runs the trainer for what this scene
renders (modal with a progress bar in a window, synchronous in scripts and background mode),
the one that cancels it, and the report of how a job ended.
"""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import IntProperty, StringProperty

from .. import sync, training
from .common import camera_object


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
        return camera_object(context) is not None

    def _camera(self, context):
        if self.camera:
            obj = bpy.data.objects.get(self.camera)
            return obj if obj is not None and obj.type == "CAMERA" else None
        return camera_object(context)

    def _start(self, context):
        from ...core.scene_needs import SceneNeedsError
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


CLASSES = (NEUROLENS_OT_train_scene_model, NEUROLENS_OT_cancel_scene_training)
