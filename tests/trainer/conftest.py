"""The trainer's tests need torch, which only the project's Python 3.11 environment has (.venv:
`make test`). Where torch is not installed (Blender 5.2 LTS's Python 3.13: `make test-52`, which
runs the add-on's tests) each module here is collected as one skipped test that says why,
instead of failing to import."""

from __future__ import annotations

import importlib.util

import pytest

HAS_TORCH = importlib.util.find_spec("torch") is not None
WHY = ("the trainer needs torch, which this Python does not have: its tests run in the "
       "project's Python 3.11 environment (.venv, make test)")


class NeedsTorch(pytest.Item):
    """Stands for a trainer test module that cannot be imported without torch."""

    def runtest(self):
        pytest.skip(WHY)

    def reportinfo(self):
        return self.path, None, f"{self.path.name}: needs torch"


class TorchlessModule(pytest.File):
    def collect(self):
        yield NeedsTorch.from_parent(self, name="needs torch")


def pytest_pycollect_makemodule(module_path, parent):
    if not HAS_TORCH:
        return TorchlessModule.from_parent(parent, path=module_path)
    return None
