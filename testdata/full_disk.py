"""A nearly full disk without root: run a command with a file-size limit.

`RLIMIT_FSIZE` caps the size any file the process writes may reach; with SIGXFSZ ignored a
write past the cap fails with EFBIG (or comes up short) as a write to a full disk fails with
ENOSPC, and each writer reacts as it would there: Python's file objects raise, Blender's image
writer logs an error and leaves a truncated file. The old file a command replaces and the
files it only reads are untouched by the cap. POSIX only (the tests that use it are skipped
elsewhere)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_RUNNER = """
import resource, runpy, signal, sys
limit = int(sys.argv[1])
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
sys.argv = [sys.argv[2]] + sys.argv[3:]
if sys.argv[0] == "-c":
    exec(compile(sys.argv[1], "<script>", "exec"), {"__name__": "__main__"})
else:
    runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
"""


def run_with_file_limit(limit: int, module: str, *args, timeout: float = 120.0,
                        umask: int | None = None) -> subprocess.CompletedProcess:
    """`python -m module args...` (or `python -c SCRIPT` for module "-c", args[0] the script)
    with every file it writes capped at `limit` bytes (and the umask `umask`, when given); its
    CompletedProcess (text output)."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}     # no .pyc cut short either
    return subprocess.run([sys.executable, "-c", _RUNNER, str(limit), module, *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env,
                          preexec_fn=None if umask is None else (lambda: os.umask(umask)))


def hidden_files(folder) -> list[str]:
    """The hidden files in `folder`: what a write left behind (temporaries, backups)."""
    return sorted(p.name for p in Path(folder).iterdir() if p.name.startswith("."))


def write_model_script(model_json, out) -> str:
    """A `python -c` script that writes the model described by `model_json` to `out` with
    trainer.pipeline.write_model, exit status 1 and the error's one line where it fails."""
    return (f"import json, sys\nfrom trainer.pipeline import write_model\n"
            f"meta = json.loads(open({str(model_json)!r}).read())\n"
            f"try:\n    write_model(meta, {str(out)!r})\n"
            f"except OSError as exc:\n    print(exc, file=sys.stderr)\n    sys.exit(1)\n")
