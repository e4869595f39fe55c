"""The add-on's compositor for Cycles renders: the lens effects the OSL camera cannot give a
frame it has not finished, each a node group applied after Render Layers.

Effects, in the order the light meets them: the lights' flare (flare_compositor: the ghosts
added), then the stop's diffraction (diffraction_compositor: the frame convolved, flare
included: its light passes the stop too). A scene without a compositor gets "NeuroLens
Compositing" (Render Layers -> each effect that is on -> output), marked as the add-on's,
rebuilt when an effect comes or goes and removed when none is left; a scene with its own
compositor keeps it: a group node of an effect placed in it is unmuted while the effect is on
and muted when it is off, and without one the effect's caller says where to put it.
"""

from __future__ import annotations

import bpy
import numpy as np

TREE = "NeuroLens Compositing"
OURS = "neurolens_made"
#: the effects' node groups, in the order they apply
ORDER = ("NeuroLens Flare", "NeuroLens Diffraction")


def group_nodes(tree, name: str) -> list:
    """The group nodes of the node group `name` in a compositor tree."""
    return [n for n in tree.nodes if n.bl_idname == "CompositorNodeGroup"
            and n.node_tree is not None and n.node_tree.name == name]


def _effects_in(tree) -> list:
    return [bpy.data.node_groups[name] for name in ORDER if group_nodes(tree, name)]


def _build(tree, groups) -> None:
    """Our tree as Render Layers -> each group in ORDER -> output."""
    tree.nodes.clear()
    rl = tree.nodes.new("CompositorNodeRLayers")
    out = tree.nodes.new("NodeGroupOutput")
    socket = rl.outputs["Image"]
    for g in sorted(groups, key=lambda g: ORDER.index(g.name)):
        node = tree.nodes.new("CompositorNodeGroup")
        node.node_tree = g
        tree.links.new(socket, node.inputs[0])
        socket = node.outputs[0]
    tree.links.new(socket, out.inputs[0])


def use_effect(scene, group) -> str | None:
    """Apply the effect `group` to the scene's Cycles renders; a message when the scene's own
    compositor has no node of it yet (else None)."""
    tree = scene.compositing_node_group
    if tree is None:
        tree = bpy.data.node_groups.new(TREE, "CompositorNodeTree")
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        tree[OURS] = True
        _build(tree, [group])
        scene.compositing_node_group = tree
        return None
    if tree.get(OURS):
        if not group_nodes(tree, group.name):
            _build(tree, _effects_in(tree) + [group])
        return None
    nodes = group_nodes(tree, group.name)
    for n in nodes:
        n.mute = False
    if not nodes:
        return (f"this scene has its own compositor; add the node group '{group.name}' after "
                "Render Layers there")
    return None


def drop_effect(scene, name: str) -> None:
    """Stop applying the effect named `name`: gone from our tree (the tree removed when no
    effect is left), muted in the scene's own."""
    tree = scene.compositing_node_group
    if tree is None:
        return
    if tree.get(OURS):
        left = [g for g in _effects_in(tree) if g.name != name]
        if left:
            if len(left) != len(_effects_in(tree)):
                _build(tree, left)
            return
        scene.compositing_node_group = None
        if tree.users == 0:
            bpy.data.node_groups.remove(tree)
        return
    for n in group_nodes(tree, name):
        n.mute = True


def float_image(name: str, width: int, height: int, rgba: np.ndarray):
    """The effect's float image `name` (data, not colour-managed), created or refilled with
    `rgba` ((height, width, 4) or (width height, 4), rows from the bottom)."""
    img = bpy.data.images.get(name)
    if img is not None and (img.size[0] != width or img.size[1] != height):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
        img.colorspace_settings.is_data = True
    img.pixels.foreach_set(np.ascontiguousarray(rgba, dtype=np.float32).ravel())
    img.update()
    img.use_fake_user = False
    return img


def new_effect_group(name: str):
    """(group, its input node, its output node) of a new effect's node group: one Image in,
    one Image out, nothing between yet."""
    ng = bpy.data.node_groups.new(name, "CompositorNodeTree")
    ng.interface.new_socket("Image", in_out="INPUT", socket_type="NodeSocketColor")
    ng.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    return ng, ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
