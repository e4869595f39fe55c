"""Nothing lost: every write goes to a temporary file beside the target and is renamed."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from neurolens_addon.core import atomic

ROOT = Path(__file__).resolve().parents[2]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_01_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    """An exception (here KeyboardInterrupt) halfway through: the target keeps its old bytes
    and no temporary file is left; a successful write replaces it whole."""
    target = tmp_path / "frame.exr"
    target.write_bytes(b"old frame")
    with pytest.raises(KeyboardInterrupt):
        with atomic.atomic_path(target) as tmp:
            tmp.write_bytes(b"half a fr")
            raise KeyboardInterrupt
    assert target.read_bytes() == b"old frame" and leftovers(tmp_path) == []
    atomic.atomic_write_bytes(target, b"new frame")
    assert target.read_bytes() == b"new frame" and leftovers(tmp_path) == []


def test_02_a_writer_that_writes_nothing_changes_nothing(tmp_path):
    """A writer that leaves the temporary file empty (Blender failing to save) is an error and
    the target stays."""
    target = tmp_path / "out.png"
    target.write_bytes(b"png")
    with pytest.raises(OSError, match="nothing was written"):
        with atomic.atomic_path(target):
            pass
    assert target.read_bytes() == b"png" and leftovers(tmp_path) == []


def test_03_sigterm_during_a_write_leaves_the_old_file(tmp_path):
    """A process with exit_on_sigterm that is sent SIGTERM in the middle of a write exits
    with 143, the old file intact and no temporary file left."""
    target = tmp_path / "rays.npy"
    target.write_bytes(b"old rays")
    script = textwrap.dedent(f"""
        import os, signal
        from neurolens_addon.core import atomic
        atomic.exit_on_sigterm()
        with atomic.atomic_path({str(target)!r}) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"partial")
                fh.flush()
                os.kill(os.getpid(), signal.SIGTERM)
                fh.write(b" never")
    """)
    p = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 128 + signal.SIGTERM, p.stderr
    assert target.read_bytes() == b"old rays" and leftovers(tmp_path) == []


def test_04_a_directory_swap_that_fails_puts_the_old_one_back(tmp_path, monkeypatch):
    """replace_directory: if renaming the new directory into place fails, the old directory
    is where it was, complete."""
    out, new = tmp_path / "m.neurolens", tmp_path / "m.tmp"
    out.mkdir()
    (out / "model.json").write_text("old")
    new.mkdir()
    (new / "model.json").write_text("new")
    real = os.replace
    calls = []

    def flaky(a, b):
        calls.append((a, b))
        if len(calls) == 2:
            raise OSError("disk full")
        return real(a, b)
    monkeypatch.setattr(atomic.os, "replace", flaky)
    with pytest.raises(OSError, match="disk full"):
        atomic.replace_directory(new, out)
    assert (out / "model.json").read_text() == "old"
    monkeypatch.setattr(atomic.os, "replace", real)
    atomic.replace_directory(new, out)
    assert (out / "model.json").read_text() == "new" and not new.exists()
