"""The core is pure numpy: importing every core module never needs bpy, onnxruntime or torch."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

BLOCKER = r"""
import sys, importlib.abc, pkgutil
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('bpy', 'onnxruntime', 'torch', 'mathutils'):
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
import neurolens_addon.core as core
names = [m.name for m in pkgutil.iter_modules(core.__path__) if m.name != '__main__']
for n in names:
    __import__('neurolens_addon.core.' + n)
print(len(names))
"""


def test_01_core_imports_with_bpy_onnxruntime_and_torch_blocked():
    """Every module of neurolens_addon.core imports with bpy, onnxruntime and torch blocked."""
    proc = subprocess.run([sys.executable, "-c", BLOCKER], cwd=ROOT, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 12
