"""A scene's render settings as core.scene_needs.RenderNeeds (what a lens model must do).

`render_needs(scene, camera_obj)` reads
  * scene.render: resolution_x / _y, resolution_percentage, the render region (use_border and
    border_min_x / _max_x / _min_y / _max_y);
  * the camera data: sensor_width, sensor_height, sensor_fit, shift; the pixel aspect;
  * the f-numbers and focus distances the frames use: a Depth of Field f-stop or focus distance
    animated by an F-curve of the camera data's action is evaluated at every frame of
    [frame_start, frame_end] (F-curve evaluation, no frame_set: nothing in the scene moves);
    with a focus object the distance at the current frame is used, and a note says so;
  * dispersion from the camera's Real Lens settings (camera.data.neurolens.dispersion);
  * the allowed error in pixels from the scene's Real Lens settings
    (scene.neurolens.pixel_fraction, default 0.5 px).
Notes for the panel are in `needs.extras["notes"]`.

The reduction to what decides a lens's region and the region itself are
neurolens_addon.camera.model_choice's (`region_needs`, `scene_region`).
`cli_arguments(needs)` gives the matching `python -m trainer fit-scene` options.
"""

from __future__ import annotations

import math
from ..core.scene_needs import RenderNeeds, SceneNeedsError
from .camera_values import film_settings, focus_distance_bu, unit_scale

DEFAULT_PIXEL_FRACTION = 0.5
FSTOP_PATH = "dof.aperture_fstop"
FOCUS_PATH = "dof.focus_distance"
#: longer frame ranges are sampled (every k-th frame, plus keyframes and the ends)
MAX_SAMPLED_FRAMES = 20_000

__all__ = ["DEFAULT_PIXEL_FRACTION", "RenderNeeds", "SceneNeedsError", "animated_values",
           "animation_fcurves", "cli_arguments", "pixel_fraction", "render_needs"]


def pixel_fraction(scene) -> float:
    """The scene's error budget in pixels (scene.neurolens.pixel_fraction)."""
    props = getattr(scene, "neurolens", None)
    value = getattr(props, "pixel_fraction", None) if props is not None else None
    try:
        value = float(value)
    except (TypeError, ValueError):
        return DEFAULT_PIXEL_FRACTION
    return value if math.isfinite(value) and value > 0.0 else DEFAULT_PIXEL_FRACTION


def animation_fcurves(id_data) -> dict:
    """{(data_path, array_index): FCurve} of the action assigned to `id_data` (muted curves
    left out). Blender 4.4+ keeps F-curves in the channelbag of the assigned action slot."""
    anim = getattr(id_data, "animation_data", None)
    if anim is None or anim.action is None:
        return {}
    curves = None
    try:
        from bpy_extras import anim_utils
        bag = anim_utils.animdata_get_channelbag_for_assigned_slot(anim)
        curves = list(bag.fcurves) if bag is not None else []
    except (ImportError, AttributeError):
        curves = list(getattr(anim.action, "fcurves", ()))   # Blender before slotted actions
    return {(fc.data_path, fc.array_index): fc for fc in curves if not fc.mute}


def _frames(fcurve, start: int, end: int) -> list:
    if end < start:
        start, end = end, start
    count = end - start + 1
    if count <= MAX_SAMPLED_FRAMES:
        return list(range(start, end + 1))
    step = math.ceil(count / MAX_SAMPLED_FRAMES)
    frames = set(range(start, end + 1, step)) | {start, end}
    frames |= {round(k.co[0]) for k in fcurve.keyframe_points
               if start <= k.co[0] <= end}
    return sorted(frames)


def sampled_values(fcurve, start: int, end: int) -> list[float]:
    """The F-curve's value at every frame of [start, end] (see MAX_SAMPLED_FRAMES)."""
    return [float(fcurve.evaluate(f)) for f in _frames(fcurve, start, end)]


def _distinct(values, scale: float = 1.0) -> tuple[float, ...]:
    """Distinct positive finite values (times `scale`), sorted. Not rounded: a value that is
    not animated stays the very float the render uses, so focus solves are shared with it."""
    return tuple(sorted({v * scale for v in values if math.isfinite(v) and v * scale > 0.0}))


def _moves(ob) -> bool:
    """An object whose place may change over the frames (an action, a parent or a
    constraint)."""
    anim = getattr(ob, "animation_data", None)
    return bool((anim is not None and (anim.action is not None or len(anim.drivers)))
                or getattr(ob, "parent", None) is not None or len(getattr(ob, "constraints", ())))


def animated_values(scene, camera_obj) -> tuple[tuple, tuple, bool]:
    """(focus distances (mm, from the sensor), f-numbers) the frames of [frame_start,
    frame_end] use where an F-curve animates them, () where nothing does, and whether an
    F-curve animates the focal length (a zoom lens's setting). A focus object that moves (or a
    camera that moves towards it) could set any distance: (0.0, inf), 0 standing for the
    lens's closest focus."""
    obj = getattr(camera_obj, "original", None) or camera_obj
    cam = obj.data
    start, end = int(scene.frame_start), int(scene.frame_end)
    curves = animation_fcurves(cam)
    fc = curves.get((FSTOP_PATH, 0))
    f_numbers = _distinct(sampled_values(fc, start, end)) if fc is not None else ()
    target = cam.dof.focus_object
    if target is not None:
        focus = (0.0, math.inf) if (_moves(target) or _moves(obj)) else ()
    else:
        fc = curves.get((FOCUS_PATH, 0))
        focus = (_distinct(sampled_values(fc, start, end), unit_scale(scene) * 1000.0)
                 if fc is not None else ())
    return tuple(focus), tuple(f_numbers), ("lens", 0) in curves


def render_needs(scene, camera_obj) -> RenderNeeds:
    """What `scene` renders through `camera_obj` asks of a lens model (see the module
    docstring). Raises SceneNeedsError for settings that describe no image."""
    obj = getattr(camera_obj, "original", None) or camera_obj
    cam = obj.data
    dof = cam.dof
    notes = []
    start, end = int(scene.frame_start), int(scene.frame_end)
    curves = animation_fcurves(cam)
    scale = unit_scale(scene)

    fc = curves.get((FSTOP_PATH, 0))
    if fc is not None:
        f_numbers = _distinct(sampled_values(fc, start, end))
        if f_numbers:
            notes.append(f"F-number animated: f/{f_numbers[0]:.3g} to f/{f_numbers[-1]:.3g} "
                         f"over frames {start}-{end}")
    else:
        f_numbers = _distinct([float(dof.aperture_fstop)])

    target = dof.focus_object
    if target is not None:
        d = focus_distance_bu(obj, cam) * scale
        focus = _distinct([d])
        notes.append(f"Focus follows '{target.name}': its distance at the current frame "
                     f"({scene.frame_current}), {d:.3f} m, is what the model choice assumes")
    else:
        fc = curves.get((FOCUS_PATH, 0))
        if fc is not None:
            focus = _distinct(sampled_values(fc, start, end), scale)
            if focus:
                notes.append(f"Focus distance animated: {focus[0]:.3g} to {focus[-1]:.3g} m "
                             f"over frames {start}-{end}")
        else:
            focus = _distinct([float(dof.focus_distance)], scale)
    drivers = getattr(getattr(cam, "animation_data", None), "drivers", None) or ()
    if any(d.data_path in (FSTOP_PATH, FOCUS_PATH) for d in drivers):
        notes.append("A driver sets the f-number or focus: only its current value is known")

    props = getattr(cam, "neurolens", None)
    return RenderNeeds.from_film(
        film_settings(cam, scene), f_numbers=f_numbers, focus_distances_m=focus,
        dispersion=bool(props.dispersion) if props is not None else True,
        pixel_fraction=pixel_fraction(scene), extras={"notes": notes})


def cli_arguments(needs: RenderNeeds) -> list[str]:
    """The `python -m trainer fit-scene` options for `needs` (floats written exactly)."""
    args = ["--resolution", f"{needs.resolution_x}x{needs.resolution_y}",
            "--percentage", repr(float(needs.resolution_percentage)),
            "--sensor-width", repr(float(needs.sensor_width_mm)),
            "--sensor-height", repr(float(needs.sensor_height_mm)),
            "--sensor-fit", needs.sensor_fit]
    if tuple(needs.border) != (0.0, 0.0, 1.0, 1.0):
        args += ["--border", ",".join(repr(float(v)) for v in needs.border)]
    for f in sorted(set(needs.f_numbers)):
        args += ["--fstop", repr(float(f))]
    for d in sorted(set(needs.focus_distances_m)):
        args += ["--focus", repr(float(d))]
    if not needs.dispersion:
        args.append("--no-dispersion")
    for name in ("pixel_aspect_x", "pixel_aspect_y", "shift_x", "shift_y"):
        value = float(getattr(needs, name))
        if value != (1.0 if name.startswith("pixel") else 0.0):
            args += ["--" + name.replace("_", "-"), repr(value)]
    args += ["--pixel-fraction", repr(float(needs.pixel_fraction))]
    return args
