"""Writing files so that nothing is lost: write a temporary file beside the target, rename it.

`os.replace` is atomic within one file system (POSIX rename, Windows MoveFileEx), so whoever
reads the target (a compositor, Blender, a later render) and whatever stops the writer (an
exception, Ctrl-C, SIGTERM, a full disk) sees either the old file or the complete new one. The
temporary file is `.NAME.<random>.tmp<SUFFIX>` in the target's folder (the target's suffix
kept, for writers that pick the format from it: matplotlib, Blender's save_render, numpy) and
is removed when the write fails. A process killed outright (SIGKILL, power loss) can leave such
a hidden temporary file behind, never a truncated target.

`exit_on_sigterm()` turns SIGTERM into SystemExit in a command-line process, so a farm that
stops a render runs the same clean-up as Ctrl-C does.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
from pathlib import Path


@contextlib.contextmanager
def atomic_path(path, allow_empty: bool = False):
    """Yield a temporary path beside `path`; rename it onto `path` when the block succeeds.

    The block must write the complete file to the yielded path; a file left empty is refused
    (a writer such as Blender's save_render that failed silently) unless `allow_empty`. On any
    exception (including KeyboardInterrupt and SystemExit) the temporary file is removed and
    `path` is untouched.
    """
    target = Path(path)
    folder = target.parent
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp" + target.suffix,
                               dir=folder)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        if not tmp.exists() or (tmp.stat().st_size == 0 and not allow_empty):
            raise OSError(f"{target}: nothing was written (the writer produced no file)")
        # flush to disk before the rename (a write handle: Windows refuses fsync on read-only
        # ones); a file system without fsync still gets the atomic rename
        with open(tmp, "r+b") as fh, contextlib.suppress(OSError):
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    with atomic_path(path, allow_empty=True) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)


def atomic_write_text(path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM for the block (POSIX; elsewhere a no-op): steps that must not be
    split, such as swapping a directory into place in two renames, finish first."""
    mask = getattr(signal, "pthread_sigmask", None)
    if mask is None:
        yield
        return
    old = mask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        mask(signal.SIG_SETMASK, old)


def replace_directory(tmp, out) -> None:
    """Put the complete directory `tmp` at `out` (replacing what is there): two renames with
    the signals held, and the old directory put back should the second fail."""
    import shutil
    tmp, out = Path(tmp), Path(out)
    with signals_held():
        if not out.exists():
            os.replace(tmp, out)
            return
        old = out.with_name(out.name + ".old")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(out, old)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old, out)
            raise
    shutil.rmtree(old, ignore_errors=True)


def exit_on_sigterm() -> None:
    """SIGTERM raises SystemExit(143) in the main thread (clean-up runs, as for Ctrl-C)."""
    def _handler(signum, _frame):
        raise SystemExit(128 + signum)
    with contextlib.suppress(ValueError):        # not the main thread: leave it alone
        signal.signal(signal.SIGTERM, _handler)
