"""Diffraction in Cycles: the compositor convolves the render with the stop's kernel.

The NEUROLENS engine convolves its finished frame itself (engine.diffraction); Cycles renders
through the OSL camera, which has no frame to convolve, so the same kernel
(LensSetup.diffraction_kernel: core.diffraction) goes to Blender's compositor:
  image  "NeuroLens Diffraction Kernel", a float image holding the R, G and B kernels (alpha
         a single centre pixel, so alpha is kept);
  group  "NeuroLens Diffraction", a compositor node group Image -> Convolve (the kernel as a
         colour image, not renormalised: each channel already sums to 1) -> Image;
  tree   a scene without a compositor gets "NeuroLens Compositing" (Render Layers -> the
         group -> output), marked as the add-on's and removed again when diffraction is off;
         a scene with its own compositor keeps it: a group node placed in it is kept up to
         date (muted when diffraction is off), and without one the set-up says where to put it.
Only for Cycles: with the NEUROLENS engine the add-on's tree is removed and the group nodes are
muted (the engine convolves, once).
"""

from __future__ import annotations

import bpy
import numpy as np

GROUP = "NeuroLens Diffraction"
IMAGE = "NeuroLens Diffraction Kernel"
TREE = "NeuroLens Compositing"
OURS = "neurolens_made"


def kernel_image(kernel):
    """The kernel image (created or refilled): RGB the channel kernels, alpha a delta."""
    k = kernel.kernels
    side = k.shape[1]
    img = bpy.data.images.get(IMAGE)
    if img is not None and (img.size[0] != side or img.size[1] != side):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(IMAGE, side, side, alpha=True, float_buffer=True)
        img.colorspace_settings.is_data = True
    px = np.zeros((side, side, 4), dtype=np.float32)
    px[..., :3] = np.moveaxis(k, 0, -1)    # row 0 at -y: Blender's rows run bottom to top
    px[side // 2, side // 2, 3] = 1.0
    img.pixels.foreach_set(px.ravel())
    img.update()
    img.use_fake_user = False
    return img


def _group(image):
    """The node group Image -> Convolve(kernel) -> Image (created once, its image updated)."""
    ng = bpy.data.node_groups.get(GROUP)
    if ng is None:
        ng = bpy.data.node_groups.new(GROUP, "CompositorNodeTree")
        ng.interface.new_socket("Image", in_out="INPUT", socket_type="NodeSocketColor")
        ng.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        gi = ng.nodes.new("NodeGroupInput")
        go = ng.nodes.new("NodeGroupOutput")
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


def _our_nodes(tree):
    return [n for n in tree.nodes if n.bl_idname == "CompositorNodeGroup"
            and n.node_tree is not None and n.node_tree.name == GROUP]


def _make_tree(group):
    tree = bpy.data.node_groups.new(TREE, "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    rl = tree.nodes.new("CompositorNodeRLayers")
    node = tree.nodes.new("CompositorNodeGroup")
    node.node_tree = group
    out = tree.nodes.new("NodeGroupOutput")
    tree.links.new(rl.outputs["Image"], node.inputs[0])
    tree.links.new(node.outputs[0], out.inputs[0])
    tree[OURS] = True
    return tree


def apply_diffraction(scene, kernel) -> str | None:
    """Convolve this scene's Cycles renders with `kernel`; a message when the scene's own
    compositor has no place for it yet (else None)."""
    group = _group(kernel_image(kernel))
    tree = scene.compositing_node_group
    if tree is None:
        scene.compositing_node_group = _make_tree(group)
        return None
    nodes = _our_nodes(tree)
    for n in nodes:
        n.mute = False
    if not nodes:
        return (f"Diffraction in Cycles: this scene has its own compositor; add the node group "
                f"'{GROUP}' after Render Layers there")
    return None


def clear_diffraction(scene) -> None:
    """No convolution: the add-on's tree removed, group nodes in the scene's own muted."""
    tree = scene.compositing_node_group
    if tree is None:
        return
    if tree.get(OURS):
        scene.compositing_node_group = None
        if tree.users == 0:
            bpy.data.node_groups.remove(tree)
        return
    for n in _our_nodes(tree):
        n.mute = True


def sync_diffraction(scene, setup) -> str | None:
    """Apply or clear for the scene's active camera's set-up (None: no lens camera)."""
    if setup is not None and setup.diffraction and scene.render.engine == "CYCLES":
        return apply_diffraction(scene, setup.diffraction_kernel)
    clear_diffraction(scene)
    return None
