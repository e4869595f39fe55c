"""register() / unregister() of the NEUROLENS engine: the RenderEngine class, its settings
(`scene.neurolens_engine`) with a Render Properties panel, and the engine's name added to the
built-in panels that make sense for it (output, dimensions, camera, light, world, material)."""

from __future__ import annotations

import bpy

from ..engine.plan import DEFAULT_MAX_RAYS, HARD_MAX_RAYS
from ..engine.settings import LIGHT_PATHS, RenderSettings
from .render_engine import ENGINE_ID, NeuroLensRenderEngine

_D = RenderSettings()


class NEUROLENS_PG_engine(bpy.types.PropertyGroup):
    samples: bpy.props.IntProperty(name="Samples", default=_D.samples, min=1, soft_max=1024,
                                   description="Camera samples per pixel")
    tile_size: bpy.props.IntProperty(name="Tile Size", default=_D.tile_size, min=8, max=512,
                                     description="Tile edge in pixels")
    max_bundle_rays: bpy.props.IntProperty(
        name="Bundle Size", default=DEFAULT_MAX_RAYS, min=1024, max=HARD_MAX_RAYS,
        description="Most camera samples evaluated through the lens at once (memory bound)")
    uncertainty_samples: bpy.props.IntProperty(
        name="Uncertainty Samples", default=_D.uncertainty_samples, min=0, soft_max=64,
        description="Samples per pixel that compute the learned lens's ensemble spread")
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    dispersion: bpy.props.BoolProperty(name="Dispersion", default=True,
                                       description="Sample wavelengths (chromatic aberration)")
    workers: bpy.props.IntProperty(
        name="Worker Threads", default=_D.workers, min=0, max=16,
        description="Threads that shade bundles at once (0: one per core; Blender ray casts "
                    "always use one)")
    colour_rays: bpy.props.EnumProperty(
        name="Colour Rays", default=str(_D.colour_rays),
        items=[("3", "Three (R, G, B)", "Three lens rays a sample, one a colour channel: no "
                                        "colour noise"),
               ("1", "One", "One lens ray a sample at a wavelength drawn across the sensor, as "
                            "the Cycles camera: three times less work a sample, colour noise")])
    device: bpy.props.EnumProperty(
        name="Device", default="AUTO",
        items=[("AUTO", "Auto", "onnxruntime CUDA when available, else CPU"),
               ("CPU", "CPU", "onnxruntime on the CPU")])
    denoise: bpy.props.BoolProperty(
        name="Denoise", default=True,
        description="Open Image Denoise on the finished frame, guided by albedo and normal "
                    "(the noisy frame is kept as the Noisy Image pass)")
    tile_order: bpy.props.EnumProperty(
        name="Tile Order", default=_D.tile_order,
        items=[("AUTO", "Auto", "Progressive, except for a frame of one pass or whose film "
                                "would pass 256 MB (then tile by tile): the same image"),
               ("PROGRESSIVE", "Progressive", "Every tile a pass at a time: the whole frame "
                                              "refines; the film holds the whole frame (64 "
                                              "bytes a pixel)"),
               ("TILES", "Tile by Tile", "Each tile finished before the next: the film holds "
                                         "one tile (large frames)")])
    memory_limit_gb: bpy.props.FloatProperty(
        name="Memory Limit (GB)", default=_D.memory_limit_gb, min=0.0, soft_max=1024.0,
        description="A render estimated to need more than this is refused before it starts; "
                    "0: the memory this machine has available")
    intersector: bpy.props.EnumProperty(
        name="Ray Casts", default="AUTO",
        items=[("AUTO", "Auto", "Intel Embree when installed (tens of times faster), else "
                                "Blender's BVH"),
               ("EMBREE", "Embree", "Intel Embree over the frame's triangles (embreex)"),
               ("BLENDER", "Blender", "Blender's own BVH, one scene.ray_cast call a ray")])


class _EnginePanel:
    """A properties-editor panel shown only while the engine renders the scene."""
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class NEUROLENS_PT_engine(_EnginePanel, bpy.types.Panel):
    bl_label = "NeuroLens"
    bl_context = "render"

    def draw(self, context):
        props = context.scene.neurolens_engine
        col = self.layout.column()
        for name in ("samples", "tile_size",
                     "max_bundle_rays", "uncertainty_samples", "seed", "dispersion",
                     "colour_rays", "device", "intersector", "workers", "denoise",
                     "tile_order", "memory_limit_gb"):
            col.prop(props, name)
        # the light-path limits are the scene's own (Cycles' Light Paths), shared by both
        paths = getattr(context.scene, "cycles", None)
        if paths is not None:
            box = col.box()
            box.label(text="Light Paths and Clamping (shared with Cycles)")
            for name in LIGHT_PATHS.values():
                if hasattr(paths, name):
                    box.prop(paths, name)


class NEUROLENS_PT_passes_data(_EnginePanel, bpy.types.Panel):
    """View Layer > Passes > Data for the engine: the passes it writes on request (Depth,
    Normal and its own always; Vector, Position and UV when switched on)."""
    bl_label = "Data"
    bl_context = "view_layer"
    bl_parent_id = "VIEWLAYER_PT_layer_passes"

    def draw(self, context):
        col = self.layout.column(heading="Include")
        for name in ("use_pass_vector", "use_pass_position", "use_pass_uv"):
            col.prop(context.view_layer, name)


#: built-in panels whose settings the engine reads (or that are engine-independent)
_PANEL_PREFIXES = ("RENDER_PT_format", "RENDER_PT_frame", "RENDER_PT_output", "RENDER_PT_color",
                   "RENDER_PT_post", "DATA_PT_camera", "DATA_PT_lens", "DATA_PT_light",
                   "DATA_PT_area", "DATA_PT_spot", "DATA_PT_sunlight", "DATA_PT_context",
                   "WORLD_PT", "MATERIAL_PT", "EEVEE_MATERIAL_PT", "CYCLES_CAMERA_PT_dof",
                   "DATA_PT_camera_dof", "VIEWLAYER_PT_layer", "NODE_")
_added: list = []


def _compat_panels():
    for name in dir(bpy.types):
        if not name.startswith(_PANEL_PREFIXES):
            continue
        cls = getattr(bpy.types, name, None)
        engines = getattr(cls, "COMPAT_ENGINES", None)
        if isinstance(engines, set) and ENGINE_ID not in engines:
            yield cls


_CLASSES = (NEUROLENS_PG_engine, NeuroLensRenderEngine, NEUROLENS_PT_engine,
            NEUROLENS_PT_passes_data)
_BASES = {NEUROLENS_PG_engine: bpy.types.PropertyGroup,
          NeuroLensRenderEngine: bpy.types.RenderEngine, NEUROLENS_PT_engine: bpy.types.Panel,
          NEUROLENS_PT_passes_data: bpy.types.Panel}


def _ours(cls) -> bool:
    return bool(getattr(cls, "is_registered", False))


def _scene_property_is_ours() -> bool:
    prop = bpy.types.Scene.bl_rna.properties.get("neurolens_engine")
    return (prop is not None and _ours(NEUROLENS_PG_engine)
            and prop.fixed_type == NEUROLENS_PG_engine.bl_rna)


def _foreign(cls) -> list:
    """Registered classes of the same name from another copy of this package (the add-on
    imported twice under two package names, e.g. as an extension and from a checkout)."""
    if cls is NeuroLensRenderEngine:
        same = lambda c: getattr(c, "bl_idname", None) == ENGINE_ID  # noqa: E731
    else:
        same = lambda c: c.__name__ == cls.__name__  # noqa: E731
    return [c for c in _BASES[cls].__subclasses__()
            if c is not cls and same(c) and _ours(c)]


def register():
    """Register the engine. Idempotent; another copy of the package that registered the same
    engine is replaced (the last registration wins, as Blender's own re-registration does)."""
    if all(_ours(c) for c in _CLASSES) and _scene_property_is_ours():
        return
    if hasattr(bpy.types.Scene, "neurolens_engine") and not _scene_property_is_ours():
        del bpy.types.Scene.neurolens_engine
    for cls in reversed(_CLASSES):
        for other in _foreign(cls):
            bpy.utils.unregister_class(other)
    for cls in _CLASSES:
        if not _ours(cls):
            bpy.utils.register_class(cls)
    bpy.types.Scene.neurolens_engine = bpy.props.PointerProperty(type=NEUROLENS_PG_engine)
    for panel in _compat_panels():
        panel.COMPAT_ENGINES.add(ENGINE_ID)
        _added.append(panel)


def unregister():
    """Undo register(); leaves alone what another copy of the package registered since."""
    if _scene_property_is_ours():
        del bpy.types.Scene.neurolens_engine
    for cls in reversed(_CLASSES):
        if _ours(cls):
            bpy.utils.unregister_class(cls)
    if not any(_foreign(NeuroLensRenderEngine)):
        for panel in _added:
            panel.COMPAT_ENGINES.discard(ENGINE_ID)
    _added.clear()


def is_registered() -> bool:
    return _ours(NeuroLensRenderEngine)
