"""The project's own error types.

Every error raised for bad input names where the problem is (file, line or surface, field) and
what was expected, so a user can fix the file without reading our code.
"""

from __future__ import annotations


class NeuroLensError(Exception):
    """Base class of every error this project raises on purpose."""


class LensError(NeuroLensError, ValueError):
    """A lens prescription is malformed or unphysical.

    `path` is the file (or None for an in-memory lens), `surface` the 1-based surface number in
    the file (None when the problem is not about one surface), `field` the offending key.
    """

    def __init__(self, message: str, *, path: str | None = None, surface: int | None = None,
                 field: str | None = None):
        self.path = path
        self.surface = surface
        self.field = field
        self.message = message
        where = []
        if path:
            where.append(str(path))
        if surface is not None:
            where.append(f"surface {surface}")
        if field:
            where.append(f"field '{field}'")
        prefix = ": ".join([", ".join(where)]) + ": " if where else ""
        super().__init__(prefix + message)


class GlassError(NeuroLensError, KeyError):
    """An unknown glass name, or a glass catalog entry that cannot be used."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0]) if self.args else ""


class FocusError(NeuroLensError, ValueError):
    """A focus distance the lens cannot reach (nearer than its closest focus, or behind it)."""


class ApertureError(NeuroLensError, ValueError):
    """An aperture setting that cannot be used (f-number wider than the lens, bad blade count,
    unreadable mask image)."""


class ResourceError(NeuroLensError):
    """A render or an input that would need more memory than the machine has (or than the
    limit the user set), refused before it is allocated."""


class ModelError(NeuroLensError, ValueError):
    """A learned-lens model that cannot be used: unreadable or incomplete model.json, wrong
    shapes, ONNX files that are truncated, foreign or not the graph model.json describes, or a
    model trained for another lens. `path` is the offending file, `field` the key inside it."""

    def __init__(self, message: str, *, path: str | None = None, field: str | None = None):
        self.path = None if path is None else str(path)
        self.field = field
        where = [w for w in (self.path, f"field '{field}'" if field else None) if w]
        super().__init__((", ".join(where) + ": " if where else "") + message)


def debug_traceback() -> None:
    """Print the current exception's traceback only when NEUROLENS_TRACEBACK=1 is set: users
    get one line (a report, a panel message), developers can still see where it came from."""
    import os
    if os.environ.get("NEUROLENS_TRACEBACK") == "1":
        import traceback
        traceback.print_exc()


def run_command(main, prog: str) -> int:
    """Run a command-line `main()`: its own errors are one line already; what no check
    anticipated (a bug, memory running out) is one line too, naming the exception, with the
    traceback only when NEUROLENS_TRACEBACK=1 is set (to report it); output cut short by its
    reader (a pipe into `head`) ends quietly."""
    import os
    import sys
    try:
        return main()
    except BrokenPipeError:
        # the reader went away (`... --json | head`): nothing more to say, and nothing may be
        # flushed into the closed pipe on the way out; the status a SIGPIPE death gives
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except OSError:
            pass
        return 141
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"{prog}: error: out of memory (ask for less: fewer rays, a smaller frame)",
              file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence of a command
        if os.environ.get("NEUROLENS_TRACEBACK") == "1":
            raise
        text = " ".join(str(exc).split())[:300]
        print(f"{prog}: error: unexpected {type(exc).__name__}: {text} (rerun with "
              "NEUROLENS_TRACEBACK=1 to see where, and report it)", file=sys.stderr)
        return 70
