"""Reading files that may not be what their names say: regular files only, bounded, never blocking.

A FIFO or a device named as a lens, model or graph file blocks open() or read() forever (on
Blender's main thread, when Automatic scans a models folder); a link to /dev/zero reads
without end. `read_regular(path, limit, what)` therefore
  1. stats the path (links followed) and refuses anything but a regular file,
  2. opens it non-blocking, so a FIFO put there after the stat cannot block the open, and
     refuses it unless the opened file is regular too (fstat),
  3. refuses a size over `limit` before reading, and reads at most limit + 1 bytes (a file
     that grows while read is refused as well).
Problems raise UnreadableFile (an OSError) with one line naming the file and its `reason`;
callers turn it into their own error (LensError, ModelError, ...).
"""

from __future__ import annotations

import os
import stat


class UnreadableFile(OSError):
    """A file that is not a readable regular file within its size limit: `reason` says why
    (callers whose errors name the file themselves use it), str() is "path: reason"."""

    def __init__(self, path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = str(path), reason


def _mib(n: int) -> str:
    return f"{n / (1 << 20):g} MiB"


def check_regular(path, what: str) -> os.stat_result:
    """The file's stat, or UnreadableFile unless `path` is a regular file (links followed)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise UnreadableFile(path, f"cannot read the {what}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnreadableFile(path, f"the {what} is {file_kind(st.st_mode)}, not a regular file")
    return st


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, in words ("a FIFO", "a directory", ...)."""
    return ("a directory" if stat.S_ISDIR(mode) else
            "a FIFO" if stat.S_ISFIFO(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else
            "a symbolic link" if stat.S_ISLNK(mode) else "not a regular file")


def read_regular(path, limit: int, what: str) -> bytes:
    """The bytes of the regular file `path`, at most `limit` of them (module docstring)."""
    st = check_regular(path, what)
    if st.st_size > limit:
        raise UnreadableFile(path, f"the {what} is {st.st_size} bytes, over its limit of "
                                   f"{_mib(limit)}")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        raise UnreadableFile(path, f"cannot read the {what}: {exc.strerror or exc}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UnreadableFile(path, f"the {what} is not a regular file")
        chunks, total = [], 0
        while total <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except UnreadableFile:
        raise
    except OSError as exc:
        raise UnreadableFile(path, f"cannot read the {what}: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if total > limit:
        raise UnreadableFile(path, f"the {what} is larger than its limit of {_mib(limit)}")
    return b"".join(chunks)
