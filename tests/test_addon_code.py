"""The shipped add-on's code as a whole (every package of neurolens_addon): it never unpickles,
evaluates file contents or reaches the network."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


FORBIDDEN_CALLS = {"eval", "exec", "compile", "__import__"}
FORBIDDEN_MODULES = {"pickle", "cPickle", "dill", "marshal", "shelve", "socket", "urllib",
                     "http", "requests", "ftplib", "smtplib"}


def test_01_addon_code_has_no_pickle_eval_or_network():
    """No module of the shipped add-on imports pickle-like or network modules, or calls eval,
    exec, compile or __import__ (lens and model files are data, never code)."""
    offenders = []
    for path in sorted((ROOT / "neurolens_addon").rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name.split(".")[0] for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [(node.module or "").split(".")[0]]
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id in FORBIDDEN_CALLS:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {node.func.id}")
                continue
            else:
                continue
            bad = [n for n in names if n in FORBIDDEN_MODULES]
            if bad:
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} imports {bad}")
    assert not offenders, "\n".join(offenders)
