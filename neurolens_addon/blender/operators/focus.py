"""Focusing on a picked point: the camera focuses at the depth of a surface clicked in a 3D
Viewport, or tracks the clicked object.

The depth of a point P for a camera at C looking along its view axis a is (P - C) . a, the
way Blender measures its own focus distance; it must be positive and no nearer than the
lens's closest focus. `focus_on_point` and `pick_point` work without the modal operator, for
scripts and tests.
"""

from __future__ import annotations

import bpy
from bpy.props import FloatVectorProperty

from ...core.errors import FocusError, NeuroLensError
from ...camera.focusing import refuse_nearer_than_closest
from ...camera.lenses import load_lens_entry
from .. import camera_reader, camera_values
from .common import camera_object, option


def focus_on_point(context, camera_obj, world_point, *, hit_object=None,
                   track_object: bool = False) -> float:
    """Focus `camera_obj` at the depth of `world_point` (along its view axis, as Blender's own
    focus distance is measured) and return that distance in scene units.

    track_object with a hit_object: make it the focus object instead (focus follows its
    origin). Raises FocusError, changing nothing, for a point behind the camera or nearer
    than the lens's closest focus.
    """
    from mathutils import Vector

    scene = context.scene
    mw = camera_obj.matrix_world
    axis = camera_values.view_axis(mw)
    target = hit_object.original if (track_object and hit_object is not None) else None
    point = target.matrix_world.translation if target is not None else Vector(world_point)
    depth = float((point - mw.translation).dot(axis))
    if track_object and target is not None:
        depth = max(abs(depth), 1e-5)         # Blender measures a focus object this way
    if not depth > 0.0:
        raise FocusError("the picked point is behind the camera: focus unchanged")
    cam = camera_obj.data
    try:
        _lens_id, path, _model, _dir = camera_reader.lens_reference(camera_obj)
        entry = load_lens_entry(path)
    except NeuroLensError:
        entry = None            # no real lens: Blender's own focus distance is all there is
    if entry is not None:
        refuse_nearer_than_closest(entry, depth * camera_values.unit_scale(scene) * 1000.0,
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
    use_location: option(
        "Use Location", "Focus on `location` instead of picking in a 3D Viewport",
        options={"HIDDEN", "SKIP_SAVE"})
    track_object: option(
        "Track Object", "Make the picked object the focus object: focus then follows its origin")

    @classmethod
    def poll(cls, context):
        return camera_object(context) is not None

    def _focus(self, context, location, obj):
        cam_obj = bpy.data.objects.get(self._camera_name) if getattr(
            self, "_camera_name", None) else camera_object(context)
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
        cam_obj = camera_object(context)
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


CLASSES = (NEUROLENS_OT_focus_pick,)
