"""Keep every Real Lens camera's Cycles custom camera in step with its settings.

`sync_camera` evaluates a camera (camera_state.evaluate_camera: the one reader and the one
resolver) and hands `cycles.CameraSpec.from_setup(setup)` to `cycles_camera.apply_lens_camera`
when the set-up changed. Handlers keep every enabled camera in sync on frame changes
(keyframed focus and f-number), on any edit (depsgraph updates) and after a file loads. With a
depsgraph the *evaluated* camera is read, which is what a render sees: during an animation
render the original datablocks still hold the values of the frame the render started on.

While another engine renders (the NEUROLENS engine reads the lens set-up itself, frame by
frame), the handlers write nothing: a camera datablock written during a render is copied
again into the render's depsgraph, which then renders the frame the render started on
(measured: an animated zoom framed at its first focal length on every frame with Lock
Interface off).

State: per camera object (Blender's `session_uid`, unique per datablock and session) for the
last evaluation, and per camera datablock for the key of the set-up last applied. Nothing is
stored per "current camera".
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from ..core.errors import NeuroLensError, debug_traceback
from . import camera_reader
from .camera_state import ERROR, CameraState, evaluate_camera


def _apply_module():
    """The Cycles camera glue (one function, so tests can put a recorder in its place)."""
    from . import cycles_camera
    return cycles_camera


def camera_spec(camera_obj, scene, depsgraph=None):
    """The cycles.CameraSpec of a camera's lens set-up (its panel's settings even while the
    panel is off). Raises the NeuroLensError that leaves the camera without one."""
    from ..cycles import CameraSpec
    return CameraSpec.from_setup(camera_reader.lens_setup(camera_obj, scene, depsgraph,
                                                          include_disabled=True))


# =============================================================================================
# applying
# =============================================================================================
_STATUS: dict = {}     # camera object session_uid -> last CameraState (with apply messages)
_APPLIED: dict = {}    # camera data session_uid -> key of the spec last applied
_SYNCING: list = []


def last_state(camera_obj) -> CameraState | None:
    return _STATUS.get(camera_obj.session_uid)


#: set on a camera whose Depth of Field the add-on turned on (an animated lens), so that
#: turning the lens off gives the user's setting back
DOF_KEY = "neurolens_turned_dof_on"


def enable_dof_for_follow(camera_data, setup) -> None:
    """Cycles hands a custom camera the frame's focus and f-number only with Depth of Field on;
    a lens that follows its animation (setup.follow) needs them, and has depth of field either
    way: turn it on, marked so that turning the lens off gives the user's setting back."""
    if setup.follow is not None and not camera_data.dof.use_dof:
        camera_data.dof.use_dof = True
        camera_data[DOF_KEY] = True


def _restore_camera(camera_data) -> None:
    _apply_module().clear_lens_camera(camera_data)
    if camera_data.get(DOF_KEY):
        camera_data.dof.use_dof = False
        del camera_data[DOF_KEY]


def sync_camera(camera_obj, scene, depsgraph=None, *, force: bool = False) -> CameraState:
    """Evaluate a camera and hand its spec to the Cycles camera when it changed.

    A camera whose settings cannot be used keeps its last working lens (the panel says why).
    """
    state = evaluate_camera(camera_obj, scene, depsgraph)
    data = camera_obj.data
    _STATUS[camera_obj.session_uid] = state
    if len(_STATUS) > 4096:
        _STATUS.clear()
    if not state.enabled:
        if _APPLIED.pop(data.session_uid, None) is not None:
            _restore_camera(data)
        return state
    if state.setup is None:
        return state
    if not force and _APPLIED.get(data.session_uid) == state.setup.key:
        return state
    module = _apply_module()
    enable_dof_for_follow(data, state.setup)
    try:
        from ..cycles import CameraSpec
        module.apply_lens_camera(data, CameraSpec.from_setup(state.setup))
    except NeuroLensError as exc:
        state.say(ERROR, f"Could not set up the lens camera: {exc}")
        return state
    except Exception as exc:  # noqa: BLE001 - a bug must not break Blender's handler loop
        debug_traceback()
        state.say(ERROR, f"Could not set up the lens camera ({exc.__class__.__name__}: {exc})")
        return state
    _APPLIED[data.session_uid] = state.setup.key
    return state


def _enabled_camera_objects(scene):
    enabled = [c for c in bpy.data.cameras if c.neurolens.enabled or c.session_uid in _APPLIED]
    if not enabled:
        return []
    uids = {c.session_uid for c in enabled}
    return [o for o in scene.objects if o.type == "CAMERA" and o.data is not None
            and o.data.session_uid in uids]


#: a render runs (between Blender's render_init and render_complete or render_cancel)
_RENDERING: list = []


def another_engine_renders(scene) -> bool:
    """A render runs and the scene renders with an engine other than Cycles."""
    return bool(_RENDERING) and scene.render.engine != "CYCLES"


def sync_scene(scene, depsgraph=None) -> list[CameraState]:
    """Sync every Real Lens camera of a scene (and undo cameras that were switched off);
    nothing while another engine renders (module docstring)."""
    if _SYNCING or another_engine_renders(scene):
        return []
    _SYNCING.append(True)
    try:
        states = [sync_camera(o, scene, depsgraph) for o in _enabled_camera_objects(scene)]
        _sync_compositor(scene)
        return states
    finally:
        _SYNCING.clear()


_COMPOSITED: dict = {}     # scene session_uid -> key of the diffraction last composited


def _sync_compositor(scene) -> None:
    """Diffraction in Cycles goes through the compositor (diffraction_compositor), for the
    scene's active camera; redone only when its set-up or the engine changed. A camera whose
    Real Lens panel is off (the command line's custom properties) keeps the compositor its
    owner set up (the command line applies its own); a convolution the handlers set up is
    undone when the panel is turned off."""
    state = last_state(scene.camera) if scene.camera is not None else None
    ours = _COMPOSITED.get(scene.session_uid, (None, None))[1] is not None
    if scene.camera is not None and not (state is not None and state.enabled) and not ours:
        return                  # not the panel's camera, and no convolution of ours to undo
    setup = state.setup if state is not None and state.enabled else None
    key = (scene.render.engine, setup.key if setup is not None and setup.diffraction else None,
           scene.compositing_node_group is None)
    if _COMPOSITED.get(scene.session_uid) == key:
        return
    from .diffraction_compositor import sync_diffraction
    from .camera_state import WARNING
    try:
        message = sync_diffraction(scene, setup)
    except Exception as exc:  # noqa: BLE001 - a bug must not break Blender's handler loop
        debug_traceback()
        message = f"Diffraction could not be set up ({exc.__class__.__name__}: {exc})"
    if message and state is not None:
        state.say(WARNING, message)
    _COMPOSITED[scene.session_uid] = (scene.render.engine, key[1],
                                      scene.compositing_node_group is None)


def on_settings_changed(camera_data, context) -> None:
    """Update callback of every Real Lens setting: sync the objects using this camera."""
    scene = getattr(context, "scene", None) or bpy.context.scene
    if scene is None:
        return
    for obj in scene.objects:
        if obj.type == "CAMERA" and obj.data == camera_data:
            sync_camera(obj, scene)


# =============================================================================================
# handlers
# =============================================================================================
@persistent
def _on_frame_change_post(scene, depsgraph=None):
    sync_scene(scene, depsgraph)


@persistent
def _on_depsgraph_update_post(scene, depsgraph=None):
    sync_scene(scene, depsgraph)


@persistent
def _on_render_init(*_args):
    _RENDERING.append(True)


@persistent
def _on_render_end(*_args):
    _RENDERING.clear()


@persistent
def _on_render_pre(scene, *_args):
    """Before each frame Cycles renders: the lamps' flare of that frame into the compositor
    (flare_compositor), for a Real Lens camera with ghosts on."""
    if scene.render.engine != "CYCLES":
        return
    cam = scene.camera
    state = last_state(cam) if cam is not None else None
    if state is None or not state.enabled:
        return          # not the panel's camera: the command line traces its own flare
    setup = state.setup
    from .flare_compositor import sync_flare
    from .camera_state import WARNING
    try:            # no ghosts: the flare of an earlier frame or setting is taken away
        message, _seconds = sync_flare(scene, None if setup is None or setup.ghosts is None
                                       else bpy.context.evaluated_depsgraph_get(), cam, setup)
    except Exception as exc:  # noqa: BLE001 - a bug must not break Blender's handler loop
        debug_traceback()
        message = f"Flare could not be traced ({exc.__class__.__name__}: {exc})"
    if message and state is not None:
        state.say(WARNING, message)


@persistent
def _on_load_post(*_args):
    _RENDERING.clear()          # a render that ended without its handlers ends here
    _STATUS.clear()
    _APPLIED.clear()
    _COMPOSITED.clear()
    for scene in bpy.data.scenes:
        sync_scene(scene)


HANDLERS = (
    ("frame_change_post", _on_frame_change_post),
    ("depsgraph_update_post", _on_depsgraph_update_post),
    ("load_post", _on_load_post),
    ("render_init", _on_render_init),
    ("render_pre", _on_render_pre),
    ("render_complete", _on_render_end),
    ("render_cancel", _on_render_end),
)


def _ours(fn, name: str) -> bool:
    """`fn` is this module's handler `name`, possibly from an earlier load of this module."""
    return getattr(fn, "__name__", None) == name and getattr(fn, "__module__", None) == __name__


def register():
    for attr, fn in HANDLERS:
        handlers = getattr(bpy.app.handlers, attr)
        for old in [h for h in handlers if _ours(h, fn.__name__)]:
            handlers.remove(old)      # a stale copy from an earlier load of this module
        handlers.append(fn)


def unregister():
    for attr, fn in HANDLERS:
        handlers = getattr(bpy.app.handlers, attr)
        for old in [h for h in handlers if h is fn or _ours(h, fn.__name__)]:
            handlers.remove(old)
    _STATUS.clear()
    _APPLIED.clear()
    _COMPOSITED.clear()
    camera_reader.forget()
    _SYNCING.clear()
