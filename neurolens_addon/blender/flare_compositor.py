"""The lights' flare in Cycles: the engine's flare layer of the frame, added in the compositor.

The OSL camera's ghost samples start from the camera and never meet a lamp, so the flare of
the scene's lamps is traced from the lights by the engine's light tracer (engine.flare) for
the frame about to render (its camera, its lights, the scene's geometry as occluders through
the engine's caster: Embree, else Blender's BVH), written to the float image "NeuroLens Flare"
and added to the render by the node group "NeuroLens Flare" (Image + that image -> Image), one
of the add-on's compositor effects (compositor_tree; diffraction after it). Rays: the ghosts'
share of the frame's camera samples, as the engine gives them, Cycles' samples counted up to
engine.flare.MAX_SAMPLES (the light tracer converges at far fewer samples than a path tracer
needs).
"""

from __future__ import annotations

import time

import bpy
import numpy as np

from .compositor_tree import ORDER, drop_effect, float_image, new_effect_group, use_effect

GROUP = ORDER[0]
IMAGE = "NeuroLens Flare"


def flare_layer(scene, depsgraph, camera_obj, setup, samples: int):
    """engine.flare.flare_of_frame for this camera's set-up and the scene's lamps, the
    scene's geometry through the engine's caster."""
    from ..engine.camera_rays import rigid
    from ..engine.casters import make_caster
    from ..engine.flare import flare_of_frame
    from ..engine.lights import scene_lights
    cam = setup.derived
    if cam.ghost_plan is None:
        return None
    lights = scene_lights(depsgraph)
    if not lights:
        return None
    return flare_of_frame(cam, rigid(camera_obj.evaluated_get(depsgraph).matrix_world),
                          setup.mm_per_unit, lights, make_caster(scene, depsgraph), samples,
                          int(getattr(scene.cycles, "seed", 0)), cam.dispersion)


def flare_image(pixels: np.ndarray, width: int, height: int):
    """The flare image (created or refilled): RGB the flare, alpha 0 (the render's is kept)."""
    px = np.zeros((width * height, 4), dtype=np.float32)
    px[:, :3] = pixels                      # rows bottom to top, as the film's pixel index
    return float_image(IMAGE, width, height, px)


def _group(image):
    """The node group Image + flare image -> Image (created once, its image updated)."""
    ng = bpy.data.node_groups.get(GROUP)
    if ng is None:
        ng, gi, go = new_effect_group(GROUP)
        add = ng.nodes.new("ShaderNodeMix")
        add.data_type, add.blend_type, add.clamp_result = "RGBA", "ADD", False
        add.inputs["Factor"].default_value = 1.0
        src = ng.nodes.new("CompositorNodeImage")
        src.name = "Flare"
        rgba = [s for s in add.inputs if s.type == "RGBA"]
        ng.links.new(gi.outputs[0], rgba[0])
        ng.links.new(src.outputs["Image"], rgba[1])
        ng.links.new(next(s for s in add.outputs if s.type == "RGBA"), go.inputs[0])
    ng.nodes["Flare"].image = image
    return ng


def apply_flare(scene, depsgraph, camera_obj, setup) -> tuple[str | None, float]:
    """Trace this frame's flare and add it to Cycles' render: (a message when the scene's own
    compositor has no place for it, else None; seconds spent)."""
    t0 = time.perf_counter()
    made = flare_layer(scene, depsgraph, camera_obj, setup, int(scene.cycles.samples))
    if made is None:
        clear_flare(scene)
        return None, time.perf_counter() - t0
    f = setup.derived.film
    message = use_effect(scene, _group(flare_image(made[0], f.width_px, f.height_px)))
    return (None if message is None else f"Flare in Cycles: {message}",
            time.perf_counter() - t0)


def clear_flare(scene) -> None:
    drop_effect(scene, GROUP)


def sync_flare(scene, depsgraph, camera_obj, setup) -> tuple[str | None, float | None]:
    """Apply (ghosts on, Cycles rendering) or clear the flare for the frame about to render:
    (apply_flare's message, the seconds it took; None when cleared)."""
    if setup is not None and setup.ghosts is not None and scene.render.engine == "CYCLES":
        return apply_flare(scene, depsgraph, camera_obj, setup)
    clear_flare(scene)
    return None, None
