"""The layering DESIGN.md promises, read from every import statement (module level and inside
functions) of the add-on and the trainer:

    render (command line) -> blender (bpy glue) -> engine, cycles -> camera -> neural -> core
    trainer -> core, and neural's model-file layer (the format it writes; the runtime only to
               measure the model it wrote); onnx_export (the model's ONNX graphs)
    onnx_export -> core, and neural's model-file layer; never torch, never the trainer

bpy, mathutils and bpy_extras are imported only by blender/ and render/; torch only by the
trainer; nothing in the add-on imports the trainer, onnx_export, tests or benchmarks; and no
two modules import each other at module level, directly or around a circle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ADDON = "neurolens_addon"

#: package -> the project packages its modules may import
ALLOWED = {
    f"{ADDON}.core": {"core"},
    f"{ADDON}.neural": {"core", "neural"},
    f"{ADDON}.camera": {"core", "neural", "camera"},
    f"{ADDON}.engine": {"core", "neural", "camera", "engine"},
    f"{ADDON}.cycles": {"core", "neural", "camera", "cycles"},
    f"{ADDON}.blender": {"core", "neural", "camera", "engine", "cycles", "blender"},
    f"{ADDON}.render": {"core", "neural", "camera", "engine", "cycles", "blender", "render",
                        ""},
    ADDON: {"blender"},
}
#: what the trainer may use of neural: the model-file layer (the format, its float64 reference
#: semantics, where scene models are stored) and the runtime itself, to measure a model it wrote
#: exactly as the renderers will run it (trainer evaluate); nothing of the glue or renderers
MODEL_FILE_LAYER = {"modelfile", "reference", "cache", "model"}
BPY = {"bpy", "_bpy", "mathutils", "bpy_extras", "bpy_types", "addon_utils", "_cycles", "cycles",
       "bmesh", "gpu", "gpu_extras", "blf", "bl_math", "idprop", "bl_ui", "bl_operators",
       "imbuf", "aud", "freestyle"}
BPY_USERS = {f"{ADDON}.blender", f"{ADDON}.render"}
NEVER = {"trainer", "onnx_export", "tests", "benchmarks", "torch"}
#: the packages beside the add-on that use its core and model-file layer, and what else each
#: must never import (onnx_export writes models where torch is not: Blender 5.2's Python 3.13)
USERS = {"trainer": {"tests", "benchmarks"},
         "onnx_export": {"tests", "benchmarks", "trainer", "torch"}}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path, name: str | None = None, source: str | None = None):
    """(imported module, line, at module level) for every import in the file (or in `source`,
    read as the module `name`)."""
    name = name or _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(source if source is not None else path.read_text(encoding="utf-8"))
    top = {id(n) for n in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno, id(node) in top
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            if node.module is None:          # from . import a, b: each is a module
                for a in node.names:
                    yield f"{mod}.{a.name}", node.lineno, id(node) in top
            else:
                yield mod, node.lineno, id(node) in top


def _files(*folders):
    for folder in folders:
        yield from sorted((ROOT / folder).rglob("*.py"))


def _package_of(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == ADDON and len(parts) > 1 else parts[0]


def _addon_violations(path: Path, name: str | None = None, source: str | None = None):
    bad = []
    mine = _package_of(name or _module_name(path))
    for mod, line, _top in _imports(path, name, source):
        root = mod.split(".")[0]
        where = f"{path.name}:{line} imports {mod}"
        if root in NEVER:
            bad.append(where)
        elif root in BPY and mine not in BPY_USERS:
            bad.append(where + " (bpy only in blender/ and render/)")
        elif root == ADDON:
            target = mod.split(".")[1] if "." in mod else ""
            if target not in ALLOWED.get(mine, set()):
                bad.append(where + f" ({mine} may import {sorted(ALLOWED.get(mine, ()))})")
    return bad


def _layer_violations():
    bad = []
    for path in _files(ADDON):
        bad += [f"{path.parent.name}/{b}" for b in _addon_violations(path)]
    for user, never in USERS.items():
        for path in _files(user):
            for mod, line, _top in _imports(path):
                parts = mod.split(".")
                if parts[0] in BPY or parts[0] in never:
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
                elif parts[0] == ADDON:
                    ok = (len(parts) > 1 and parts[1] == "core") or (
                        len(parts) > 2 and parts[1] == "neural" and parts[2] in MODEL_FILE_LAYER)
                    if not ok:
                        bad.append(f"{path.relative_to(ROOT)}:{line} imports {mod} ({user} "
                                   f"uses core and neural.{sorted(MODEL_FILE_LAYER)})")
    return bad


def test_every_import_points_down_the_layers():
    assert _layer_violations() == []


def _cycles(graph: dict) -> list[list[str]]:
    """Every circle of module-level imports in {module: imported modules} (one per circle
    found). A package's __init__ importing its own submodules is not a circle through them."""
    state, found = {}, []

    def inside(module, package):
        return module.startswith(package + ".")

    def visit(node, stack):
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if inside(nxt, node):
                continue            # a package importing its own submodule
            if state.get(nxt) == 1:
                found.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    return found


def _module_graph(inside_functions: bool = False) -> dict:
    """{module: the project modules it imports} over the add-on, the trainer and onnx_export:
    the imports at module level, and with `inside_functions` those inside functions too."""
    names = {_module_name(path) for path in _files(ADDON, *USERS)}
    graph = {}
    for path in _files(ADDON, *USERS):
        me = _module_name(path)
        deps = set()
        for mod, _line, top in _imports(path):
            if not (top or inside_functions):
                continue
            while mod and mod not in names:      # `from pkg.mod import name` -> pkg.mod
                mod = mod.rpartition(".")[0]
            if mod and mod != me:
                deps.add(mod)
        graph[me] = deps
    return graph


def test_no_module_level_import_cycle():
    assert _cycles(_module_graph()) == []


def test_no_import_cycle_through_imports_inside_functions():
    """A circle held apart only by an import inside a function is still a circle: two modules
    that need each other are one concept split in two, or a third module's missing."""
    assert _cycles(_module_graph(inside_functions=True)) == []


def test_the_graph_sees_imports_inside_functions():
    """An import inside a function is read (not at module level), and the graph with such
    imports holds edges the module-level graph lacks (so the test above could fail)."""
    path = ROOT / ADDON / "cycles" / "probe.py"
    source = "import math\ndef f():\n    from ..camera.derived import follow_tables\n"
    found = list(_imports(path, f"{ADDON}.cycles.probe", source))
    assert (f"{ADDON}.camera.derived", 3, False) in found and ("math", 1, True) in found
    at_top, everywhere = _module_graph(), _module_graph(inside_functions=True)
    assert any(everywhere[m] - at_top.get(m, set()) for m in everywhere)


@pytest.mark.parametrize("source", ["from ..blender import sync\n", "import bpy\n",
                                    "import bmesh\n", "from ..neural.model import LearnedLens\n",
                                    "def f():\n    from ..engine import plan\n"])
def test_the_check_itself_sees_a_wrong_way_import(source):
    """A core module importing the glue, bpy or the neural runtime is reported."""
    path = ROOT / ADDON / "core" / "probe.py"
    assert len(_addon_violations(path, f"{ADDON}.core.probe", source)) == 1
    assert _addon_violations(path, f"{ADDON}.core.probe", "from .film import Film\n") == []
