"""The extension package: Blender's own tool validates the manifest and builds the zip, the zip
ships only what Blender needs, installs and registers in a fresh Blender user directory and
unregisters cleanly; release builds bundle onnxruntime wheels per platform, never numpy."""

import json
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from testdata.scripts import load_script

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = ROOT / "scripts"
SHIPPED_TOP = {"__init__.py", "blender_manifest.toml", "neurolens_addon", "presets"}
NEVER_SHIPPED = ("trainer/", "onnx_export/", "tests/", "benchmarks/", "docs/", "scripts/", "out/",
                 ".venv/", ".venv-5.2/", "__pycache__/", ".git/", "Makefile", "requirements",
                 "pyproject.toml")


def _script(name):
    return load_script(name)


def _run(*args, env=None, timeout=240):
    proc = subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True,
                          check=False, cwd=ROOT, env=env, timeout=timeout)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("extension")
    log = _run(SCRIPTS / "build_extension.py", "--out", out)
    zips = sorted(out.glob("*.zip"))
    assert len(zips) == 1, log
    return zips[0], log


def _repo_files(folder):
    return {p.relative_to(ROOT).as_posix() for p in (ROOT / folder).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
            and not any(part.startswith(".") for part in p.relative_to(ROOT).parts)}


def test_01_manifest_is_valid_for_blender_5(built_zip):
    """Blender's extension tool validates the manifest; it targets Blender 5.0+, is an add-on
    with id 'neurolens' and lists no wheels (those go into release builds only)."""
    _zip, log = built_zip
    assert "Success parsing TOML" in log
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["blender_version_min"] == "5.0.0" and manifest["type"] == "add-on"
    assert manifest["id"] == "neurolens"
    assert "wheels" not in manifest and "platforms" not in manifest


def test_02_zip_ships_only_what_blender_needs(built_zip):
    """The zip holds the entry point, the manifest, every file of neurolens_addon and the
    presets (lenses and models), and nothing else: no trainer, tests, benchmarks, docs,
    scripts, caches or wheels; never numpy."""
    path, _log = built_zip
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        assert zf.testzip() is None
    top = {n.split("/", 1)[0] for n in names}
    assert top == SHIPPED_TOP, top
    for bad in NEVER_SHIPPED:
        assert not any(bad in n for n in names), bad
    assert not any(n.endswith(".pyc") or "numpy" in n.lower() for n in names)
    assert not any(n.endswith(".whl") for n in names)
    files = {n for n in names if not n.endswith("/")}
    assert _repo_files("neurolens_addon") <= files
    assert _repo_files("presets") <= files
    assert "presets/lenses/double_gauss_50mm_f2.toml" in files
    assert "presets/models/double_gauss_50mm_f2.neurolens/model.json" in files


INSTALL_CHECK = r'''
import json, os, sys
from pathlib import Path
zip_path, user = sys.argv[1], sys.argv[2]
os.environ["BLENDER_USER_RESOURCES"] = user
import bpy, addon_utils
pkg = "bl_ext.user_default.neurolens"
out = {"user": bpy.utils.resource_path("USER")}
res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                               enable_on_install=True)
out["installed"] = sorted(res)
out["enabled"] = addon_utils.check(pkg)[1]
ext_dir = Path(bpy.utils.user_resource("EXTENSIONS", path="user_default/neurolens"))
def listing():
    return sorted(str(p.relative_to(ext_dir)) for p in ext_dir.rglob("*")
                  if "__pycache__" not in p.parts)
out["panel"] = hasattr(bpy.types, "NEUROLENS_PT_real_lens")
out["operators"] = [hasattr(bpy.types, n) for n in ("NEUROLENS_OT_load_lens_file",
                                                     "NEUROLENS_OT_focus_pick")]
out["camera_prop"] = hasattr(bpy.types.Camera, "neurolens")
out["handlers"] = sum(f.__module__.startswith(pkg) for f in bpy.app.handlers.frame_change_post)
cam = bpy.context.scene.camera
import importlib
camera_state = importlib.import_module(pkg + ".neurolens_addon.blender.camera_state")
props = importlib.import_module(pkg + ".neurolens_addon.blender.properties")
before = listing()
state = camera_state.evaluate_camera(cam, bpy.context.scene, with_fov=True)
out["lens"] = state.entry.name
out["fov"] = state.fov_deg
out["items"] = len(props.lens_items(cam.data.neurolens, bpy.context))
out["addon_folder_unchanged"] = listing() == before
thumbs = Path(bpy.utils.extension_path_user(pkg, path="thumbnails"))
out["thumbnails"] = len(list(thumbs.glob("*.png")))
addon_utils.disable(pkg, default_set=True)
out["after_disable"] = [hasattr(bpy.types, "NEUROLENS_PT_real_lens"),
                        hasattr(bpy.types.Camera, "neurolens"),
                        sum(f.__module__.startswith(pkg)
                            for f in bpy.app.handlers.frame_change_post)]
print("RESULT " + json.dumps(out))
'''


def test_03_zip_installs_registers_and_unregisters_in_a_fresh_user_dir(built_zip, tmp_path):
    """In a new Blender process with an empty user directory, Blender installs the zip into
    its user extension repository and enables it: the panel, operators, Camera property and
    handlers exist, a camera evaluates through the shipped presets, thumbnails go to the
    user directory (the installed add-on folder is unchanged), and disabling removes all."""
    path, _log = built_zip
    user = tmp_path / "blender-user"
    user.mkdir()
    script = tmp_path / "install_check.py"
    script.write_text(INSTALL_CHECK)
    log = _run(script, path, user)
    line = next(x for x in log.splitlines() if x.startswith("RESULT "))
    out = json.loads(line[len("RESULT "):])
    assert Path(out["user"]).resolve() == user.resolve()
    assert out["installed"] == ["FINISHED"] and out["enabled"]
    assert out["panel"] and all(out["operators"]) and out["camera_prop"]
    assert out["handlers"] == 1
    assert out["lens"].startswith("Double Gauss") and all(out["fov"])
    assert out["items"] >= 12 and out["thumbnails"] >= 12
    assert out["addon_folder_unchanged"]
    assert out["after_disable"] == [False, False, 0]
    assert (user / "extensions" / "user_default" / "neurolens" / "blender_manifest.toml").is_file()


def _fake_wheel(folder: Path, filename: str, requires=()):
    name = filename.split("-")[0]
    version = filename.split("-")[1]
    meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
    meta += "".join(f"Requires-Dist: {r}\n" for r in requires)
    info = f"{name}-{version}.dist-info"
    with zipfile.ZipFile(folder / filename, "w") as zf:
        zf.writestr(f"{name}/__init__.py", "")
        zf.writestr(f"{info}/METADATA", meta)
        zf.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nRoot-Is-Purelib: false\n")
        zf.writestr(f"{info}/RECORD", "")
    return folder / filename


ORT_REQUIRES = ("flatbuffers", "numpy>=1.21.6", "packaging", "protobuf",
                "coloredlogs; sys_platform == 'win32'", "sympy; extra == 'tools'")
FAKE_FILES = {
    ("onnxruntime", "linux-x64"): "onnxruntime-1.31.1-cp311-cp311-manylinux_2_28_x86_64.whl",
    ("onnxruntime", "windows-x64"): "onnxruntime-1.31.1-cp311-cp311-win_amd64.whl",
    ("onnxruntime", "macos-arm64"): "onnxruntime-1.31.1-cp311-cp311-macosx_14_0_arm64.whl",
    ("protobuf", "linux-x64"): "protobuf-7.36.2-cp310-abi3-manylinux2014_x86_64.whl",
    ("protobuf", "windows-x64"): "protobuf-7.36.2-cp310-abi3-win_amd64.whl",
    ("protobuf", "macos-arm64"): "protobuf-7.36.2-cp310-abi3-macosx_10_9_universal2.whl",
    ("flatbuffers", None): "flatbuffers-25.12.19-py2.py3-none-any.whl",
    ("packaging", None): "packaging-26.3-py3-none-any.whl",
    ("coloredlogs", None): "coloredlogs-15.0.1-py2.py3-none-any.whl",
    ("numpy", None): "numpy-1.26.4-cp311-cp311-win_amd64.whl",
    ("embreex", "linux-x64"): "embreex-4.4.0.post1-cp311-cp311-manylinux_2_28_x86_64.whl",
    ("embreex", "windows-x64"): "embreex-4.4.0.post1-cp311-cp311-win_amd64.whl",
    ("embreex", "macos-arm64"): "embreex-4.4.0.post1-cp311-cp311-macosx_13_0_arm64.whl",
}


def test_04_fetch_wheels_takes_onnxruntime_embreex_and_their_deps_but_never_numpy(tmp_path, monkeypatch):
    """fetch_wheels asks pip for binary cp311 wheels per Blender platform with --no-deps,
    follows each wheel's Requires-Dist (platform markers evaluated, extras skipped), never
    downloads numpy, and writes the manifest lines for exactly what it fetched (offline: pip
    is replaced by a fake that writes small wheels)."""
    fw = _script("fetch_wheels")
    calls = []

    def fake_run(cmd, check):
        req = cmd[-1]
        name = fw.canonical(req.split("=")[0].split(">")[0].split("<")[0])
        platform = next(p for p, tags in fw.PLATFORMS.items() if tags[0] in cmd)
        calls.append((name, platform, cmd))
        dest = Path(cmd[cmd.index("--dest") + 1])
        filename = FAKE_FILES.get((name, platform)) or FAKE_FILES[(name, None)]
        requires = {"onnxruntime": ORT_REQUIRES, "embreex": ("numpy",)}.get(name, ())
        _fake_wheel(dest, filename, requires)

    monkeypatch.setattr(fw.subprocess, "run", fake_run)
    files = fw.fetch("1.31.1", tmp_path, list(fw.PLATFORMS), extra=("embreex==4.4.0.post1",))
    names = {f.name for f in files}
    assert not any(n.startswith("numpy") for n in names)
    assert {c[0] for c in calls} == {"onnxruntime", "flatbuffers", "packaging", "protobuf",
                                     "coloredlogs", "embreex"}
    assert {c[1] for c in calls if c[0] == "embreex"} == set(fw.PLATFORMS)
    assert {c[1] for c in calls if c[0] == "coloredlogs"} == {"windows-x64"}   # marker
    for _name, _platform, cmd in calls:
        assert {"--no-deps", "--only-binary=:all:"} <= set(cmd)
        assert cmd[cmd.index("--python-version") + 1] == "3.11"
    listed = tomllib.loads((tmp_path / "wheels.toml").read_text())
    assert listed["platforms"] == ["linux-x64", "windows-x64", "macos-arm64"]
    assert sorted(Path(w).name for w in listed["wheels"]) == sorted(names)
    with pytest.raises(SystemExit, match="numpy"):
        fw.manifest_lines([tmp_path / FAKE_FILES[("numpy", None)]], ["windows-x64"])


@pytest.mark.slow
def test_05_release_build_bundles_platform_wheels_without_editing_the_repo(tmp_path):
    """build_extension --wheels --split-platforms: one zip per platform, each with its own
    onnxruntime wheel plus the pure ones, a manifest listing them, never numpy; the
    repository's manifest is untouched. Without wheels the build still works (offline)."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    for (name, _plat), filename in FAKE_FILES.items():
        if name not in ("numpy", "coloredlogs"):
            _fake_wheel(wheels, filename)
    fw = _script("fetch_wheels")
    (wheels / "wheels.toml").write_text(fw.manifest_lines(sorted(wheels.glob("*.whl")),
                                                          list(fw.PLATFORMS)))
    manifest_before = (ROOT / "blender_manifest.toml").read_bytes()
    out = tmp_path / "dist"
    _run(SCRIPTS / "build_extension.py", "--out", out, "--wheels", wheels, "--split-platforms")
    assert (ROOT / "blender_manifest.toml").read_bytes() == manifest_before
    zips = {z.name: z for z in out.glob("*.zip")}
    assert set(zips) == {"neurolens-0.1.0-linux_x64.zip", "neurolens-0.1.0-windows_x64.zip",
                         "neurolens-0.1.0-macos_arm64.zip"}
    tags = {"linux_x64": "manylinux", "windows_x64": "win_amd64", "macos_arm64": "macosx"}
    for zname, z in zips.items():
        with zipfile.ZipFile(z) as zf:
            names = zf.namelist()
            manifest = zf.read("blender_manifest.toml").decode()
        whls = [n for n in names if n.endswith(".whl")]
        ort = [n for n in whls if "onnxruntime" in n]
        want = tags[zname.split("-")[-1][:-4]]
        assert len(ort) == 1 and want in ort[0], (zname, ort)
        assert any("flatbuffers" in n for n in whls) and any("packaging" in n for n in whls)
        assert not any("numpy" in n.lower() for n in names)
        assert "wheels" in manifest and "platforms" in manifest
        assert {n.split("/", 1)[0] for n in names} == SHIPPED_TOP | {"wheels"}
    empty = tmp_path / "no-wheels"
    empty.mkdir()
    log = _run(SCRIPTS / "build_extension.py", "--out", tmp_path / "plain", "--wheels", empty)
    assert "building without them" in log
    assert len(list((tmp_path / "plain").glob("*.zip"))) == 1
