"""The extension package: Blender's own tool validates the manifest and builds the zip, the zip
ships only what Blender needs, installs and registers in a fresh Blender user directory and
unregisters cleanly; release builds bundle onnxruntime wheels per platform, never numpy, for
Python 3.11 (Blender 5.0) and 3.13 (5.1, 5.2 LTS) in one zip a platform, from which Blender
installs its own Python's. `make test` runs this file with Blender 5.0's bpy and tool,
`make test-52` with 5.2's."""

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
    """This Blender's extension tool validates the manifest and the built zip; it targets
    Blender 5.0 up to (not including) 5.3, the versions tested (5.0 and 5.2 LTS, this
    Blender among them), is an add-on with id 'neurolens' and lists no wheels (those go into
    release builds only)."""
    import bpy
    _zip, log = built_zip
    assert "Success parsing TOML" in log
    assert f"validated by blender_ext of bpy {bpy.app.version_string.split()[0]}" in log
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["blender_version_min"] == "5.0.0" and manifest["type"] == "add-on"
    assert manifest["blender_version_max"] == "5.3.0"
    assert (5, 0, 0) <= bpy.app.version < (5, 3, 0)
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


def _for_python(filename: str, python: str) -> str:
    """FAKE_FILES' cp311 file name as the wheel of Python `python` ("3.13": cp313); pure and
    abi3 wheels serve every Python and keep their name."""
    tag = "cp3" + python.split(".")[1]
    return filename.replace("cp311-cp311", f"{tag}-{tag}")


def test_04_fetch_wheels_takes_onnxruntime_embreex_and_their_deps_but_never_numpy(tmp_path, monkeypatch):
    """fetch_wheels asks pip for binary wheels per Blender platform and per Blender Python
    (3.11 for 5.0, 3.13 for 5.1 and 5.2 LTS) with --no-deps, follows each wheel's
    Requires-Dist (platform and Python markers evaluated, extras skipped), never downloads
    numpy, and writes the manifest lines for exactly what it fetched, one list for both
    Pythons (offline: pip is replaced by a fake that writes small wheels)."""
    fw = _script("fetch_wheels")
    calls = []

    def fake_run(cmd, check):
        req = cmd[-1]
        name = fw.canonical(req.split("=")[0].split(">")[0].split("<")[0])
        platform = next(p for p, tags in fw.PLATFORMS.items() if tags[0] in cmd)
        python = cmd[cmd.index("--python-version") + 1]
        calls.append((name, platform, python, cmd))
        dest = Path(cmd[cmd.index("--dest") + 1])
        filename = FAKE_FILES.get((name, platform)) or FAKE_FILES[(name, None)]
        requires = {"onnxruntime": ORT_REQUIRES, "embreex": ("numpy",)}.get(name, ())
        _fake_wheel(dest, _for_python(filename, python), requires)

    monkeypatch.setattr(fw.subprocess, "run", fake_run)
    files = fw.fetch("1.31.1", tmp_path, list(fw.PLATFORMS), extra=("embreex==4.4.0.post1",))
    names = {f.name for f in files}
    assert not any(n.startswith("numpy") for n in names)
    assert {c[0] for c in calls} == {"onnxruntime", "flatbuffers", "packaging", "protobuf",
                                     "coloredlogs", "embreex"}
    assert {(c[1], c[2]) for c in calls if c[0] == "embreex"} == {
        (p, v) for p in fw.PLATFORMS for v in ("3.11", "3.13")}
    assert {c[1] for c in calls if c[0] == "coloredlogs"} == {"windows-x64"}   # marker
    for _name, _platform, _python, cmd in calls:
        assert {"--no-deps", "--only-binary=:all:"} <= set(cmd)
    assert {c[2] for c in calls} == {"3.11", "3.13"} == set(fw.PYTHON_VERSIONS)
    ort = sorted(n for n in names if n.startswith("onnxruntime"))
    assert len(ort) == 6 and sum("cp313" in n for n in ort) == 3     # 3 platforms x 2
    assert sum(n.startswith("protobuf") for n in names) == 3          # abi3: once a platform
    listed = tomllib.loads((tmp_path / "wheels.toml").read_text())
    assert listed["platforms"] == ["linux-x64", "windows-x64", "macos-arm64"]
    assert listed["pythons"] == ["3.11", "3.13"]
    assert sorted(Path(w).name for w in listed["wheels"]) == sorted(names)
    for platform in fw.PLATFORMS:
        assert fw.missing_pythons(files, listed["pythons"], platform) == {}
    with pytest.raises(SystemExit, match="numpy"):
        fw.manifest_lines([tmp_path / FAKE_FILES[("numpy", None)]], ["windows-x64"])


@pytest.mark.parametrize("filename, pythons, platform", [
    ("onnxruntime-1.32.0-cp311-cp311-manylinux_2_28_x86_64.whl", {"3.11"}, "linux-x64"),
    ("onnxruntime-1.32.0-cp313-cp313-win_amd64.whl", {"3.13"}, "windows-x64"),
    ("embreex-4.4.0.post1-cp313-cp313-macosx_13_0_arm64.whl", {"3.13"}, "macos-arm64"),
    ("protobuf-7.36.2-cp310-abi3-macosx_10_9_universal2.whl", {"3.11", "3.13"}, "macos-arm64"),
    ("cffi-2.0.0-cp312-cp312-manylinux_2_17_x86_64.whl", set(), "linux-x64"),
    ("pyoidn-2.5.1.0-py3-none-manylinux2014_x86_64.whl", {"3.11", "3.13"}, "linux-x64"),
    ("flatbuffers-25.12.19-py2.py3-none-any.whl", {"3.11", "3.13"}, None),
    ("onnxruntime-1.32.0-cp313-cp313-manylinux_2_28_aarch64.whl", {"3.13"}, "other"),
])
def test_04b_a_wheel_tells_its_pythons_and_platform(filename, pythons, platform):
    """Which Blender Pythons and platform a wheel file serves, read from its tags as Blender's
    installer reads them (cpXY exactly, abi3 from its version on, py3 always; any glibc or
    macOS version, arm64 or universal2 on a Mac)."""
    fw = _script("fetch_wheels")
    assert fw.wheel_pythons(filename) == pythons
    assert fw.wheel_platform(filename) == platform


def test_04c_a_release_missing_a_pythons_wheel_is_refused(tmp_path):
    """wheels/ whose windows onnxruntime is there for Python 3.11 only: the build stops before
    building, naming the platform, the package and the Python left without it."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    made = [_fake_wheel(wheels, _for_python(FAKE_FILES[("onnxruntime", p)], v))
            for p in ("linux-x64", "windows-x64") for v in ("3.11", "3.13")
            if (p, v) != ("windows-x64", "3.13")]
    made.append(_fake_wheel(wheels, FAKE_FILES[("packaging", None)]))
    fw = _script("fetch_wheels")
    (wheels / "wheels.toml").write_text('pythons = ["3.11", "3.13"]\n' + fw.manifest_lines(
        made, ["linux-x64", "windows-x64"]))
    proc = subprocess.run([sys.executable, str(SCRIPTS / "build_extension.py"), "--out",
                           str(tmp_path / "dist"), "--wheels", str(wheels)],
                          capture_output=True, text=True, cwd=ROOT, timeout=240)
    assert proc.returncode != 0
    assert "windows-x64: onnxruntime for Python 3.13" in proc.stderr
    assert "linux-x64" not in proc.stderr.split("package")[-1]
    assert not (tmp_path / "dist").exists() or not list((tmp_path / "dist").glob("*.zip"))


@pytest.mark.slow
def test_05_release_build_bundles_platform_wheels_without_editing_the_repo(tmp_path):
    """build_extension --wheels --split-platforms: one zip per platform, each with its own
    onnxruntime wheels for Python 3.11 and 3.13 plus the pure ones, a manifest listing them,
    validated by this Blender's tool, never numpy; the repository's manifest is untouched.
    Without wheels the build still works (offline)."""
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    for (name, _plat), filename in FAKE_FILES.items():
        if name not in ("numpy", "coloredlogs"):
            for python in ("3.11", "3.13"):
                _fake_wheel(wheels, _for_python(filename, python))
    fw = _script("fetch_wheels")
    (wheels / "wheels.toml").write_text('pythons = ["3.11", "3.13"]\n' + fw.manifest_lines(
        sorted(wheels.glob("*.whl")), list(fw.PLATFORMS)))
    manifest_before = (ROOT / "blender_manifest.toml").read_bytes()
    out = tmp_path / "dist"
    log = _run(SCRIPTS / "build_extension.py", "--out", out, "--wheels", wheels,
               "--split-platforms")
    assert log.count("validated by blender_ext of bpy") == 3
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
        assert len(ort) == 2 and all(want in n for n in ort), (zname, ort)
        assert sorted(n.split("-")[2] for n in ort) == ["cp311", "cp313"]
        assert any("flatbuffers" in n for n in whls) and any("packaging" in n for n in whls)
        assert not any("numpy" in n.lower() for n in names)
        assert "wheels" in manifest and "platforms" in manifest
        assert {n.split("/", 1)[0] for n in names} == SHIPPED_TOP | {"wheels"}
    empty = tmp_path / "no-wheels"
    empty.mkdir()
    log = _run(SCRIPTS / "build_extension.py", "--out", tmp_path / "plain", "--wheels", empty)
    assert "building without them" in log
    assert len(list((tmp_path / "plain").glob("*.zip"))) == 1


PICK_CHECK = r'''
import json, os, sys
zip_path, user = sys.argv[1], sys.argv[2]
os.environ["BLENDER_USER_RESOURCES"] = user
import bpy
res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                               enable_on_install=True)
import neurolens_probe
print("RESULT " + json.dumps({"installed": sorted(res), "tag": neurolens_probe.TAG,
                              "file": neurolens_probe.__file__,
                              "python": "cp%d%d" % sys.version_info[:2]}))
'''


@pytest.mark.slow
def test_06_one_zip_installs_in_either_blender_with_its_own_pythons_wheel(tmp_path):
    """A release zip for Linux holding one package's wheels for Python 3.11 and 3.13 (a small
    package made here that says which wheel it came from) installs in this Blender (5.0 or
    5.2): Blender's installer picks the wheel of its own Python, from the user directory."""
    import sysconfig
    if sysconfig.get_platform() != "linux-x86_64":
        pytest.skip("the probe wheels are built for linux-x86_64")
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    made = []
    for tag in ("cp311", "cp313"):
        path = wheels / f"neurolens_probe-1.0-{tag}-{tag}-manylinux_2_28_x86_64.whl"
        info = "neurolens_probe-1.0.dist-info"
        with zipfile.ZipFile(path, "w") as zf:
            zf.writestr("neurolens_probe/__init__.py", f'TAG = "{tag}"\n')
            zf.writestr(f"{info}/METADATA",
                        "Metadata-Version: 2.1\nName: neurolens_probe\nVersion: 1.0\n")
            zf.writestr(f"{info}/WHEEL", f"Wheel-Version: 1.0\nRoot-Is-Purelib: false\n"
                                         f"Tag: {tag}-{tag}-manylinux_2_28_x86_64\n")
            zf.writestr(f"{info}/RECORD", "")
        made.append(path)
    fw = _script("fetch_wheels")
    (wheels / "wheels.toml").write_text('pythons = ["3.11", "3.13"]\n'
                                        + fw.manifest_lines(made, ["linux-x64"]))
    out = tmp_path / "dist"
    _run(SCRIPTS / "build_extension.py", "--out", out, "--wheels", wheels, "--split-platforms")
    (zip_path,) = out.glob("*.zip")
    user = tmp_path / "blender-user"
    user.mkdir()
    script = tmp_path / "pick_check.py"
    script.write_text(PICK_CHECK)
    log = _run(script, zip_path, user)
    result = json.loads(next(x for x in log.splitlines() if x.startswith("RESULT "))[7:])
    assert result["installed"] == ["FINISHED"]
    assert result["tag"] == result["python"]
    assert Path(result["file"]).resolve().is_relative_to(user.resolve())
