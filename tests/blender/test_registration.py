"""Registration: the add-on registers and unregisters ten times in one process, leaving
nothing behind (classes, the Camera property, handlers, preview collections, caches)."""

import bpy
import bpy.utils.previews

from .conftest import PACKAGE, disable_addon, enable_addon

CLASSES = ("NEUROLENS_PT_real_lens", "NEUROLENS_OT_load_lens_file", "NEUROLENS_OT_focus_pick")
HANDLERS = ("frame_change_post", "depsgraph_update_post", "load_post")


def _ours(fn):
    return getattr(fn, "__module__", "").startswith(PACKAGE)


def _handler_counts():
    return {h: sum(_ours(f) for f in getattr(bpy.app.handlers, h)) for h in HANDLERS}


def _registered():
    import sys
    found = {name: hasattr(bpy.types, name) for name in CLASSES}
    props = sys.modules[PACKAGE + ".neurolens_addon.blender.properties"]
    found["NEUROLENS_PG_camera"] = props.NEUROLENS_PG_camera.is_registered
    return found


def _prefs_registered():
    addon = bpy.context.preferences.addons.get(PACKAGE)
    return addon is not None and addon.preferences is not None


def test_01_enabled_addon_registers_each_piece_once(addon):
    """Enabled: the panel, property group and operators exist, Camera has `neurolens`, each
    handler is installed exactly once and the add-on preferences exist."""
    assert all(_registered().values()), _registered()
    assert hasattr(bpy.types.Camera, "neurolens")
    assert _handler_counts() == {h: 1 for h in HANDLERS}
    assert _prefs_registered()
    assert addon.thumbnails.collection() is not None


def test_02_register_unregister_ten_times_without_leaks(addon, scene):
    """Ten disable/enable cycles: after each disable nothing of ours is left (classes, the
    Camera property, handlers, the preview collection, module caches); after each enable
    everything is back exactly once, a Real Lens camera still evaluates, and the loaded
    modules do not pile up."""
    import sys
    sc, camera = scene
    cam = camera("Cycle")
    previews_before = len(bpy.utils.previews._uuid_open)
    loaded = []
    for cycle in range(10):
        disable_addon()
        assert not any(_registered().values()), (cycle, _registered())
        assert not hasattr(bpy.types.Camera, "neurolens"), cycle
        assert _handler_counts() == {h: 0 for h in HANDLERS}, cycle
        assert len(bpy.utils.previews._uuid_open) == previews_before - 1, cycle
        assert addon.thumbnails.collection() is None
        assert not addon.sync._STATUS and not addon.sync._APPLIED
        assert addon.lru.stats["lens_reads"] == 0       # caches were emptied
        enable_addon()
        assert all(_registered().values()), (cycle, _registered())
        assert _handler_counts() == {h: 1 for h in HANDLERS}, cycle
        assert len(bpy.utils.previews._uuid_open) == previews_before, cycle
        # the settings stored on the camera survive, and work
        assert cam.data.neurolens.enabled
        state = addon.camera_state.evaluate_camera(cam, sc)
        assert state.setup is not None and state.setup.lens.name.startswith("Double Gauss")
        loaded.append({m for m in sys.modules if m.startswith(PACKAGE)})
    assert all(names == loaded[0] for names in loaded)


def test_03_reenabled_addon_still_syncs_through_its_handlers(addon, scene, cycles_stub):
    """After the cycles, a frame change reaches our frame_change_post handler exactly once
    per camera (no duplicate handlers applying twice)."""
    sc, camera = scene
    cam = camera("Handlers")
    cam.data.dof.focus_distance = 3.0
    cam.data.dof.keyframe_insert("focus_distance", frame=1)
    cam.data.dof.focus_distance = 6.0
    cam.data.dof.keyframe_insert("focus_distance", frame=2)
    sc.frame_set(1)
    cycles_stub.applied.clear()
    sc.frame_set(2)
    mine = [spec for name, spec in cycles_stub.applied if name == cam.data.name]
    assert len(mine) == 1
    assert abs(mine[0].focus_distance_m - 6.0) < 1e-9
