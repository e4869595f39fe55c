"""Writing files so that nothing is lost: write temporary files beside the targets, check
them, rename them.

`os.replace` is atomic within one file system (POSIX rename, Windows MoveFileEx), so whoever
reads the target (a compositor, Blender, a later render) and whatever stops the writer (an
exception, Ctrl-C, SIGTERM, a full disk) sees either the old file or the complete new one. The
temporary file is `.NAME.<random>.tmp<SUFFIX>` in the target's folder (the target's suffix
kept, for writers that pick the format from it: matplotlib, Blender's save_render, numpy) and
is removed when the write fails. A process killed outright (SIGKILL, power loss) can leave such
a hidden temporary file behind, never a truncated target.

Before a temporary file may replace anything it is
  1. flushed to disk (fsync; an error there is a failed write, not a detail),
  2. read back (core.filecheck): a writer can fail without saying so (Blender's image writer
     on a nearly full disk logs an error, returns, and leaves a truncated PNG or EXR), so
     PNG, OpenEXR and .npy files are decoded by default, and the byte writers compare what
     reached the disk with what they meant to write; a caller may pass its own `verify`,
  3. given the target's mode (and owner and group where allowed), or for a new file the mode
     the umask gives (0666 & ~umask), as open() would have: mkstemp's 0600 would make a
     farm's frames unreadable to the other users.
The target is the file a link names (the link stays a link) and must be a regular file or
absent: a FIFO, device, socket or directory is refused before anything is written, never
turned into a regular file (`output_target`; commands call it before they start their work).
Several files written together (`atomic_paths`, a render's --out) are all written and checked
before any is renamed, then renamed with the signals held, and if a rename fails the ones
already renamed are put back from hard links of the old files: all new or all old, as far as
POSIX allows (a file system without hard links renames those targets last).

Failures raise WriteError (an OSError): one line naming the file the caller asked for.

`exit_on_sigterm()` turns SIGTERM into SystemExit in a command-line process, so a farm that
stops a render runs the same clean-up as Ctrl-C does.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import signal
import stat
import tempfile
from pathlib import Path

from .filecheck import FileCheckError, check_file


class WriteError(OSError):
    """A file that could not be written, or that did not read back; str() is one line naming
    the file the caller asked for."""


def output_target(path) -> Path:
    """The file a write to `path` will replace, or WriteError saying why it cannot be written.

    Links are followed to their target (a dangling link to the file it names); the target
    must be a regular file or absent, in an existing folder this process may write to."""
    shown = str(path)
    real = Path(os.path.realpath(path))
    try:
        st = os.lstat(real)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise WriteError(f"{shown}: cannot write there ({exc.strerror or exc})") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        from .safe_io import file_kind
        what = ("a symbolic link that leads nowhere (a loop)" if stat.S_ISLNK(st.st_mode)
                else file_kind(st.st_mode))
        shown_real = "" if str(real) == os.path.abspath(shown) else f" ({real})"
        raise WriteError(f"{shown}{shown_real} is {what}, not a regular file: refusing to "
                         "replace it")
    folder = real.parent
    if not folder.is_dir():
        raise WriteError(f"{shown}: the folder {folder} does not exist" if not folder.exists()
                         else f"{shown}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise WriteError(f"{shown}: the folder {folder} is not writable")
    return real


def _umask() -> int:
    """The process's umask, read without changing it where the system says (Linux's
    /proc/self/status); elsewhere set and restored at once."""
    with contextlib.suppress(OSError, ValueError), \
            open("/proc/self/status", encoding="ascii", errors="replace") as fh:
        for line in fh:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def mode_for(target, directory: bool = False) -> int:
    """The permission bits a new version of `target` gets: the existing file's, or for a new
    one what the umask leaves of 0666 (0777 for a directory)."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return (0o777 if directory else 0o666) & ~_umask()


def _give_mode(tmp: Path, target: Path) -> None:
    """The target's mode, owner and group onto the temporary file (module docstring, 3)."""
    try:
        st = os.stat(target)
    except FileNotFoundError:
        os.chmod(tmp, mode_for(target))
        return
    chown = getattr(os, "chown", None)
    if chown is not None:
        mine = os.stat(tmp)
        # only root may give a file away, and only a group one belongs to: a file this process
        # cannot give its old owner or group keeps its own (the mode still applies)
        for uid in ((st.st_uid, -1) if mine.st_uid != st.st_uid else (-1,)):
            if (uid, st.st_gid) == (-1, mine.st_gid):
                break
            try:
                chown(tmp, uid, st.st_gid)
                break
            except OSError:
                continue
    os.chmod(tmp, stat.S_IMODE(st.st_mode))       # after chown, which clears set-id bits


def _sync(path: Path, shown: str) -> None:
    """fsync `path` through a write handle (Windows refuses fsync on read-only ones); a file
    system without fsync (EINVAL, ENOTSUP) still gets the atomic rename, any other error
    (EIO, ENOSPC, EDQUOT: data that never reached the disk) fails the write."""
    fd = os.open(path, os.O_RDWR | getattr(os, "O_BINARY", 0))
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
            raise WriteError(f"{shown}: could not write it to disk ({exc.strerror or exc}): "
                             "nothing was replaced") from None
    finally:
        os.close(fd)


def _finish(tmp: Path, target: Path, shown: str, allow_empty: bool, verify) -> None:
    """Steps 1-3 of the module docstring for one temporary file (checked as the format the
    name asked for says: the temporary file carries that suffix)."""
    try:
        size = os.stat(tmp).st_size
    except FileNotFoundError:
        size = None
    if size is None or (size == 0 and not allow_empty):
        raise WriteError(f"{shown}: nothing was written (the writer produced no file)")
    _sync(tmp, shown)
    try:
        if verify is None:
            check_file(tmp)
        else:
            verify(tmp)
    except (FileCheckError, OSError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise WriteError(f"{shown}: the new file does not read back ({reason}): nothing was "
                         "replaced") from None
    _give_mode(tmp, target)


def _backup(target: Path):
    """A hard link to the old `target` (a hidden name beside it), None where there is no old
    file or the file system cannot link."""
    for _ in range(100):
        name = target.with_name(f".{target.name}.{secrets.token_hex(4)}.old")
        try:
            os.link(target, name)
            return name
        except FileExistsError:
            continue
        except OSError:
            return None
    return None


def _rename_all(tmps: list[Path], targets: list[Path], shown: list[str]) -> None:
    """Rename every temporary file onto its target; put back what was renamed if one fails."""
    if len(targets) == 1:
        try:
            with signals_held():
                os.replace(tmps[0], targets[0])
        except OSError as exc:
            raise WriteError(f"{shown[0]}: could not replace it ({exc.strerror or exc}): "
                             "nothing was replaced") from None
        return
    existed = [os.path.lexists(t) for t in targets]
    backups = [_backup(t) if e else None for t, e in zip(targets, existed)]
    # an old file that could not be linked cannot be put back: rename those last
    order = sorted(range(len(targets)), key=lambda i: existed[i] and backups[i] is None)
    done = []
    try:
        with signals_held():
            try:
                for i in order:
                    os.replace(tmps[i], targets[i])
                    done.append(i)
            except OSError as exc:
                lost = []
                for j in reversed(done):
                    try:
                        if backups[j] is not None:
                            os.replace(backups[j], targets[j])
                            backups[j] = None
                        elif not existed[j]:
                            os.unlink(targets[j])
                        else:
                            lost.append(shown[j])
                    except OSError:
                        lost.append(shown[j])
                tail = (f"{', '.join(lost)} could not be put back" if lost else
                        "nothing was replaced")
                raise WriteError(f"{shown[i]}: could not replace it ({exc.strerror or exc}): "
                                 f"{tail}") from None
    finally:
        for b in backups:
            if b is not None:
                with contextlib.suppress(OSError):
                    os.unlink(b)


@contextlib.contextmanager
def atomic_paths(paths, allow_empty: bool = False, verify=None):
    """Yield temporary paths beside `paths` (one each); when the block succeeds, check them
    all, then rename them all onto their targets (module docstring).

    The block must write each complete file to its yielded path; a file left empty is refused
    (a writer such as Blender's save_render that failed silently) unless `allow_empty`.
    `verify(tmp)` raises (FileCheckError, OSError) when a written file is not what it should
    be; by default core.filecheck checks the formats it knows by the target's suffix. On any
    exception (including KeyboardInterrupt and SystemExit) the temporary files are removed
    and every target is untouched.
    """
    shown = [str(p) for p in paths]
    targets = [output_target(p) for p in paths]
    for k, t in enumerate(targets):
        if t in targets[:k]:
            raise WriteError(f"{shown[k]}: the same file as {shown[targets.index(t)]}")
    tmps = []
    try:
        for s, t in zip(shown, targets):
            try:
                # the suffix of the name asked for, which writers pick the format from (a
                # link `latest.png` to `frame` still gets a PNG)
                fd, tmp = tempfile.mkstemp(prefix=f".{t.name}.", suffix=".tmp" + Path(s).suffix,
                                           dir=t.parent)
            except OSError as exc:
                raise WriteError(f"{s}: cannot create a file in {t.parent} "
                                 f"({exc.strerror or exc})") from None
            os.close(fd)
            tmps.append(Path(tmp))
        try:
            yield list(tmps)
        except WriteError:
            raise
        except OSError as exc:
            # the writer's own error names the temporary file: name the target instead
            named = [s for s, tmp in zip(shown, tmps)
                     if len(tmps) == 1 or str(exc.filename or "") == str(tmp)]
            if not named:
                raise
            raise WriteError(f"{named[0]}: could not write it ({exc.strerror or exc}): "
                             "nothing was replaced") from None
        for s, t, tmp in zip(shown, targets, tmps):
            _finish(tmp, t, s, allow_empty, verify)
        _rename_all(tmps, targets, shown)
    except BaseException:
        for tmp in tmps:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_path(path, allow_empty: bool = False, verify=None):
    """Yield a temporary path beside `path`; check it and rename it onto `path` when the
    block succeeds (atomic_paths for one file)."""
    with atomic_paths([path], allow_empty=allow_empty, verify=verify) as (tmp,):
        yield tmp


def _holds(path, data: bytes) -> None:
    """FileCheckError unless the file at `path` holds exactly `data`."""
    size = os.path.getsize(path)
    if size != len(data):
        raise FileCheckError(f"{size} of its {len(data)} bytes reached the disk")
    with open(path, "rb") as fh:
        pos = 0
        while pos < len(data):
            piece = fh.read(1 << 20)
            if not piece or piece != data[pos:pos + len(piece)]:
                raise FileCheckError(f"the bytes on disk differ from those written at byte "
                                     f"{pos}")
            pos += len(piece)


def _write_all(path, data: bytes, shown: str) -> None:
    try:
        with open(path, "wb") as fh:
            fh.write(data)
    except OSError as exc:        # a short write raises here or at close's flush
        raise WriteError(f"{shown}: could not write it ({exc.strerror or exc}): nothing was "
                         "replaced") from None


def atomic_write_bytes(path, data: bytes) -> None:
    """`data` into `path` atomically, read back before it replaces the old file."""
    data = bytes(data)
    with atomic_path(path, allow_empty=True, verify=lambda tmp: _holds(tmp, data)) as tmp:
        _write_all(tmp, data, str(path))


def atomic_write_text(path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def write_checked(path, data: bytes, shown=None) -> None:
    """`data` into `path` in place, flushed to disk and read back: a file inside a directory
    that is itself renamed into place whole (replace_directory); `shown` names it in errors
    (the file the user will know, not the temporary directory's)."""
    shown = str(shown if shown is not None else path)
    data = bytes(data)
    _write_all(path, data, shown)
    _sync(Path(path), shown)
    try:
        _holds(path, data)
    except (FileCheckError, OSError) as exc:
        raise WriteError(f"{shown}: the new file does not read back ({exc}): nothing was "
                         "replaced") from None


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
