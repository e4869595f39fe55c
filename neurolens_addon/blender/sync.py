"""From a camera's settings to the lens camera Cycles renders: `camera_spec`, `sync_camera`.

`evaluate_camera` reads one camera (its Real Lens settings, Blender's Depth of Field settings,
the render's sensor fit) and works out what the lens does with them: the lens (cached by file
content), the f-number clamped to the lens's widest, the focus distance refused nearer than
the closest focus, the exact sensor position for that focus (cached), the aperture shape, the
model actually used (a learned lens falls back to the exact trace, saying why), and for the
panel the field of view on the sensor. Problems become messages, never exceptions.

Model AUTO (`auto_choice`): the scene's render settings give an error budget and the region of
the lens's input space it uses (scene_needs_bpy); among the lens's learned models (the preset's,
the user's models folder and its scene-model cache) neural.choice.choose_model picks the
cheapest whose recorded image error (p99) meets the budget and whose domain covers the region,
else the exact trace. The choice (`CameraState.choice`, a ModelChoice) is cached by (lens
content hash, the needs, the candidate models' model.json stat), so redrawing the panel costs
a few stat() calls.

`camera_spec` turns that into the Cycles side's `CameraSpec`; `sync_camera` hands it to
`cycles_camera.apply_lens_camera` when it changed. Handlers keep every enabled camera in sync
on frame changes (keyframed focus and f-number), on any edit (depsgraph updates) and after a
file loads. With a depsgraph the *evaluated* camera is read, which is what a render sees:
during an animation render the original datablocks still hold the values of the frame the
render started on.

State: per camera object (Blender's `session_uid`, unique per datablock and session) for the
last evaluation, and per camera datablock for the last applied spec; the lens, focus and
field-of-view caches are keyed by content. Nothing is stored per "current camera".
"""

from __future__ import annotations

import dataclasses
import math
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

from ..core.errors import ApertureError, FocusError, LensError, NeuroLensError
from . import lensdata, library

MODEL_NAMES = {"AUTO": "auto", "EXACT": "exact", "LEARNED": "learned", "THIN": "thin"}
INFO, WARNING, ERROR = "INFO", "WARNING", "ERROR"


def make_spec(fields: dict):
    """A cycles.CameraSpec from evaluate_camera's fields (those the spec declares)."""
    from ..cycles import CameraSpec
    names = {f.name for f in dataclasses.fields(CameraSpec)}
    return CameraSpec(**{k: v for k, v in fields.items() if k in names})


def _apply_module():
    """The Cycles camera glue (one function, so tests can put a recorder in its place)."""
    from . import cycles_camera
    return cycles_camera


@dataclass
class CameraState:
    """What one camera's settings amount to, with the messages the panel shows."""

    enabled: bool
    messages: list = field(default_factory=list)        # [(level, text)]
    fields: dict | None = None                          # CameraSpec keyword arguments
    error: NeuroLensError | None = None                 # why there is no spec
    entry: lensdata.LensEntry | None = None
    lens_id: str | None = None
    requested_model: str = "EXACT"
    model: str | None = None
    f_number_requested: float = math.nan
    f_number: float = math.nan
    stop_radius_mm: float = math.nan
    focus_requested_m: float = math.nan
    focus_m: float = math.nan
    sensor_z_mm: float = math.nan
    model_info: lensdata.ModelInfo | None = None
    frame_mm: tuple | None = None
    fov_deg: tuple | None = None                        # (horizontal, vertical, diagonal)
    image_circle_mm: float | None = None
    choice: ModelChoice | None = None                   # model AUTO: what it chose and why
    key: tuple | None = None

    def say(self, level: str, text: str) -> None:
        self.messages.append((level, text))

    @property
    def closest_focus_m(self) -> float:
        return self.entry.closest_focus_mm / 1000.0 if self.entry else math.nan


# =============================================================================================
# reading a camera
# =============================================================================================
def unit_scale(scene) -> float:
    """Metres per Blender unit."""
    try:
        s = float(scene.unit_settings.scale_length)
    except AttributeError:
        return 1.0
    return s if s > 0.0 else 1.0


def _view_axis(matrix_world):
    """Unit vector the camera looks along (its local -Z) in world space."""
    from mathutils import Vector
    axis = matrix_world.to_3x3() @ Vector((0.0, 0.0, -1.0))
    return axis.normalized()


def focus_distance_bu(camera_obj, camera_data) -> float:
    """Blender's own focus distance (scene units): along the view axis to the focus object
    (or its bone), else the Depth of Field focus distance."""
    dof = camera_data.dof
    target = dof.focus_object
    if target is None:
        return float(dof.focus_distance)
    point = target.matrix_world.translation
    if target.type == "ARMATURE" and dof.focus_subtarget and target.pose:
        bone = target.pose.bones.get(dof.focus_subtarget)
        if bone is not None:
            point = target.matrix_world @ bone.head
    mw = camera_obj.matrix_world
    return max(abs((point - mw.translation).dot(_view_axis(mw))), 1e-5)


def film_size_mm(camera_data, scene) -> tuple[float, float]:
    """(width, height) of the film in mm as Cycles frames the render (sensor fit, pixel
    aspect, the final pixel counts)."""
    r = scene.render
    pct = r.resolution_percentage / 100.0
    ax = max(1, int(r.resolution_x * pct)) * r.pixel_aspect_x
    ay = max(1, int(r.resolution_y * pct)) * r.pixel_aspect_y
    return lensdata.frame_size_mm(camera_data.sensor_width, camera_data.sensor_height,
                                  camera_data.sensor_fit, ax, ay)


def lens_path(props) -> tuple[str | None, str]:
    """(library id or None, file path) of the lens a camera's settings name."""
    if props.source == "FILE":
        if not props.lens_file:
            raise LensError("no lens file loaded: use Load Lens File to pick one")
        return None, bpy.path.abspath(props.lens_file)
    return props.lens_id, library.path_for(props.lens_id)


_MASKS: dict = {}


def mask_aperture(image):
    """An ImageMaskAperture from a Blender image (luminance x alpha), cached by pixels."""
    import hashlib

    import numpy as np

    from ..core.aperture import ImageMaskAperture

    w, h = image.size
    if w < 1 or h < 1:
        raise ApertureError(f"aperture mask image '{image.name}' has no pixels (is the file "
                            "missing?)")
    key = (image.session_uid, w, h, image.filepath_raw)
    hit = _MASKS.get(key)
    if hit is not None and not image.is_dirty:
        return hit[1]
    px = np.empty(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(px)
    digest = hashlib.sha1(px.tobytes()).hexdigest()
    if hit is not None and hit[0] == digest:
        return hit[1]
    c = image.channels
    img = px.reshape(h, w, c)[::-1].astype(np.float64)    # Blender's row 0 is the bottom
    if c >= 3:
        lum = img[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    else:
        lum = img[..., 0]
    if c in (2, 4):
        lum = lum * img[..., -1]
    aperture = ImageMaskAperture(lum, source=image.name)
    if len(_MASKS) > 16:
        _MASKS.clear()
    _MASKS[key] = (digest, aperture)
    return aperture


def _aperture(props, dof, state: CameraState):
    from ..core.aperture import aperture_from_settings

    shape = props.aperture_shape
    if shape == "MASK":
        if props.mask_image is None:
            state.say(WARNING, "Aperture mask: no image chosen; using a round aperture")
            return aperture_from_settings("circle"), ("circle",)
        try:
            ap = mask_aperture(props.mask_image)
        except ApertureError as exc:
            state.say(WARNING, f"{exc}; using a round aperture")
            return aperture_from_settings("circle"), ("circle",)
        return ap, ("mask", props.mask_image.name_full, id(ap))
    if shape == "BLADES":
        rot = math.degrees(dof.aperture_rotation)
        ap = aperture_from_settings("polygon", blades=int(dof.aperture_blades), rotation_deg=rot,
                                    curvature=float(props.blade_curvature))
        return ap, ("polygon", int(dof.aperture_blades), round(rot, 9),
                    round(float(props.blade_curvature), 9))
    return aperture_from_settings("circle"), ("circle",)


# =============================================================================================
# automatic model choice
# =============================================================================================
EXACT_NAME = "exact trace"


@dataclass(frozen=True)
class ModelChoice:
    """What model AUTO uses for a camera, its expected error and why (for the panel)."""

    kind: str                       # "learned" | "exact"
    name: str                       # shown in the panel
    path: str | None                # the model directory (learned)
    error_um_p99: float             # the model's recorded image error, 99th percentile (um)
    budget_um: float                # the scene's budget (um on the sensor); nan: unknown
    pixel_fraction: float           # the budget in pixels
    reason: str
    trainable: bool = False         # exact because no learned model meets the budget
    notes: tuple = ()               # how the render settings were read (animation, focus object)
    considered: tuple = ()          # ((model name, why it does not qualify or ""), ...)
    needs: object = None            # the RenderNeeds (reduced to the region's) it was made for

    @property
    def summary(self) -> str:
        budget = (f"budget {self.budget_um:.3g} \u00b5m = {self.pixel_fraction:g} px"
                  if math.isfinite(self.budget_um) else f"budget {self.pixel_fraction:g} px")
        return (f"Using: {self.name} \u2014 expected error p99 {self.error_um_p99:.3g} \u00b5m "
                f"({budget})")


_CHOICES: dict = {}     # (lens hash, needs, candidate stats) -> ModelChoice


def _model_dirs(candidates) -> list[tuple[Path, tuple]]:
    """(model directory, stat key of its model.json) for every model among `candidates`
    (model directories, or folders of *.neurolens directories), each once. Cheap: one
    scandir per folder and one stat per model, on every redraw."""
    import os
    out, seen = [], set()

    def add(path: str) -> bool:
        try:
            st = os.stat(os.path.join(path, "model.json"))
        except OSError:
            return False
        if path not in seen:
            seen.add(path)
            out.append((Path(path), (path, st.st_mtime_ns, st.st_size)))
        return True

    for cand in candidates:
        if cand is None:
            continue
        folder = os.path.normpath(os.fspath(cand))
        if add(folder):
            continue
        try:
            with os.scandir(folder) as it:
                names = sorted(e.path for e in it if e.name.endswith(".neurolens"))
        except OSError:
            continue
        for path in names:
            add(path)
    return out


def _display_name(path: Path) -> str:
    from ..neural.cache import CACHE_DIR
    stem = path.name.removesuffix(".neurolens")
    if path.parent.name == CACHE_DIR:
        return f"scene model {stem.rsplit('-', 1)[-1][:8]}"
    return f"learned model {stem}"


def auto_choice(entry, lens_id, camera_obj, scene) -> ModelChoice:
    """The model AUTO uses for `camera_obj` in `scene` (cached; see the module docstring)."""
    import json

    from ..core.scene_needs import SceneNeedsError
    from ..neural.cache import cached_models
    from . import scene_needs_bpy
    from .preferences import user_directory

    pf = scene_needs_bpy.pixel_fraction(scene)
    try:
        needs = scene_needs_bpy.render_needs(scene, camera_obj)
        rneeds = scene_needs_bpy.region_needs(needs, entry)
    except SceneNeedsError as exc:
        return ModelChoice("exact", EXACT_NAME, None, 0.0, math.nan, pf,
                           f"exact trace: the render settings describe no image ({exc})")
    notes = tuple(needs.extras.get("notes", ()))
    try:
        candidates = list(library.model_candidates(lens_id)) + \
            cached_models(user_directory("models"))
    except OSError as exc:
        candidates = [library.PRESET_MODELS_DIR]
        notes += (f"Your models folder cannot be used ({exc})",)
    found = _model_dirs(candidates)
    key = (entry.content_hash, json.dumps(rneeds.as_dict(), sort_keys=True),
           tuple(k for _d, k in found))
    hit = _CHOICES.get(key)
    if hit is None:
        hit = _choose(entry, rneeds, [d for d, _k in found])
        if len(_CHOICES) > 256:
            _CHOICES.clear()
        _CHOICES[key] = hit
    return dataclasses.replace(hit, notes=notes) if notes else hit


def _choose(entry, needs, dirs) -> ModelChoice:
    from ..core.errors import ModelError
    from ..neural.choice import choose_model
    from . import scene_needs_bpy

    pf = needs.pixel_fraction
    budget = needs.error_budget_um()
    mine = []
    for d in dirs:
        try:
            if lensdata.model_info(d).lens_content_hash == entry.content_hash:
                mine.append(d)
        except ModelError:
            continue
    try:
        region = scene_needs_bpy.scene_region(entry, needs)
    except NeuroLensError as exc:
        return ModelChoice("exact", EXACT_NAME, None, 0.0, budget, pf,
                           f"exact trace: the scene's region of the lens is unknown ({exc})",
                           needs=needs)
    c = choose_model(mine, needs, region, entry.content_hash)
    considered = tuple((_display_name(o.path), o.why_not) for o in c.considered)
    if c.option.kind == "learned":
        return ModelChoice("learned", _display_name(c.option.path), str(c.option.path),
                           float(c.option.image_error_um_p99), c.budget_um, pf,
                           f"The cheapest model within the budget: {c.reason}",
                           considered=considered, needs=needs)
    if not c.considered:
        reason = (f"No learned model of '{entry.name}' yet: the exact trace is used (train a "
                  "model for this scene to render faster)")
    else:
        reason = "No learned model meets the budget: " + "; ".join(
            f"{name}: {why}" for name, why in considered)
    return ModelChoice("exact", EXACT_NAME, None, 0.0, c.budget_um, pf, reason,
                       trainable=True, considered=considered, needs=needs)


def evaluate_camera(camera_obj, scene, depsgraph=None, *, with_fov: bool = False) -> CameraState:
    """Work out what a camera's settings amount to (see the module docstring)."""
    from ..core.aperture import clamp_f_number, stop_radius_for_f_number

    obj = camera_obj.evaluated_get(depsgraph) if depsgraph is not None else camera_obj
    cam = obj.data
    props = cam.neurolens
    dof = cam.dof
    state = CameraState(enabled=bool(props.enabled), requested_model=props.model)

    # the lens
    try:
        state.lens_id, path = lens_path(props)
        entry = state.entry = lensdata.load_lens_entry(path)
    except NeuroLensError as exc:
        state.error = exc
        state.say(ERROR, str(exc))
        return state

    # f-number: Blender's own F-Stop, clamped to the lens's widest
    requested = float(dof.aperture_fstop)
    state.f_number_requested = requested
    if not (math.isfinite(requested) and requested > 0.0):
        n, msg = entry.f_number, (f"f-number {requested:g} is not usable; using the lens's "
                                  f"widest aperture f/{entry.f_number:g}")
    else:
        n, msg = clamp_f_number(requested, entry.f_number)
    if msg:
        state.say(WARNING, msg)
    state.f_number = n
    state.stop_radius_mm = stop_radius_for_f_number(entry.lens.stop_radius_mm, entry.f_number, n)

    # focus: Blender's own focus distance / focus object, refused nearer than the closest focus
    scale = unit_scale(scene)
    wanted_mm = focus_distance_bu(obj, cam) * scale * 1000.0
    state.focus_requested_m = wanted_mm / 1000.0
    distance_mm, msg = lensdata.clamp_focus_mm(entry, wanted_mm)
    if msg:
        state.say(WARNING, msg)
    state.focus_m = distance_mm / 1000.0

    # aperture shape
    try:
        aperture, aperture_key = _aperture(props, dof, state)
    except ApertureError as exc:
        state.error = exc
        state.say(ERROR, str(exc))
        return state

    # the model actually used
    model = MODEL_NAMES[props.model]
    dispersion = bool(props.dispersion)
    info = None
    if model == "auto":
        choice = auto_choice(entry, state.lens_id, camera_obj, scene)
        model = choice.kind
        if model == "learned":
            ok, msg = lensdata.onnxruntime_status()
            try:
                info = lensdata.model_info(choice.path) if ok else None
            except NeuroLensError as exc:
                ok, msg = False, f"the chosen model cannot be read ({exc})"
            if not ok:
                state.say(WARNING, msg)
                model, info = "exact", None
                choice = dataclasses.replace(
                    choice, kind="exact", name=EXACT_NAME, path=None, error_um_p99=0.0,
                    reason=f"{choice.name} meets the budget, but {msg}: the exact trace is used")
        state.choice = choice
    elif model == "learned":
        ok, msg = lensdata.onnxruntime_status()
        if not ok:
            state.say(WARNING, msg)
            model = "exact"
        else:
            info = lensdata.find_model(entry, library.model_candidates(state.lens_id))
            if info is None:
                from .preferences import user_directory
                state.say(WARNING, f"No trained NeuroLens model for '{entry.name}' (lens hash "
                          f"{entry.content_hash}) in {user_directory('models')}: train one "
                          "with 'python -m trainer fit LENS --out FOLDER/NAME'; using the "
                          "exact trace")
                model = "exact"

    # the sensor position that focuses (exact rays, so focus breathing is real)
    if model == "thin":
        sensor_z = 0.0
    else:
        try:
            sensor_z = lensdata.focus_sensor_z_mm(entry, distance_mm, state.stop_radius_mm)
        except FocusError as exc:
            state.error = exc
            state.say(ERROR, str(exc))
            return state
    state.sensor_z_mm = sensor_z

    if model == "learned" and info is not None:
        lo, hi = info.sensor_z_range
        if not (lo - 1e-6 <= sensor_z <= hi + 1e-6):
            state.say(WARNING, f"Focus at {distance_mm / 1000.0:.3f} m puts the sensor at z = "
                      f"{sensor_z:.3f} mm, outside the learned model's range [{lo:.3f}, "
                      f"{hi:.3f}] mm; using the exact trace")
            model, info = "exact", None
            if state.choice is not None:
                state.choice = dataclasses.replace(
                    state.choice, kind="exact", name=EXACT_NAME, path=None, error_um_p99=0.0,
                    reason=f"{state.choice.name} was trained for other focus settings: the "
                           "exact trace is used", trainable=True)
        elif dispersion and not info.dispersion:
            state.say(INFO, "This learned model was trained without dispersion: no chromatic "
                      "aberration (the exact trace has it)")
            dispersion = False
    state.model = model
    state.model_info = info
    model_dir = str(Path(info.directory)) if info is not None else None
    state.frame_mm = film_size_mm(cam, scene)

    state.fields = {"model": model, "lens": entry.lens, "model_dir": model_dir,
                    "sensor_z_mm": float(sensor_z), "f_number": float(n),
                    "aperture": aperture, "dispersion": dispersion,
                    "focal_mm": float(entry.efl_mm),
                    "focus_distance_m": float(distance_mm / 1000.0),
                    "sensor_width_mm": float(state.frame_mm[0]),
                    "sensor_height_mm": float(state.frame_mm[1]), "metres_per_unit": scale}
    state.key = (model, entry.content_hash, entry.path, model_dir, round(sensor_z, 9),
                 round(n, 9), aperture_key, dispersion, round(entry.efl_mm, 9),
                 round(distance_mm, 6), round(state.frame_mm[0], 9),
                 round(state.frame_mm[1], 9), scale)

    if model == "thin" and not dof.use_dof:
        state.say(INFO, "Blender's Depth of Field is off: the thin lens renders everything "
                  "sharp (the exact and learned lenses always have depth of field)")
    anim = getattr(camera_obj.data, "animation_data", None)
    if anim is not None and anim.action is not None and \
            not getattr(scene.render, "use_lock_interface", True):
        state.say(INFO, "This camera is animated: turn on Render > Lock Interface, so that "
                  "the lens can follow the animation safely while rendering")
    if with_fov:
        _field_of_view(state, cam, scene)
    return state


def _field_of_view(state: CameraState, cam, scene) -> None:
    w, h = state.frame_mm
    halves = (0.5 * w, 0.5 * h, 0.5 * math.hypot(w, h))
    entry = state.entry
    if state.model == "thin":
        f = entry.efl_mm
        state.fov_deg = tuple(2.0 * math.degrees(math.atan(x / f)) for x in halves)
        return
    state.fov_deg = tuple(lensdata.field_of_view_deg(entry, state.sensor_z_mm, x)
                          for x in halves)
    state.image_circle_mm = lensdata.image_circle_mm(entry, state.sensor_z_mm)
    if state.fov_deg[2] is None:
        state.say(INFO, f"The frame's corners lie outside the lens's image circle "
                  f"({state.image_circle_mm:.1f} mm across): they stay dark")
    if state.model_info is not None and halves[2] > state.model_info.film_radius_mm:
        state.say(WARNING, f"The frame's corners ({halves[2]:.1f} mm from the centre) lie beyond "
                  f"the learned model's film radius {state.model_info.film_radius_mm:.1f} mm: "
                  "those rays are outside its domain")


def camera_spec(camera_obj, scene, depsgraph=None):
    """The CameraSpec of a camera's settings. Raises the NeuroLensError (LensError,
    FocusError, ApertureError) that leaves it without one."""
    state = evaluate_camera(camera_obj, scene, depsgraph)
    if state.fields is None:
        raise state.error
    return make_spec(state.fields)


# =============================================================================================
# applying
# =============================================================================================
_STATUS: dict = {}     # camera object session_uid -> last CameraState (with apply messages)
_APPLIED: dict = {}    # camera data session_uid -> key of the spec last applied
_SYNCING: list = []


def last_state(camera_obj) -> CameraState | None:
    return _STATUS.get(camera_obj.session_uid)


def _restore_camera(camera_data) -> None:
    _apply_module().clear_lens_camera(camera_data)


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
    if state.fields is None:
        return state
    if not force and _APPLIED.get(data.session_uid) == state.key:
        return state
    module = _apply_module()
    try:
        module.apply_lens_camera(data, make_spec(state.fields))
    except NeuroLensError as exc:
        state.say(ERROR, f"Could not set up the lens camera: {exc}")
        return state
    except Exception as exc:  # noqa: BLE001 - a bug must not break Blender's handler loop
        traceback.print_exc()
        state.say(ERROR, f"Could not set up the lens camera ({exc.__class__.__name__}: {exc})")
        return state
    _APPLIED[data.session_uid] = state.key
    return state


def _enabled_camera_objects(scene):
    enabled = [c for c in bpy.data.cameras if c.neurolens.enabled or c.session_uid in _APPLIED]
    if not enabled:
        return []
    uids = {c.session_uid for c in enabled}
    return [o for o in scene.objects if o.type == "CAMERA" and o.data is not None
            and o.data.session_uid in uids]


def sync_scene(scene, depsgraph=None) -> list[CameraState]:
    """Sync every Real Lens camera of a scene (and undo cameras that were switched off)."""
    if _SYNCING:
        return []
    _SYNCING.append(True)
    try:
        return [sync_camera(o, scene, depsgraph) for o in _enabled_camera_objects(scene)]
    finally:
        _SYNCING.clear()


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
def _on_load_post(*_args):
    _STATUS.clear()
    _APPLIED.clear()
    for scene in bpy.data.scenes:
        sync_scene(scene)


HANDLERS = (
    ("frame_change_post", _on_frame_change_post),
    ("depsgraph_update_post", _on_depsgraph_update_post),
    ("load_post", _on_load_post),
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
    _MASKS.clear()
    _CHOICES.clear()
    _SYNCING.clear()
