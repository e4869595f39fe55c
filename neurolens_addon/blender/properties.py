"""Per-camera settings: `camera.data.neurolens` (a PointerProperty on bpy.types.Camera).

Settings that mean the same thing as Blender's own camera settings are *not* duplicated:
the f-number, blade count and blade rotation are the camera's Depth of Field settings
(`dof.aperture_fstop`, `dof.aperture_blades`, `dof.aperture_rotation`), and so are the focus
distance and focus object. They stay in sync by construction (one value, two panels) and are
keyframed the way Blender users already do it. Only what Blender lacks lives here.

Every setting belongs to one camera datablock: nothing is shared between cameras. The one
scene-wide setting, the error budget of automatic model choice in pixels, is
`scene.neurolens.pixel_fraction` (it belongs with the render resolution it is measured in).

The lens model: AUTO (the default for new cameras) uses the cheapest model that meets the
scene's error budget (neural.choice; see camera.model_choice); EXACT, LEARNED and THIN are the
one-click overrides. The enum's stored numbers of EXACT/LEARNED/THIN are unchanged (0/1/2), so
files saved before AUTO existed keep the model they had.
"""

from __future__ import annotations

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty,
                       StringProperty)

from ..camera.resolve import MAX_GHOST_INTENSITY, MAX_GHOSTS
from . import library, thumbnails

MODEL_ITEMS = (
    ("AUTO", "Auto", "Automatic: the exact trace or the learned model, whichever costs less "
                     "a camera ray on this render engine, within this scene's error budget",
     "AUTO", 3),
    ("EXACT", "Exact", "Trace every ray through the real lens prescription (spectral, exact)",
     "LIGHT_SUN", 0),
    ("LEARNED", "Learned", ("NeuroLens: the lens's trained neural-network model (ONNX), "
                            "faster than the exact trace within its learned range"),
     "NETWORK_DRIVE", 1),
    ("THIN", "Thin Lens", ("Blender's own thin-lens camera with this lens's focal length "
                           "and f-number (fastest, no aberrations)"), "CAMERA_DATA", 2),
)
SOURCE_ITEMS = (
    ("LIBRARY", "Library", "A shipped preset or a lens from your lens folder"),
    ("FILE", "Lens File", "A lens file anywhere on disk (.toml, pbrt .dat or Zemax .zmx)"),
)
SHAPE_ITEMS = (
    ("CIRCLE", "Circle", "A round aperture", "MESH_CIRCLE", 0),
    ("BLADES", "Blades", ("An iris of straight or curved blades (the camera's Depth of "
                          "Field blade count and rotation)"), "SEQ_CHROMA_SCOPE", 1),
    ("MASK", "Mask", "An image: white lets light through, black blocks it", "IMAGE_DATA", 2),
)
_SHAPES = [item[0] for item in SHAPE_ITEMS]
DEFAULT_BLADES = 6

#: Blender keeps pointers to enum item strings: the list must outlive the callback.
_LENS_ITEMS: list = []


def _changed(self, context):
    from . import sync
    sync.on_settings_changed(self.id_data, context)


# ---- the lens picker: an enum view of the stored `lens_id` string -------------------------------
def lens_items(self, context):
    items = []
    for number, item in enumerate(library.items()):
        icon = thumbnails.icon_id(item.entry)
        if item.entry is not None:
            desc = (f"Designed {item.summary}. {item.entry.lens.source}")[:400]
        else:
            desc = item.error or "unreadable lens file"
        items.append((item.id, f"{item.label}  ({item.summary})" if item.entry else item.label,
                      desc, icon, number))
    if not items:
        items.append(("NONE", "No lenses found", "No lens files in the presets or your folder",
                      "ERROR", 0))
    _LENS_ITEMS[:] = items
    return _LENS_ITEMS


def _search_lenses(self, context, edit_text):
    """The picker's search: every library lens whose name or summary (focal length,
    f-number, kind) contains each typed word."""
    words = str(edit_text).lower().split()
    return [item.search_text for item in library.items()
            if all(w in item.search_text.lower() for w in words)]


def _pick_searched(self, context):
    """A lens chosen in the search becomes the camera's lens (the field then clears)."""
    text = self.lens_search
    if not text:
        return
    for item in library.items():
        if item.search_text == text:
            self.lens_id = item.id
            self.source = "LIBRARY"
            break
    self["lens_search"] = ""


def _get_lens(self):
    for number, item in enumerate(library.items()):
        if item.id == self.lens_id:
            return number
    return -1   # stored lens no longer in the library: nothing selected (the panel says why)


def _set_lens(self, value):
    entries = library.items()
    if 0 <= value < len(entries):
        self.lens_id = entries[value].id
        if self.source != "LIBRARY":
            self.source = "LIBRARY"


# ---- the aperture shape: CIRCLE / BLADES follow Blender's own blade count ---------------------
def _get_shape(self):
    if self.use_mask:
        return 2
    return 1 if self.id_data.dof.aperture_blades >= 3 else 0


def _set_shape(self, value):
    dof = self.id_data.dof
    shape = _SHAPES[value]
    self.use_mask = shape == "MASK"
    if shape == "CIRCLE":
        dof.aperture_blades = 0
    elif shape == "BLADES" and dof.aperture_blades < 3:
        dof.aperture_blades = DEFAULT_BLADES


class NEUROLENS_PG_camera(bpy.types.PropertyGroup):
    """The Real Lens settings of one camera."""

    enabled: BoolProperty(
        name="Real Lens", default=False, options=set(), update=_changed,
        description="Render this camera through a real multi-element lens")
    source: EnumProperty(
        name="Source", items=SOURCE_ITEMS, default="LIBRARY", options=set(), update=_changed,
        description="Where the lens comes from")
    lens_id: StringProperty(
        name="Lens Identifier", default=library.DEFAULT_LENS_ID, options={"HIDDEN"},
        update=_changed,
        description="The library lens: a preset's file stem, or 'user:' and a file name in "
                    "your lens folder")
    lens: EnumProperty(
        name="Lens", items=lens_items, get=_get_lens, set=_set_lens, options=set(),
        update=_changed,
        description="The lens: its cross-section, designed focal length and f-number")
    lens_search: StringProperty(
        name="Find Lens", default="", options={"SKIP_SAVE"}, search=_search_lenses,
        update=_pick_searched,
        description="Search the library by name, focal length, f-number or kind (zoom, "
                    "fisheye, wide angle, normal, telephoto)")
    lens_file: StringProperty(
        name="Lens File", default="", subtype="FILE_PATH", options=set(),
        description="The lens file in use when the source is a file (set it with Load Lens "
                    "File, which checks it first)")
    model: EnumProperty(
        name="Lens Model", items=MODEL_ITEMS, default="AUTO", options=set(), update=_changed,
        description="How rays go through the lens")
    aperture_shape: EnumProperty(
        name="Aperture Shape", items=SHAPE_ITEMS, get=_get_shape, set=_set_shape,
        options=set(), update=_changed,
        description="The shape of the aperture stop (and so of the bokeh)")
    use_mask: BoolProperty(
        name="Use Mask", default=False, options={"HIDDEN"}, update=_changed,
        description="The aperture is an image mask")
    blade_curvature: FloatProperty(
        name="Blade Curvature", default=0.0, min=0.0, max=1.0, subtype="FACTOR",
        update=_changed,
        description="0: straight blades (a polygon); 1: round (a circle)")
    mask_image: PointerProperty(
        name="Mask Image", type=bpy.types.Image, update=_changed,
        description="The aperture mask: luminance times alpha is the transmittance, "
                    "stretched over the full aperture")
    dispersion: BoolProperty(
        name="Dispersion", default=True, update=_changed,
        description="Trace each camera ray at its own wavelength through the glass: "
                    "spectral chromatic aberration (off: every ray at the d line)")
    ghosts: BoolProperty(
        name="Ghosts", default=False, update=_changed,
        description="Render the light the lens's surfaces reflect twice before it reaches "
                    "the sensor: ghost images of bright lights, flare")
    coating: EnumProperty(
        name="Coating", default="SINGLE", update=_changed,
        items=[("BARE", "Uncoated", "Bare glass: Fresnel reflection, 4-8 % a surface"),
               ("SINGLE", "Single Layer", "A quarter-wave MgF2 layer (1-2 % a surface)"),
               ("MULTI", "Multi-Layer", "A broadband three-layer stack (under 0.5 % over "
                                         "the visible on crown glass)")],
        description="What covers every air-glass surface (cemented faces stay bare)")
    ghost_intensity: FloatProperty(
        name="Ghost Intensity", default=1.0, min=0.0, soft_max=100.0,
        max=MAX_GHOST_INTENSITY, update=_changed,
        description="Multiplier of the ghosts' light (1: as the optics give it)")
    ghost_count: IntProperty(
        name="Ghost Count", default=8, min=1, max=MAX_GHOSTS, update=_changed,
        description="How many of the brightest ghosts are rendered")
    ghost_share: FloatProperty(
        name="Ghost Samples", default=0.25, min=0.02, max=0.9, subtype="FACTOR",
        update=_changed, description="Share of camera samples spent on ghosts")
    diffraction: BoolProperty(
        name="Diffraction", default=False, update=_changed,
        description="Spread every camera ray by the aperture's Fraunhofer pattern at its "
                    "wavelength: starbursts on bright highlights (spikes from the blades), "
                    "softening at small apertures")


def _scene_changed(self, context):
    from . import sync
    sync.sync_scene(self.id_data)


class NEUROLENS_PG_scene(bpy.types.PropertyGroup):
    """Scene-wide Real Lens settings."""

    pixel_fraction: FloatProperty(
        name="Error Budget", default=0.5, min=0.01, max=10.0, soft_min=0.05, soft_max=2.0,
        precision=2, step=5, options=set(), update=_scene_changed,
        description="The lens-model error this scene can afford, in pixels: automatic model "
                    "choice uses the cheapest model whose measured image error (99th "
                    "percentile) stays within this fraction of a pixel")


CLASSES = (NEUROLENS_PG_camera, NEUROLENS_PG_scene)


_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def register():
    _register_classes()
    bpy.types.Camera.neurolens = PointerProperty(type=NEUROLENS_PG_camera, name="Real Lens")
    bpy.types.Scene.neurolens = PointerProperty(type=NEUROLENS_PG_scene, name="Real Lens")


def unregister():
    if hasattr(bpy.types.Scene, "neurolens"):
        del bpy.types.Scene.neurolens
    if hasattr(bpy.types.Camera, "neurolens"):
        del bpy.types.Camera.neurolens
    _unregister_classes()
    _LENS_ITEMS.clear()
