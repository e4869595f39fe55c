"""Plain values a camera object and its scene hold, read with bpy: the scene's unit scale,
the camera's view axis and focus distance, and the film settings (camera.CameraSettings'
film). Read by the one camera reader (camera_reader) and by the scene's needs
(scene_needs_bpy)."""

from __future__ import annotations

from ..core.film import FULL_FRAME, FilmSettings


def unit_scale(scene) -> float:
    """Metres per Blender unit."""
    try:
        s = float(scene.unit_settings.scale_length)
    except AttributeError:
        return 1.0
    return s if s > 0.0 else 1.0


def view_axis(matrix_world):
    """Unit vector the camera looks along (its local -Z) in world space."""
    from mathutils import Vector
    return (matrix_world.to_3x3() @ Vector((0.0, 0.0, -1.0))).normalized()


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
    return max(abs((point - mw.translation).dot(view_axis(mw))), 1e-5)


def film_settings(camera_data, scene) -> FilmSettings:
    r = scene.render
    border = ((float(r.border_min_x), float(r.border_min_y), float(r.border_max_x),
               float(r.border_max_y)) if r.use_border else FULL_FRAME)
    return FilmSettings(
        sensor_width=float(camera_data.sensor_width),
        sensor_height=float(camera_data.sensor_height),
        sensor_fit=str(camera_data.sensor_fit), resolution_x=int(r.resolution_x),
        resolution_y=int(r.resolution_y), percentage=float(r.resolution_percentage),
        pixel_aspect_x=float(r.pixel_aspect_x), pixel_aspect_y=float(r.pixel_aspect_y),
        shift_x=float(camera_data.shift_x), shift_y=float(camera_data.shift_y), border=border)
