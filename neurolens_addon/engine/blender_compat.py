"""Blender 5.0 to 5.2 LTS: every difference between them that the add-on's code meets, in one
place, read from the Blender objects themselves.

Differences, each with its test (tests/engine/test_9_blender_versions.py):
  lights' node trees  Blender 5.0 lights have no node tree until "Use Nodes" is switched on,
                      and Cycles ignores a tree that is switched off. From 5.1 every light has
                      one (new lights, and lights of files saved by 5.0 when 5.2 opens them: a
                      default Emission -> Light Output), `use_nodes` is retired (it always
                      reads True, reading it warns that 6.0 removes it) and Cycles always
                      renders the tree. The engine renders plain lights, so it must tell a tree
                      that changes the light from the default one: `light_node_tree` is the tree
                      Cycles renders (None: none), `light_nodes_change_light` whether that tree
                      does anything a plain light does not. The retired switch is found from
                      the property's own RNA (is_deprecated), not from a version number.
numpy 1.26 against numpy 2 is pure numpy and lives in core.np_compat.

Checked and alike (every type, property, function, enum item and node socket the add-on's code
names, compared between bpy 5.0.1 and 5.2.3): the compositor's node groups
(scene.compositing_node_group, Group Input / Output, the Convolve node's inputs), the OSL
custom camera (custom_mode, custom_shader, custom_bytecode, cycles.osl's
update_custom_camera_shader, and the attributes the shader reads: cam:focal_distance,
cam:aperture_size, cam:image_resolution) and materials and worlds (always on their node trees
since 5.0). The Render Layers node lists only the view layer's enabled passes from 5.2 (5.0
listed them all); the add-on links its Image output, which both have. The tests that use them
(tests/blender, tests/cycles) run under both Blenders: `make test` and `make test-52`.

This module lives in engine/, the lowest layer that reads Blender objects (handed to it as
arguments; nothing here imports bpy), so that the engine can use it: blender/ and render/,
above it, import it from here.
"""

from __future__ import annotations

#: what a plain light's node tree holds: Emission(white, strength 1) -> Light Output's Surface
PLAIN_COLOUR = (1.0, 1.0, 1.0)
PLAIN_STRENGTH = 1.0


def use_nodes_retired(light) -> bool:
    """True when this Blender always renders a light's node tree (5.1 and later: the light's
    `use_nodes` is deprecated, or gone)."""
    prop = light.bl_rna.properties.get("use_nodes")
    return prop is None or bool(getattr(prop, "is_deprecated", False))


def light_node_tree(light):
    """The node tree Cycles renders `light` (a bpy.types.Light) with, or None: 5.0 renders a
    tree only when Use Nodes is on; 5.1 and later always render it."""
    tree = getattr(light, "node_tree", None)
    if tree is None:
        return None
    if use_nodes_retired(light):
        return tree                     # never read the retired switch: it warns
    return tree if light.use_nodes else None


def _linked_from(socket):
    """The (node, output socket) feeding `socket`, or None."""
    if not socket.is_linked:
        return None
    link = socket.links[0]
    if getattr(link, "is_muted", False) or not getattr(link, "is_valid", True):
        return None
    return link.from_node, link.from_socket


def _active_output(tree):
    """The Light Output node Cycles uses: the active one for Cycles or for all renderers."""
    outs = [n for n in tree.nodes if n.type == "OUTPUT_LIGHT"
            and getattr(n, "target", "ALL") in ("ALL", "CYCLES")]
    active = [n for n in outs if n.is_active_output]
    return (active or outs or [None])[0]


def is_plain_light_tree(tree) -> bool:
    """True when `tree` renders the light exactly as its plain settings do: its Light Output
    takes an unmuted Emission node of white colour and strength 1, nothing linked into it (the
    tree Blender gives every light). Anything else (another colour or strength, a texture, an
    IES profile, no output) changes the light."""
    out = _active_output(tree)
    if out is None:
        return False
    src = _linked_from(out.inputs["Surface"])
    if src is None:
        return False
    node, socket = src
    if node.type != "EMISSION" or node.mute or socket.identifier != "Emission":
        return False
    colour, strength = node.inputs["Color"], node.inputs["Strength"]
    if colour.is_linked or strength.is_linked:
        return False
    return (tuple(round(float(c), 6) for c in colour.default_value[:3]) == PLAIN_COLOUR
            and float(strength.default_value) == PLAIN_STRENGTH)


def light_nodes_change_light(light) -> bool:
    """True when Cycles renders `light` through a node tree that makes it differ from its
    plain settings (what the NEUROLENS engine renders)."""
    tree = light_node_tree(light)
    return tree is not None and not is_plain_light_tree(tree)
