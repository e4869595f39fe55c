"""What differs between Blender 5.0 and 5.2 LTS, handled in engine.blender_compat, on the real
bpy of this environment (5.0.1 in .venv, 5.2.3 in .venv-5.2: `make test` and `make test-52`
run this file under each).

Lights: 5.0 gives a light a node tree only when Use Nodes is switched on; from 5.1 every light
has one (new lights, and the lamps of a file saved by 5.0 once 5.2 opens it), Use Nodes always
reads True and warns. The engine notes light nodes only where the tree changes the light."""

from __future__ import annotations

import warnings
from pathlib import Path

import bpy
import pytest

from neurolens_addon.engine.blender_compat import (is_plain_light_tree, light_node_tree,
                                                   light_nodes_change_light, use_nodes_retired)
from neurolens_addon.engine.unsupported import scene_notes
from testdata import engine_scenes as scenes

ROOT = Path(__file__).resolve().parents[2]
KINDS = ("POINT", "SUN", "SPOT", "AREA")
#: Blender 5.0 still has the Use Nodes switch on lights; 5.1 and later retired it
SWITCH = bpy.app.version[:2] == (5, 0)


def _switch_on(light):
    """5.0: switch Use Nodes on (Blender then makes the default tree); later: already on."""
    if SWITCH:
        light.use_nodes = True
    return light.node_tree


def _light_nodes_notes():
    notes = scene_notes(bpy.context.scene, bpy.context.evaluated_depsgraph_get())
    return [n for n in notes if n.startswith("light nodes")]


@pytest.mark.parametrize("kind", KINDS)
def test_01_a_new_light_renders_as_its_plain_settings(kind):
    """A new light: 5.0 gives it no tree and an off switch, 5.2 the default Emission -> Light
    Output tree and a retired switch; on both it renders as its plain settings (no light-nodes
    difference), and reading it through blender_compat warns of nothing (5.2 warns on every
    read of the retired switch)."""
    scenes.reset()
    light = bpy.data.lights.new(f"new {kind}", kind)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        retired = use_nodes_retired(light)
        tree = light_node_tree(light)
        changes = light_nodes_change_light(light)
    assert retired == (not SWITCH)
    assert (tree is not None) == retired == (light.node_tree is not None)
    assert not changes
    if tree is not None:
        assert is_plain_light_tree(tree)


def test_02_the_lamps_of_a_file_saved_by_5_0_are_plain_lamps():
    """The demo scene, saved by Blender 5.0 with plain lamps: under 5.2 its lamps come with a
    node tree (what made the engine say "light nodes ... ignored" there), under 5.0 without;
    under both the engine notes no light nodes."""
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "presets" / "scenes" / "demo.blend"),
                             load_ui=False)
    assert tuple(bpy.data.version[:2]) == (5, 0)            # the file's own Blender
    lamps = [ob.data for ob in bpy.data.objects if ob.type == "LIGHT"]
    assert len(lamps) >= 2
    assert all((lamp.node_tree is not None) == (not SWITCH) for lamp in lamps)
    assert not any(light_nodes_change_light(lamp) for lamp in lamps)
    assert _light_nodes_notes() == []


def test_03_a_light_tree_that_changes_the_light_is_noted():
    """Each change a plain light does not render (a stronger or coloured Emission, a Blackbody
    into its colour, no emission reaching the output) is a light-nodes note naming the lamp;
    the default tree is not; under 5.0 a tree switched off is not rendered, so not noted."""
    scenes.reset()
    light = bpy.data.lights.new("Lamp", "POINT")
    ob = bpy.data.objects.new("Lamp", light)
    bpy.context.scene.collection.objects.link(ob)
    tree = _switch_on(light)
    assert not light_nodes_change_light(light) and _light_nodes_notes() == []
    emission = next(n for n in tree.nodes if n.type == "EMISSION")
    emission.inputs["Strength"].default_value = 3.0
    assert light_nodes_change_light(light)
    notes = _light_nodes_notes()
    assert len(notes) == 1 and "'Lamp'" in notes[0] and "Cycles renders it" in notes[0]
    emission.inputs["Strength"].default_value = 1.0
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.2, 1.0)
    assert light_nodes_change_light(light)
    emission.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    assert not light_nodes_change_light(light)
    blackbody = tree.nodes.new("ShaderNodeBlackbody")
    link = tree.links.new(blackbody.outputs[0], emission.inputs["Color"])
    assert light_nodes_change_light(light)
    tree.links.remove(link)
    output = next(n for n in tree.nodes if n.type == "OUTPUT_LIGHT")
    tree.links.remove(output.inputs["Surface"].links[0])
    assert light_nodes_change_light(light)              # no emission reaches the output
    if SWITCH:
        light.use_nodes = False
        assert light_node_tree(light) is None and not light_nodes_change_light(light)
        assert _light_nodes_notes() == []
