"""The one bpy reader: a camera object -> camera.CameraSettings (plain values, no decisions).

Where each setting comes from:
  lens      the Real Lens panel (`camera.data.neurolens`, when enabled): a library lens or a
            lens file; otherwise the custom properties the command line documents:
              camera.data["neurolens_lens"]   a preset name or a lens file path
              camera.data["neurolens_model"]  "auto" (the default, as the panel's), "exact",
                                              "learned", "thin" or a NAME.neurolens directory
              camera.data["neurolens_diffraction"]  1 for diffraction (the panel's checkbox
                                              when the add-on's properties are registered)
              camera.data["neurolens_dispersion"]  0 for none (likewise; default: on)
              camera.data["neurolens_ghosts"]  1 for ghosts; "neurolens_coating" (bare,
                                              single, multi), "neurolens_ghost_intensity",
                                              "neurolens_ghost_count", "neurolens_ghost_share"
  f-number  Blender's Depth of Field F-Stop (dof.aperture_fstop);
  focus     dof.focus_object (its bone's head with a focus subtarget) measured along the view
            axis, else dof.focus_distance; scene units times scene.unit_settings.scale_length;
  aperture  the panel's shape (circle / blades / mask), Blender's blade count and rotation,
            the panel's blade curvature and mask image; without the panel, blades >= 3;
  film      the camera's sensor size, fit and shift; the render's resolution, percentage,
            pixel aspect and render region;
  model     AUTO also reads what the scene needs (scene_needs_bpy) and where models are.
With a depsgraph the *evaluated* camera is read: what a render of this frame sees.
`lens_setup(...)` is the reader followed by the one resolver (camera.resolve_camera).
"""

from __future__ import annotations

import hashlib
import math

import bpy

from ..camera import ApertureSettings, CameraSettings, GhostSettings, LensSetup, resolve_camera
from ..camera import lenses
from ..camera.lenses import library_path, resolve_lens_path
from ..camera.setup import INFO
from ..core.errors import ApertureError, LensError
from .camera_values import film_settings, focus_distance_bu, unit_scale
from .scene_needs_bpy import animated_values, pixel_fraction, render_needs

LENS_PROP = "neurolens_lens"
MODEL_PROP = "neurolens_model"
DIFFRACTION_PROP = "neurolens_diffraction"
DISPERSION_PROP = "neurolens_dispersion"
GHOST_PROPS = ("neurolens_ghosts", "neurolens_coating", "neurolens_ghost_intensity",
               "neurolens_ghost_count", "neurolens_ghost_share")


def ghost_settings(camera_data) -> GhostSettings:
    """The panel's ghost settings, or the custom properties without the add-on's panel."""
    props = getattr(camera_data, "neurolens", None)
    if props is not None:
        return GhostSettings(bool(props.ghosts), str(props.coating).lower(),
                             float(props.ghost_intensity), int(props.ghost_count),
                             float(props.ghost_share))
    d = GhostSettings()
    on, coating, k, count, share = (camera_data.get(name) for name in GHOST_PROPS)
    return GhostSettings(bool(on or 0), str(coating or d.coating).lower(),
                         float(d.intensity if k is None else k),
                         int(d.count if count is None else count),
                         float(d.share if share is None else share))
PANEL_MODELS = {"AUTO": "auto", "EXACT": "exact", "LEARNED": "learned", "THIN": "thin"}


# ---- the aperture mask: a Blender image -> core ImageMaskAperture, cached by its pixels -------
_MASKS: dict = {}


def mask_image_size(image) -> tuple[int, int]:
    """(width, height) of a Blender image without decoding it when it is not loaded yet: a
    generated image's own size, a file's (or a packed file's) header (core.image_header);
    Blender's size (which loads the image) only when it is loaded already or no header says."""
    import io

    from ..core.image_header import image_size
    if image.has_data or image.is_dirty:
        return tuple(image.size)
    if image.source == "GENERATED":
        return int(image.generated_width), int(image.generated_height)
    size = None
    if image.source == "FILE":
        packed = image.packed_file
        if packed is not None:
            size = image_size(io.BytesIO(packed.data), image.filepath_raw)
        else:
            path = bpy.path.abspath(image.filepath_raw, library=image.library)
            try:
                with open(path, "rb") as f:
                    size = image_size(f, path)
            except OSError:
                size = None
    return size if size is not None else tuple(image.size)


def mask_aperture(image):
    """(ImageMaskAperture, key) of a Blender image (luminance x alpha), cached by pixels.

    The image's size comes from its header (mask_image_size) and an image over the pixel limit
    is refused, naming it and its size, before Blender decodes it; an accepted image's pixels
    are read once as float32 and reduced a block of rows at a time (ImageMaskAperture.from_rows:
    no full-size float64 copy); an image this loaded is unloaded again (its decoded pixels are
    not needed: only the reduced mask is kept)."""
    import numpy as np

    from ..core.aperture import ImageMaskAperture
    from ..core.aperture.image_mask import check_mask_size, transmittance_rows

    was_loaded = image.has_data
    w, h = mask_image_size(image)
    where = f"aperture mask image '{image.name}'"
    if w < 1 or h < 1:
        raise ApertureError(f"{where} has no pixels (is the file missing?)")
    check_mask_size(w, h, where + (f" ({image.filepath_raw})" if image.filepath_raw else ""))
    key = (image.session_uid, w, h, image.filepath_raw)
    hit = _MASKS.get(key)
    if hit is not None and not image.is_dirty:
        return hit[1], (image.name_full, hit[0])
    if tuple(image.size) != (w, h):             # loads it: the header must have told the truth
        w, h = image.size
        check_mask_size(w, h, where)
    c = image.channels
    px = np.empty(w * h * c, dtype=np.float32)
    image.pixels.foreach_get(px)
    digest = hashlib.sha1(memoryview(px)).hexdigest()          # no bytes copy
    if hit is not None and hit[0] == digest:
        return hit[1], (image.name_full, digest)
    img = px.reshape(h, w, c)

    def rows_of(a, b):             # Blender's row 0 is the bottom: mask row i is h - 1 - i
        return transmittance_rows(img[h - b:h - a][::-1], 1.0)

    try:
        aperture = ImageMaskAperture.from_rows(h, w, rows_of, source=image.name)
    finally:
        if not was_loaded and not image.is_dirty:
            image.buffers_free()
    if len(_MASKS) > 16:
        _MASKS.clear()
    _MASKS[key] = (digest, aperture)
    return aperture, (image.name_full, digest)


def aperture_settings(camera_data) -> ApertureSettings:
    dof = camera_data.dof
    props = getattr(camera_data, "neurolens", None)
    if props is not None:
        shape = props.aperture_shape
    else:
        shape = "BLADES" if int(dof.aperture_blades) >= 3 else "CIRCLE"
    if shape == "MASK":
        if props.mask_image is None:
            return ApertureSettings("mask", mask_problem="Aperture mask: no image chosen")
        try:
            mask, key = mask_aperture(props.mask_image)
        except ApertureError as exc:
            return ApertureSettings("mask", mask_problem=str(exc))
        return ApertureSettings("mask", mask=mask, mask_key=key)
    if shape == "BLADES":
        return ApertureSettings("blades", blades=int(dof.aperture_blades),
                                rotation_deg=math.degrees(float(dof.aperture_rotation)),
                                curvature=float(props.blade_curvature) if props else 0.0)
    return ApertureSettings()


# ---- the lens and where its models are ---------------------------------------------------------
def uses_panel(camera_data) -> bool:
    props = getattr(camera_data, "neurolens", None)
    return props is not None and bool(props.enabled)


def _user_directory(kind: str):
    from .preferences import user_directory
    return user_directory(kind)


def panel_lens_path(props) -> tuple[str | None, str]:
    """(library id or None, file path) of the lens the panel names."""
    if props.source == "FILE":
        if not props.lens_file:
            raise LensError("no lens file loaded: use Load Lens File to pick one")
        return None, bpy.path.abspath(props.lens_file)
    lens_id = props.lens_id
    try:
        folder = _user_directory("lenses") if lens_id.startswith(lenses.USER_PREFIX) else None
    except OSError as exc:
        raise LensError(f"your lens folder cannot be used ({exc})") from None
    return lens_id, library_path(lens_id, folder)


def _model_candidates(lens_id, model: str, notes: list) -> tuple[tuple, str | None]:
    """(candidates, the user's models folder): the preset's own model, the user's models folder
    (and, for model AUTO, the scene models trained there), the presets."""
    from ..neural.cache import cache_dir
    out, folder = [lenses.preset_model_dir(lens_id)], None
    try:
        models = _user_directory("models")
        folder = str(models)
        out += [models, cache_dir(models)] if model == "auto" else [models]
    except OSError as exc:
        notes.append((INFO, f"Your models folder cannot be used ({exc})"))
    out.append(lenses.PRESET_MODELS_DIR)
    return tuple(str(c) for c in out if c is not None), folder


def _custom_lens(camera_obj) -> tuple[str | None, str, str, str | None]:
    """(library id, file path, model, model directory) from the command line's properties."""
    cam = camera_obj.data
    name = cam.get(LENS_PROP)
    if not name:
        from ..camera.lenses import preset_names
        raise LensError(f"camera '{camera_obj.name}' names no lens: set its '{LENS_PROP}' "
                        f"custom property to a preset name ({', '.join(preset_names()[:3])}, "
                        "...) or a lens file path, or turn on its Real Lens panel")
    path = resolve_lens_path(str(name))
    lens_id = lenses.preset_id(path)
    choice = str(cam.get(MODEL_PROP, "auto") or "auto")
    if choice.lower() in PANEL_MODELS.values():
        return lens_id, str(path), choice.lower(), None
    return lens_id, str(path), "learned", choice


def lens_reference(camera_obj, *, include_disabled: bool = False):
    """(library id, file path, model, model directory) the camera names (module docstring).
    `include_disabled`: a camera whose Real Lens panel is off and that names no lens otherwise
    reads the panel anyway (what the panel shows, greyed). Raises LensError: no lens."""
    cam = camera_obj.data
    if uses_panel(cam) or (include_disabled and getattr(cam, "neurolens", None) is not None
                           and not cam.get(LENS_PROP)):
        props = cam.neurolens
        lens_id, path = panel_lens_path(props)
        return lens_id, path, PANEL_MODELS[props.model], None
    return _custom_lens(camera_obj)


def renderer_of(scene) -> str:
    """The renderer that renders `scene` as model AUTO names it: "cycles" or "neurolens" (the
    NEUROLENS engine, and any other engine: the lens is ours there)."""
    return "cycles" if scene.render.engine == "CYCLES" else "neurolens"


def read_camera(camera_obj, scene, depsgraph=None, *,
                include_disabled: bool = False) -> CameraSettings:
    """The CameraSettings of a camera object (module docstring). Raises LensError when the
    camera names no usable lens (see lens_reference for `include_disabled`)."""
    if camera_obj is None or getattr(camera_obj, "type", None) != "CAMERA":
        raise LensError("the scene has no active camera (set scene.camera to a camera object)")
    obj = camera_obj.evaluated_get(depsgraph) if depsgraph is not None else camera_obj
    cam = obj.data
    notes: list = []
    lens_id, path, model, model_dir = lens_reference(camera_obj,
                                                     include_disabled=include_disabled)
    props = getattr(cam, "neurolens", None)
    dispersion = bool(props.dispersion if props is not None else cam.get(DISPERSION_PROP, 1))
    diffraction = bool(props.diffraction if props is not None else cam.get(DIFFRACTION_PROP, 0))
    scale = unit_scale(scene)
    needs, needs_error = None, None
    if model == "auto":
        from ..core.scene_needs import SceneNeedsError
        try:
            needs = render_needs(scene, camera_obj)
        except SceneNeedsError as exc:
            needs_error = str(exc)
    if model == "thin" and not cam.dof.use_dof:
        notes.append((INFO, "Blender's Depth of Field is off: the thin lens renders everything "
                            "sharp (the exact and learned lenses always have depth of field)"))
    anim = getattr(camera_obj.data, "animation_data", None)
    if anim is not None and anim.action is not None and \
            not getattr(scene.render, "use_lock_interface", True):
        notes.append((INFO, "This camera is animated: turn on Render > Lock Interface, so that "
                            "the lens can follow the animation safely while rendering"))
    animated = animated_values(scene, camera_obj)
    candidates, models_folder = _model_candidates(lens_id, model, notes)
    return CameraSettings(
        camera=camera_obj.name, lens_path=path, lens_id=lens_id, model=model,
        model_dir=model_dir, model_candidates=candidates, models_folder=models_folder,
        f_number=float(cam.dof.aperture_fstop),
        focus_distance_mm=focus_distance_bu(obj, cam) * scale * 1000.0,
        zoom_mm=float(cam.lens), zoom_animated=animated[2],
        animated_focus_mm=animated[0], animated_f_numbers=animated[1],
        aperture=aperture_settings(cam), dispersion=dispersion, diffraction=diffraction,
        ghosts=ghost_settings(cam),
        film=film_settings(cam, scene), metres_per_unit=scale, needs=needs,
        needs_error=needs_error, pixel_fraction=pixel_fraction(scene),
        renderer=renderer_of(scene),
        notes=tuple(notes))


def lens_setup(camera_obj, scene, depsgraph=None, *, include_disabled: bool = False) -> LensSetup:
    """The LensSetup of a camera object: the one reader, then the one resolver."""
    return resolve_camera(read_camera(camera_obj, scene, depsgraph,
                                      include_disabled=include_disabled))


def forget() -> None:
    _MASKS.clear()
