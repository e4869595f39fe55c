"""The add-on's compositor effects for Cycles (blender.compositor_tree): the flare and the
diffraction node groups chained in the order light meets them, in the add-on's own tree or in
the scene's."""

from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy")

from neurolens_addon.blender import compositor_tree as ct  # noqa: E402


def _group(name):
    old = bpy.data.node_groups.get(name)      # an earlier test's: this test wants its own
    if old is not None:
        bpy.data.node_groups.remove(old)
    ng = bpy.data.node_groups.new(name, "CompositorNodeTree")
    ng.interface.new_socket("Image", in_out="INPUT", socket_type="NodeSocketColor")
    ng.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    ng.links.new(ng.nodes.new("NodeGroupInput").outputs[0],
                 ng.nodes.new("NodeGroupOutput").inputs[0])
    return ng


def _chain(tree):
    """Node groups from Render Layers to the output, following the links."""
    node = next(n for n in tree.nodes if n.bl_idname == "CompositorNodeRLayers")
    names = []
    while True:
        links = [lk for lk in tree.links if lk.from_node == node]
        assert len(links) == 1
        node = links[0].to_node
        if node.bl_idname == "NodeGroupOutput":
            return names
        names.append(node.node_tree.name)


def test_01_effects_chain_in_light_order_and_the_tree_goes_with_the_last():
    """Diffraction first, then flare: the add-on's tree runs Render Layers -> flare ->
    diffraction -> output whatever order they came in; dropping one leaves the other; dropping
    both removes the add-on's tree. A scene's own compositor is only muted or unmuted."""
    # a scene of its own: factory settings would unregister the add-on the other tests use
    scene = bpy.data.scenes.new("compositor-tree-test")
    flare, diffraction = _group(ct.ORDER[0]), _group(ct.ORDER[1])
    assert ct.use_effect(scene, diffraction) is None
    tree = scene.compositing_node_group
    assert tree.name.startswith(ct.TREE) and _chain(tree) == [ct.ORDER[1]]
    assert ct.use_effect(scene, flare) is None
    assert _chain(scene.compositing_node_group) == list(ct.ORDER)
    ct.drop_effect(scene, ct.ORDER[1])
    assert _chain(scene.compositing_node_group) == [ct.ORDER[0]]
    ct.drop_effect(scene, ct.ORDER[0])
    assert scene.compositing_node_group is None
    own = bpy.data.node_groups.new("mine", "CompositorNodeTree")
    scene.compositing_node_group = own
    assert "own compositor" in ct.use_effect(scene, flare)
    node = own.nodes.new("CompositorNodeGroup")
    node.node_tree = flare
    node.mute = True
    assert ct.use_effect(scene, flare) is None and not node.mute
    ct.drop_effect(scene, ct.ORDER[0])
    assert node.mute and scene.compositing_node_group == own
    bpy.data.scenes.remove(scene)
    for g in (flare, diffraction, own):
        bpy.data.node_groups.remove(g)
