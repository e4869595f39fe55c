"""Blender tests run the add-on the way Blender runs it: as the extension
`bl_ext.user_default.neurolens`, in a throw-away Blender user directory.

Before bpy is imported, BLENDER_USER_RESOURCES points at a temporary folder (so nothing is
read from or written to the real user's Blender config), and the repository's shipped files
(__init__.py, blender_manifest.toml, neurolens_addon/, presets/) are linked into that folder's
"user_default" extension repository. Nothing is written into the repository or into the add-on
folder at run time (Python's own __pycache__ aside).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "bl_ext.user_default.neurolens"
SHIPPED = ("__init__.py", "blender_manifest.toml", "neurolens_addon", "presets")

_OWN_DIR = "bpy" not in sys.modules
if _OWN_DIR:
    USER_RESOURCES = Path(tempfile.mkdtemp(prefix="neurolens-blender-user-"))
    os.environ["BLENDER_USER_RESOURCES"] = str(USER_RESOURCES)

import bpy  # noqa: E402  (after the environment is set)

if not _OWN_DIR:
    # bpy came first (another test folder collected before this one): use its user folder
    # only if it is a throw-away one, never the real user's Blender configuration.
    USER_RESOURCES = Path(bpy.utils.resource_path("USER"))
#: why the Blender tests cannot run here (None: they can)
UNUSABLE = None if USER_RESOURCES.resolve().is_relative_to(
    Path(tempfile.gettempdir()).resolve()) else (
    f"bpy was imported before tests/blender with the user folder {USER_RESOURCES}; run "
    "tests/blender first or on its own so that it can use a temporary Blender user folder")
assert not _OWN_DIR or Path(bpy.utils.resource_path("USER")).resolve() == \
    USER_RESOURCES.resolve(), "bpy did not take BLENDER_USER_RESOURCES"
_EXT = USER_RESOURCES / "extensions" / "user_default" / "neurolens"
if UNUSABLE is None and not _EXT.exists():
    _EXT.mkdir(parents=True)
    for name in SHIPPED:
        (_EXT / name).symlink_to(ROOT / name)


def pytest_sessionfinish(session, exitstatus):
    if _OWN_DIR:
        shutil.rmtree(USER_RESOURCES, ignore_errors=True)


def enable_addon():
    import addon_utils
    mod = addon_utils.enable(PACKAGE, default_set=True, handle_error=_raise)
    assert mod is not None, f"could not enable {PACKAGE}"
    return mod


def disable_addon():
    import addon_utils
    addon_utils.disable(PACKAGE, default_set=True, handle_error=_raise)


def _raise(exc):
    raise exc


class Addon:
    """The enabled add-on's modules, as Blender imported them."""

    def __init__(self):
        import importlib
        base = PACKAGE + ".neurolens_addon"
        self.package = importlib.import_module(PACKAGE)
        for name in ("sync", "camera_reader", "camera_values", "camera_state", "library",
                     "operators", "panel", "preferences", "properties", "thumbnails", "training",
                     "scene_needs_bpy"):
            setattr(self, name, importlib.import_module(f"{base}.blender.{name}"))
        for name in ("lenses", "focusing", "models", "model_choice", "field_of_view", "lru",
                     "resolve"):
            setattr(self, name, importlib.import_module(f"{base}.camera.{name}"))
        self.crosssection = importlib.import_module(f"{base}.core.crosssection")
        self.errors = importlib.import_module(f"{base}.core.errors")
        self.aperture = importlib.import_module(f"{base}.core.aperture")
        self.focus = importlib.import_module(f"{base}.core.focus")
        self.lensfile = importlib.import_module(f"{base}.core.lensfile")
        self.root = base


@pytest.fixture(scope="session")
def addon():
    if UNUSABLE:
        pytest.skip(UNUSABLE)
    enable_addon()
    yield Addon()
    import addon_utils
    if addon_utils.check(PACKAGE)[1]:
        disable_addon()


@pytest.fixture
def scene(addon):
    """A fresh scene with nothing in it, made the window's scene; removed afterwards."""
    sc = bpy.data.scenes.new("neurolens-test")
    old = bpy.context.window.scene if bpy.context.window else None
    if bpy.context.window:
        bpy.context.window.scene = sc
    sc.render.resolution_x, sc.render.resolution_y = 1920, 1080
    made = []

    def camera(name="Cam", lens_id=None, enabled=True, location=(0.0, 0.0, 0.0)):
        data = bpy.data.cameras.new(name)
        obj = bpy.data.objects.new(name, data)
        obj.location = location
        sc.collection.objects.link(obj)
        made.append(obj)
        if lens_id is not None:
            data.neurolens.lens_id = lens_id
        data.neurolens.enabled = enabled
        if sc.camera is None:
            sc.camera = obj
        return obj

    yield sc, camera
    if old is not None and bpy.context.window:
        bpy.context.window.scene = old
    for obj in made:
        data = obj.data
        bpy.data.objects.remove(obj)
        if data.users == 0:
            bpy.data.cameras.remove(data)
    bpy.data.scenes.remove(sc)


class RecordingCycles:
    """Stands in for neurolens_addon.blender.cycles_camera: records what would be applied
    (compiling an OSL camera takes about a second; only tests marked `real_cycles` do)."""

    def __init__(self):
        self.applied = []      # (camera data name, spec)
        self.cleared = []

    def apply_lens_camera(self, camera_data, spec):
        self.applied.append((camera_data.name, spec))
        return True

    def clear_lens_camera(self, camera_data):
        self.cleared.append(camera_data.name)


def pytest_configure(config):
    config.addinivalue_line("markers", "real_cycles: apply specs with the real Cycles camera")


@pytest.fixture(autouse=True)
def cycles_stub(request, monkeypatch):
    if request.node.get_closest_marker("real_cycles") or "addon" not in request.fixturenames:
        yield None
        return
    addon = request.getfixturevalue("addon")
    stub = RecordingCycles()
    monkeypatch.setattr(addon.sync, "_apply_module", lambda: stub)
    yield stub
