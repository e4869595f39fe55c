"""Diffraction in Cycles: the compositor convolves the render with the stop's kernel.

The NEUROLENS engine convolves its finished frame itself (engine.diffraction); Cycles renders
through the OSL camera, which has no frame to convolve, so the same kernel
(LensSetup.diffraction_kernel: core.diffraction) goes to Blender's compositor:
  image  "NeuroLens Diffraction Kernel", a float image holding the R, G and B kernels (alpha
         a single centre pixel, so alpha is kept);
  group  "NeuroLens Diffraction", a compositor node group Image -> Convolve (the kernel as a
         colour image, not renormalised: each channel already sums to 1) -> Image, one of the
         add-on's compositor effects (compositor_tree: its tree, or a node in the scene's own).
Only for Cycles: with the NEUROLENS engine the effect is dropped (the engine convolves, once).
"""

from __future__ import annotations

import bpy
import numpy as np

from .compositor_tree import (OURS, ORDER, TREE, drop_effect, float_image,  # noqa: F401
                              new_effect_group, use_effect)

GROUP = ORDER[1]
IMAGE = "NeuroLens Diffraction Kernel"


def kernel_image(kernel):
    """The kernel image (created or refilled): RGB the channel kernels, alpha a delta."""
    k = kernel.kernels
    side = k.shape[1]
    px = np.zeros((side, side, 4), dtype=np.float32)
    px[..., :3] = np.moveaxis(k, 0, -1)    # row 0 at -y: Blender's rows run bottom to top
    px[side // 2, side // 2, 3] = 1.0
    return float_image(IMAGE, side, side, px)


def _group(image):
    """The node group Image -> Convolve(kernel) -> Image (created once, its image updated)."""
    ng = bpy.data.node_groups.get(GROUP)
    if ng is None:
        ng, gi, go = new_effect_group(GROUP)
        conv = ng.nodes.new("CompositorNodeConvolve")
        conv.name = "Convolve"
        src = ng.nodes.new("CompositorNodeImage")
        src.name = "Kernel"
        conv.inputs["Kernel Data Type"].default_value = "Color"
        conv.inputs["Normalize Kernel"].default_value = False
        ng.links.new(gi.outputs[0], conv.inputs["Image"])
        ng.links.new(src.outputs["Image"], _colour_kernel_socket(conv))
        ng.links.new(conv.outputs["Image"], go.inputs[0])
        ng[OURS] = True
    ng.nodes["Kernel"].image = image
    return ng


def _colour_kernel_socket(conv):
    return next(s for s in conv.inputs if s.name == "Kernel" and s.type == "RGBA")


def apply_diffraction(scene, kernel) -> str | None:
    """Convolve this scene's Cycles renders with `kernel`; a message when the scene's own
    compositor has no place for it yet (else None)."""
    message = use_effect(scene, _group(kernel_image(kernel)))
    return None if message is None else f"Diffraction in Cycles: {message}"


def clear_diffraction(scene) -> None:
    """No convolution (compositor_tree.drop_effect)."""
    drop_effect(scene, GROUP)


def sync_diffraction(scene, setup) -> str | None:
    """Apply or clear for the scene's active camera's set-up (None: no lens camera)."""
    if setup is not None and setup.diffraction and scene.render.engine == "CYCLES":
        return apply_diffraction(scene, setup.diffraction_kernel)
    clear_diffraction(scene)
    return None
