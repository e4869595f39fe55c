"""The apply step with the real Cycles camera (neurolens_addon.cycles and
blender/cycles_camera.py), instead of the recorder the other Blender tests use."""

import importlib

import pytest

from .conftest import PACKAGE


@pytest.fixture
def cycles_camera(addon):
    return importlib.import_module(PACKAGE + ".neurolens_addon.blender.cycles_camera")


@pytest.mark.real_cycles
def test_01_spec_type_is_the_cycles_camera_spec(addon, cycles_camera, scene):
    """camera_spec returns the Cycles package's CameraSpec, carrying the
    film size as Cycles frames it and the scene's unit scale."""
    cycles = importlib.import_module(PACKAGE + ".neurolens_addon.cycles")
    sc, camera = scene
    obj = camera("Spec", enabled=False)
    sc.unit_settings.scale_length = 0.5
    spec = addon.sync.camera_spec(obj, sc)
    assert type(spec) is cycles.CameraSpec
    film = importlib.import_module(PACKAGE + ".neurolens_addon.core.film")
    assert (spec.sensor_width_mm, spec.sensor_height_mm) == pytest.approx(
        film.film_from_settings(addon.camera_values.film_settings(obj.data, sc)).size_mm)
    assert spec.metres_per_unit == 0.5


@pytest.mark.real_cycles
def test_02_enabling_the_real_lens_makes_a_custom_camera_and_disabling_restores(
        addon, cycles_camera, scene):
    """Turning the Real Lens on makes the camera a Cycles Custom (OSL) camera with the
    generated shader; turning it off gives Blender's perspective camera back."""
    _sc, camera = scene
    obj = camera("Apply", enabled=False)
    obj.data.neurolens.enabled = True
    state = addon.sync.last_state(obj)
    assert state is not None and state.setup is not None, state and state.messages
    errors = [t for level, t in state.messages if level == "ERROR"]
    assert not errors, errors
    assert obj.data.type == "CUSTOM" and obj.data.custom_shader is not None
    obj.data.neurolens.enabled = False
    assert obj.data.type == "PERSP"


@pytest.mark.slow
@pytest.mark.real_cycles
def test_03_diffraction_goes_to_the_compositor_for_cycles_only(addon, cycles_camera, scene):
    """Diffraction on a Real Lens camera rendered by Cycles puts the add-on's compositor tree
    on a scene without one (Render Layers -> the 'NeuroLens Diffraction' group, whose kernel
    image holds the set-up's kernel); turning it off, or switching to the NEUROLENS engine
    (which convolves itself), removes that tree; a scene with its own compositor is left as
    it is, with a message saying where the group goes."""
    import bpy
    import numpy as np
    comp = importlib.import_module(PACKAGE + ".neurolens_addon.blender.diffraction_compositor")
    sc, camera = scene
    sc.render.engine = "CYCLES"
    sc.render.resolution_x, sc.render.resolution_y = 64, 36
    obj = camera("Diffr")
    obj.data.dof.aperture_blades = 6
    obj.data.neurolens.aperture_shape = "BLADES"
    obj.data.neurolens.diffraction = True
    addon.sync.sync_scene(sc)
    tree = sc.compositing_node_group
    assert tree is not None and tree.name.startswith(comp.TREE)
    state = addon.sync.last_state(obj)
    k = state.setup.diffraction_kernel.kernels
    img = bpy.data.images[comp.IMAGE]
    px = np.array(img.pixels[:]).reshape(img.size[1], img.size[0], 4)
    np.testing.assert_allclose(px[..., :3], np.moveaxis(k, 0, -1), atol=1e-7)
    obj.data.neurolens.diffraction = False
    addon.sync.sync_scene(sc)
    assert sc.compositing_node_group is None
    obj.data.neurolens.diffraction = True
    addon.sync.sync_scene(sc)
    assert sc.compositing_node_group is not None
    sc.render.engine = "NEUROLENS"
    addon.sync.sync_scene(sc)
    assert sc.compositing_node_group is None
    own = bpy.data.node_groups.new("mine", "CompositorNodeTree")
    sc.compositing_node_group = own
    sc.render.engine = "CYCLES"
    addon.sync.sync_scene(sc)
    assert sc.compositing_node_group == own
    assert any(comp.GROUP in text for _level, text in addon.sync.last_state(obj).messages)
    sc.compositing_node_group = None
    bpy.data.node_groups.remove(own)


@pytest.mark.slow
@pytest.mark.real_cycles
def test_04_a_cycles_render_with_ghosts_gets_the_lamps_flare_in_the_compositor(
        addon, cycles_camera, scene):
    """A Real Lens camera with ghosts, rendered by Cycles with the add-on running: before the
    frame renders, the add-on traces the point lamp's flare for it (the render_pre handler)
    into the image 'NeuroLens Flare', added after Render Layers by the 'NeuroLens Flare'
    group of the add-on's compositor; with ghosts off the group is gone again."""
    import bpy
    import numpy as np
    comp = importlib.import_module(PACKAGE + ".neurolens_addon.blender.flare_compositor")
    sc, camera = scene
    sc.render.engine = "CYCLES"
    sc.cycles.samples = 2
    sc.render.resolution_x, sc.render.resolution_y = 48, 27
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy = 1000.0
    lamp.location = (0.3, 0.2, -8.0)                 # ahead of the camera (it looks down -Z)
    sc.collection.objects.link(lamp)
    obj = camera("Flare")
    obj.data.neurolens.ghosts = True
    addon.sync.sync_scene(sc)
    bpy.ops.render.render(write_still=False, scene=sc.name)
    tree = sc.compositing_node_group
    assert tree is not None and any(n.bl_idname == "CompositorNodeGroup" and n.node_tree
                                    and n.node_tree.name == comp.GROUP for n in tree.nodes)
    img = bpy.data.images[comp.IMAGE]
    assert tuple(img.size) == (48, 27)
    assert np.array(img.pixels[:]).sum() > 0
    obj.data.neurolens.ghosts = False
    addon.sync.sync_scene(sc)
    bpy.ops.render.render(write_still=False, scene=sc.name)
    assert sc.compositing_node_group is None
