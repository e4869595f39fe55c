"""The "Real Lens" panel in Camera properties (one panel, collapsible sections inside).

`draw_panel(layout, scene, camera_obj, camera_data)` does the drawing, so it can be exercised
without a window.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import bpy

from . import library, sync, training
from .camera_state import ERROR, INFO, WARNING, evaluate_camera

OSL_NOTE = "OSL cameras need Cycles on the CPU, or OptiX on NVIDIA GPUs"
_ICONS = {INFO: "INFO", WARNING: "ERROR", ERROR: "CANCEL"}
_WRAP = 58


def _wrapped(layout, text: str, icon: str = "NONE") -> None:
    lines = textwrap.wrap(text, _WRAP) or [""]
    col = layout.column(align=True)
    for k, line in enumerate(lines):
        col.label(text=line, icon=icon if k == 0 else "BLANK1")


def _fmt_deg(v) -> str:
    return "beyond the image circle" if v is None else f"{v:.1f}\u00b0"


def _section(layout, idname: str, title: str, default_closed: bool = False):
    header, body = layout.panel(idname, default_closed=default_closed)
    header.label(text=title)
    return body


def _cycles_device_warning(context_prefs, scene) -> str | None:
    """A warning when Cycles renders on a GPU backend other than OptiX (no OSL camera)."""
    if scene.render.engine != "CYCLES":
        return None
    if getattr(getattr(scene, "cycles", None), "device", "CPU") != "GPU":
        return None
    try:
        backend = context_prefs.addons["cycles"].preferences.compute_device_type
    except (KeyError, AttributeError):
        return None
    if backend in ("NONE", "OPTIX"):
        return None
    return (f"Cycles renders on the GPU with {backend}, which cannot run OSL cameras: "
            "switch the device to CPU, or the backend to OptiX")


def _draw_choice(layout, scene, camera_obj, choice) -> None:
    """Model AUTO: what it uses, its expected error against the budget, why, and (when no
    learned model meets the budget) the button that trains one for this scene."""
    box = layout.box()
    _wrapped(box, choice.summary, "NETWORK_DRIVE" if choice.kind == "learned" else "LIGHT_SUN")
    _wrapped(box, choice.reason, "INFO")
    for note in choice.notes:
        _wrapped(box, note, "TIME")
    settings = getattr(scene, "neurolens", None)
    if settings is not None:
        box.prop(settings, "pixel_fraction", text="Error Budget (px)")
    job = training.active_job()
    if job is not None:
        row = box.row(align=True)
        row.progress(factor=job.progress, type="BAR",
                     text=f"Training '{job.label}': {int(100 * job.progress)} %")
        row.operator("neurolens.cancel_scene_training", text="", icon="CANCEL")
        _wrapped(box, job.status, "TIME")
    elif choice.trainable:
        op = box.operator("neurolens.train_scene_model", text="Train a model for this scene",
                          icon="PLAY")
        if camera_obj is not None:
            op.camera = camera_obj.name


def draw_panel(layout, scene, camera_obj, cam, prefs=None) -> None:
    props = cam.neurolens
    dof = cam.dof
    state = evaluate_camera(camera_obj, scene, with_fov=True) if camera_obj else None
    entry = state.entry if state else None

    layout.use_property_split = True
    layout.use_property_decorate = True
    root = layout.column()
    root.active = props.enabled

    # ---- lens ---------------------------------------------------------------------------------
    body = _section(root, "neurolens_lens", "Lens")
    if body:
        body.row().prop(props, "source", expand=True)
        if props.source == "LIBRARY":
            body.template_icon_view(props, "lens", show_labels=True, scale=7.0, scale_popup=6.0)
            body.prop(props, "lens", text="Lens")
            body.prop(props, "lens_search", text="", icon="VIEWZOOM")
            row = body.row(align=True)
            op = row.operator("wm.path_open", text="Your Lens Folder", icon="FILE_FOLDER")
            op.filepath = str(library.user_lenses_dir())
        else:
            name = Path(props.lens_file).name if props.lens_file else "No lens file loaded"
            body.label(text=name, icon="FILE")
        body.operator("neurolens.load_lens_file", icon="FILEBROWSER")
        if entry is not None:
            box = body.box()
            _wrapped(box, entry.name, "CAMERA_DATA")
            if entry.table:
                focus = entry.closest_focus_mm
                at = "infinity" if not math.isfinite(focus) else f"{focus / 1000.0:.3g} m"
                box.label(text=f"Measured: {entry.focal_length_mm:.4g} mm  "
                               f"f/{entry.f_number:.3g}   Focused at {at}")
                _wrapped(box, "Known only from a ray table: its learned model renders it, "
                              "whatever its cost, at the table's focus and aperture", "INFO")
            else:
                box.label(text=f"Designed: {entry.focal_length_mm:.4g} mm  "
                               f"f/{entry.f_number:.3g}   "
                               f"Closest focus: {entry.closest_focus_mm / 1000.0:.2f} m")
            if entry.squeeze != 1.0:
                box.label(text=f"Anamorphic: {entry.squeeze:.3g}x squeeze, the frame "
                               "desqueezed", icon="INFO")
            zoom = entry.lens.zoom_gaps
            if zoom is not None:
                # a zoom lens takes Blender's own (keyframable) focal length, within its range
                box.prop(cam, "lens", text="Focal Length")
                box.label(text=f"Zooms {zoom.positions[0]:g}-{zoom.positions[-1]:g} mm",
                          icon="INFO")
        body.row().prop(props, "model", expand=True)
        if props.model == "AUTO" and state is not None and state.choice is not None:
            _draw_choice(body, scene, camera_obj, state.choice)

    # ---- focus --------------------------------------------------------------------------------
    body = _section(root, "neurolens_focus", "Focus")
    if body:
        body.prop(dof, "focus_object", text="Focus Object")
        if dof.focus_object is not None and dof.focus_object.type == "ARMATURE":
            body.prop_search(dof, "focus_subtarget", dof.focus_object.data, "bones",
                             text="Focus Bone")
        row = body.row(align=True)
        row.active = dof.focus_object is None
        row.prop(dof, "focus_distance", text="Distance")
        row.operator("neurolens.focus_pick", text="", icon="EYEDROPPER")
        if entry is not None and not entry.table:
            how = ("its focusing groups move" if entry.lens.focus_gaps is not None
                   else "the sensor moves")
            body.label(text=f"Closest focus {entry.closest_focus_mm / 1000.0:.3f} m; {how} to "
                            "focus (with breathing)", icon="INFO")

    # ---- aperture -----------------------------------------------------------------------------
    body = _section(root, "neurolens_aperture", "Aperture")
    if body:
        body.prop(dof, "aperture_fstop", text="F-Number")
        if state is not None and state.setup is not None and state.setup.f_number_clamped:
            body.label(text=f"Using f/{state.f_number:.3g}: the widest this lens opens",
                       icon="ERROR")
        body.row().prop(props, "aperture_shape", expand=True)
        if props.aperture_shape == "BLADES":
            body.prop(dof, "aperture_blades", text="Blades")
            body.prop(dof, "aperture_rotation", text="Rotation")
            body.prop(props, "blade_curvature", text="Curvature")
        elif props.aperture_shape == "MASK":
            body.template_ID(props, "mask_image", open="image.open")
        body.prop(props, "dispersion", text="Dispersion (chromatic aberration)")
        body.prop(props, "diffraction", text="Diffraction (starbursts)")
        body.prop(props, "ghosts", text="Ghosts (flare)")
        if props.ghosts:
            col = body.column(align=True)
            col.prop(props, "coating", text="Coating")
            col.prop(props, "ghost_intensity", text="Intensity")
            col.prop(props, "ghost_count", text="Ghosts")
            col.prop(props, "ghost_share", text="Samples")

    # ---- what the lens gives ------------------------------------------------------------------
    body = _section(root, "neurolens_info", "Field of View")
    if body and state is not None and state.fov_deg is not None:
        h, v, d = state.fov_deg
        w_mm, h_mm = state.frame_mm
        body.label(text=f"Frame {w_mm:.1f} x {h_mm:.1f} mm (the camera's sensor)")
        body.label(text=f"Horizontal {_fmt_deg(h)}   Vertical {_fmt_deg(v)}")
        body.label(text=f"Diagonal {_fmt_deg(d)}")
        if state.model != "thin" and math.isfinite(state.sensor_z_mm):
            body.label(text=f"Sensor at z = {state.sensor_z_mm:+.3f} mm for "
                            f"{state.focus_m:.3f} m focus")
        # the lens's distortion for compositing (camera.stmaps)
        body.operator("neurolens.write_st_maps", icon="EXPORT")

    # ---- messages and the render note ---------------------------------------------------------
    if state is not None:
        for level, text in state.messages:
            _wrapped(root, text, _ICONS.get(level, "INFO"))
        last = sync.last_state(camera_obj)
        if last is not None:
            for level, text in last.messages:
                if (level, text) not in state.messages:
                    _wrapped(root, text, _ICONS.get(level, "INFO"))
    note = layout.box()
    _wrapped(note, OSL_NOTE + ". The learned and exact lenses render through an OSL camera; "
             "Blender's thin lens renders anywhere.", "INFO")
    warning = _cycles_device_warning(prefs or bpy.context.preferences, scene)
    if warning:
        _wrapped(note, warning, "ERROR")


class NEUROLENS_PT_real_lens(bpy.types.Panel):
    bl_label = "Real Lens"
    bl_idname = "NEUROLENS_PT_real_lens"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return getattr(context, "camera", None) is not None

    def draw_header(self, context):
        self.layout.prop(context.camera.neurolens, "enabled", text="")

    def draw(self, context):
        obj = context.object
        if obj is None or obj.data != context.camera:   # pinned camera data: no object
            obj = None
        draw_panel(self.layout, context.scene, obj, context.camera, context.preferences)


CLASSES = (NEUROLENS_PT_real_lens,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
