"""The two environments the add-on is tested in: Blender 5.0 (requirements.txt: bpy 5.0.1,
Python 3.11, numpy 1.26, torch for the trainer) and Blender 5.2 LTS (requirements-5.2.txt: bpy
5.2.3, Python 3.13, numpy 2, no torch), `make test` and `make test-52`, and CI running both."""

from __future__ import annotations

import platform
import re
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from packaging.requirements import Requirement
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]


def requirements(name: str) -> dict:
    """{canonical project name: Requirement} of a requirements file."""
    out = {}
    for line in (ROOT / name).read_text(encoding="utf-8").splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            req = Requirement(line)
            out[req.name.lower()] = req
    return out


def test_01_blender_5_0_keeps_its_pins():
    """requirements.txt: bpy 5.0.1, numpy below 2 (bpy 5.0 needs 1.x), torch exactly 2.13.0
    (the CPU wheel already on the machines)."""
    reqs = requirements("requirements.txt")
    assert str(reqs["bpy"].specifier) == "==5.0.1"
    assert str(reqs["torch"].specifier) == "==2.13.0"
    assert not reqs["numpy"].specifier.contains("2.0") and reqs["numpy"].specifier.contains(
        "1.26.4")


def test_02_blender_5_2_has_numpy_2_and_no_torch():
    """requirements-5.2.txt: bpy 5.2.3, numpy 2 (never 1.x, which bpy 5.2 refuses), the add-on's
    runtime packages and no torch (the trainer stays in the 3.11 environment)."""
    reqs = requirements("requirements-5.2.txt")
    assert str(reqs["bpy"].specifier) == "==5.2.3"
    assert reqs["numpy"].specifier.contains("2.5.5") and not reqs["numpy"].specifier.contains(
        "1.26.4")
    assert "torch" not in reqs
    assert {"onnxruntime", "embreex", "pyoidn", "pytest", "openexr", "onnx"} <= set(reqs)


def test_03_this_environment_is_one_of_the_two():
    """The Python running the tests is one of them: bpy 5.0.x on Python 3.11 with numpy 1, or
    bpy 5.2.x on Python 3.13 with numpy 2."""
    import numpy
    try:
        bpy_version = Version(version("bpy"))
    except PackageNotFoundError:
        import pytest
        pytest.skip("bpy is not installed here")
    numpy_major = int(numpy.__version__.split(".")[0])
    python = sys.version_info[:2]
    want = {(5, 0): ((3, 11), 1), (5, 2): ((3, 13), 2)}.get(bpy_version.release[:2])
    assert want is not None, f"bpy {bpy_version}: neither of the tested Blenders"
    assert (python, numpy_major) == want, (platform.python_version(), numpy.__version__)


def test_04_make_and_ci_run_both():
    """`make test-52` builds .venv-5.2 from requirements-5.2.txt with PYTHON313 and runs the
    tests there; .ci/run runs it after `make test`, where a Python 3.13 is found."""
    make = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert re.search(r"^\$\(STAMP52\): requirements-5\.2\.txt$", make, re.M)
    assert "$(PYTHON313) -m venv $(VENV52)" in make
    assert re.search(r"^test-52: venv-52\n(\t.*\n)*\t\$\(PY52\) -m pytest .* tests$", make, re.M)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert ci.index("make test\n") < ci.index("make test-52")
    assert ".venv-5.2/" in (ROOT / ".gitignore").read_text(encoding="utf-8").splitlines()
