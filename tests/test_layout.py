"""Repository layout: tests and benchmarks never import each other (what both need lives in
testdata/, which imports neither), the add-on's tests never import the trainer or torch (they
also run under Blender 5.2 LTS's Python 3.13, where torch is not installed: only tests/trainer/
may), and testdata/ stays out of the extension zip."""

import ast
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: folder -> the top-level packages its modules must not import
FORBIDDEN = {"tests": {"benchmarks"}, "benchmarks": {"tests"},
             "testdata": {"tests", "benchmarks"}}
#: what the add-on's tests (every folder of tests/ but tests/trainer/) and testdata/ never import
TRAINER_SIDE = {"trainer", "torch"}


def imported_top_levels(source: str, package: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, top-level package) of every import in a module's source; relative imports are
    resolved against `package`, the module's own package as folder names from the root."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name.split(".")[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:max(len(package) - node.level + 1, 0)] if node.level else ()
            parts = list(base) + (node.module.split(".") if node.module else [])
            if parts:
                found.append((node.lineno, parts[0]))
            else:                          # `from .. import x` climbing to the root
                found += [(node.lineno, a.name) for a in node.names]
    return found


def test_01_tests_and_benchmarks_do_not_import_each_other():
    """Every module under tests/, benchmarks/ and testdata/, parsed with ast: no tests module
    imports benchmarks, no benchmarks module imports tests, testdata imports neither."""
    offenders = []
    for folder, forbidden in FORBIDDEN.items():
        files = sorted((ROOT / folder).rglob("*.py"))
        assert files, f"no Python files under {folder}/"
        for path in files:
            package = path.relative_to(ROOT).parent.parts
            for line, top in imported_top_levels(path.read_text(encoding="utf-8"), package):
                if top in forbidden:
                    offenders.append(f"{path.relative_to(ROOT)}:{line} imports {top}")
    assert not offenders, "\n".join(offenders)


def test_02_absolute_and_relative_imports_are_all_seen():
    """The check itself: absolute, dotted and relative imports (also ones that climb out of
    their package) are attributed to the top-level package they reach."""
    source = ("import tests.core\nfrom tests import core\nfrom .. import tests\n"
              "from ..tests.core import lenses\nfrom .common import ROOT\n"
              "def f():\n    import numpy as np\n")
    assert imported_top_levels(source, ("benchmarks",)) == [
        (1, "tests"), (2, "tests"), (3, "tests"), (4, "tests"), (5, "benchmarks"),
        (7, "numpy")]


def test_03_testdata_is_not_shipped():
    """The manifest's [build] excludes every top-level path ("/*") and re-includes what
    Blender needs, never testdata/."""
    build = tomllib.loads((ROOT / "blender_manifest.toml").read_text())["build"]
    patterns = build["paths_exclude_pattern"]
    assert "/*" in patterns
    assert not [p for p in patterns if p.startswith("!") and "testdata" in p]


def _trainer_side_imports(path: Path, source: str | None = None) -> list[str]:
    package = path.relative_to(ROOT).parent.parts
    text = path.read_text(encoding="utf-8") if source is None else source
    return [f"{path.relative_to(ROOT)}:{line} imports {top}"
            for line, top in imported_top_levels(text, package) if top in TRAINER_SIDE]


def test_04_the_addons_tests_import_neither_the_trainer_nor_torch():
    """Every module under tests/ (tests/trainer/ aside) and testdata/, imports inside functions
    included, imports neither the trainer nor torch: `make test-52` runs them where torch is
    not (they write their random models with onnx_export, not the trainer)."""
    files = [p for folder in ("tests", "testdata") for p in sorted((ROOT / folder).rglob("*.py"))
             if "trainer" not in p.relative_to(ROOT).parts[1:2]]
    assert len(files) > 50
    offenders = [bad for path in files for bad in _trainer_side_imports(path)]
    assert not offenders, "\n".join(offenders)


def test_05_the_trainer_check_sees_the_trainer():
    """The check of test_04 reports a trainer or torch import, also one inside a function."""
    path = ROOT / "tests" / "neural" / "probe.py"
    assert len(_trainer_side_imports(path, "from trainer.mlp import MLP\n")) == 1
    assert len(_trainer_side_imports(path, "def f():\n    import torch\n")) == 1
    assert _trainer_side_imports(path, "from onnx_export import write_onnx_files\n") == []


def test_06_every_script_and_benchmark_compiles():
    """The project's scripts, benchmarks and test data are run rarely (make models, make
    bench), so a syntax error there would sit unseen (a docstring's stray quote once broke
    scripts/train_presets.py): each compiles."""
    import ast
    files = [p for folder in ("scripts", "benchmarks", "testdata", "trainer")
             for p in sorted((ROOT / folder).rglob("*.py"))]
    assert len(files) > 30
    for path in files:
        ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
