"""Training a scene model from Blender: `python -m trainer fit-scene ...` in its own process.

Blender does not ship torch, so the trainer never runs inside Blender: `trainer_command` builds
the command line (the Python and folder from the preferences, the lens file, the user's models
folder as the cache root, and the render settings as scene_needs_bpy reads them), having first
asked that Python whether it has torch (`trainer_python_problem`: Blender's own Python and the
add-on's Blender 5.2 environment, Python 3.13, do not; the preference "Trainer Python" then
names the project's Python 3.11 environment, .venv/bin/python), and
`TrainingJob` runs it, reading its output on a thread into a queue so that Blender's UI never
waits on it:

    job = TrainingJob(command.argv, command.cwd); job.start()
    ...  job.poll()  (non-blocking: new lines, progress 0..1, status text, state)
    job.cancel()     (SIGINT first, so the trainer unwinds and removes its temporary
                      directory; SIGTERM, then SIGKILL, if it has not exited after GRACE_S)
    job.wait()       (blocking, for scripts and background mode)

The trainer writes a model under a temporary name and renames it into place (neural.cache
counts a directory only once it holds a model.json), so a job cancelled while it trains adds
no model to the cache (what it leaves is NAME.neurolens.partial, the trainer's per-cell
checkpoints, from which the next run of the same job resumes). A job cancelled after the
trainer wrote the model (`job.written`; it is then being evaluated) keeps that model: the next
run finds it in the cache and evaluates it. Without SIGINT (Windows) the process is terminated
at once; a temporary directory it leaves (*.tmp) never counts as a model. The last line a successful job prints is JSON: {"model": path, "trained": bool,
"budget_um": x}, in `job.result`. One job runs at a time (`active_job()`): training uses every
core it gets.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import NeuroLensError

PENDING, RUNNING, FINISHED, FAILED, CANCELLED = (
    "pending", "running", "finished", "failed", "cancelled")
#: progress at each step the trainer announces (trainer.pipeline.fit_lens, trainer.scene)
MILESTONES = (("training a scene model", 0.03), ("[1/4]", 0.05), ("[2/4]", 0.10),
              ("[3/4]", 0.45), ("[4/4]", 0.80), ("wrote ", 0.85), ("scene model cached", 0.90))
EVALUATED = 0.98


class TrainingError(NeuroLensError):
    """A scene model cannot be trained from here (no trainer, no usable camera or lens)."""


#: asks a Python for its version and whether torch is importable, without importing torch
_PROBE = ("import importlib.util, sys; print('%d.%d' % sys.version_info[:2]); "
          "sys.exit(0 if importlib.util.find_spec('torch') else 3)")


def trainer_python_problem(python: str) -> str | None:
    """Why `python` cannot run the trainer (one line), or None. It is run once (a few tens of
    milliseconds): can it start, and does it have torch?"""
    try:
        proc = subprocess.run([python, "-c", _PROBE], capture_output=True, text=True,
                              timeout=60, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"the trainer's Python {python} cannot be run ({exc})"
    version = proc.stdout.strip() or "?"
    if proc.returncode == 3:
        return (f"training needs torch, which the trainer's Python ({version}, {python}) does "
                "not have: set Preferences > Add-ons > NeuroLens > Trainer Python to the "
                "project's Python 3.11 environment (.venv/bin/python in a checkout, made by "
                "'make venv')")
    if proc.returncode != 0:
        return f"the trainer's Python {python} does not run (exit status {proc.returncode})"
    return None


@dataclass(frozen=True)
class TrainingCommand:
    argv: list
    cwd: Path
    models_dir: Path
    needs: object            # core.scene_needs.RenderNeeds
    lens_name: str


def trainer_command(camera_obj, scene, *, rays: int | None = None,
                    max_depth: int | None = None) -> TrainingCommand:
    """The fit-scene command for `camera_obj` in `scene`. Raises TrainingError (no trainer
    folder, an unusable lens, a trainer Python without torch) or
    core.scene_needs.SceneNeedsError (settings with no image)."""
    from ..camera.lenses import load_lens_entry
    from ..camera.model_choice import region_needs
    from .camera_reader import lens_reference
    from .preferences import trainer_python, trainer_root, user_directory
    from .scene_needs_bpy import cli_arguments, render_needs

    if camera_obj is None or camera_obj.type != "CAMERA":
        raise TrainingError("no camera: select a camera object")
    try:
        _lens_id, path, _model, _dir = lens_reference(camera_obj, include_disabled=True)
        entry = load_lens_entry(path)
    except NeuroLensError as exc:
        raise TrainingError(f"no usable lens: {exc}") from None
    root = trainer_root()
    if root is None:
        raise TrainingError("the trainer is not installed with the add-on: set Preferences > "
                            "Add-ons > NeuroLens > Trainer Folder to a checkout of the "
                            "NeuroLens repository (the folder holding trainer/)")
    python = trainer_python()
    problem = trainer_python_problem(python)
    if problem is not None:
        raise TrainingError(problem)
    needs = region_needs(render_needs(scene, camera_obj), entry)
    models_dir = user_directory("models")
    argv = [python, "-u", "-m", "trainer", "fit-scene", entry.path,
            "--models-dir", str(models_dir), *cli_arguments(needs)]
    if rays is not None:
        argv += ["--rays", str(int(rays))]
    if max_depth is not None:
        argv += ["--max-depth", str(int(max_depth))]
    return TrainingCommand(argv, Path(root), Path(models_dir), needs, entry.name)


class TrainingJob:
    """One trainer process, read without blocking (see the module docstring)."""

    GRACE_S = 3.0

    def __init__(self, argv, cwd, *, label: str = "", env: dict | None = None, on_line=None):
        self.argv = [str(a) for a in argv]
        self.on_line = on_line           # called with each line as poll()/wait() take it
        self.cwd = str(cwd)
        self.label = label
        self.env = env
        self.lines: list[str] = []
        self.status = "starting the trainer"
        self.progress = 0.0
        self.state = PENDING
        self.result: dict | None = None
        self.written: str | None = None  # the model directory the trainer said it wrote
        self.error: str | None = None
        self.returncode: int | None = None
        self.started: float | None = None
        self._proc: subprocess.Popen | None = None
        self._queue: queue.Queue = queue.Queue()
        self._eof = False
        self._cancel_at: float | None = None
        self._signals = 0

    # -- running -----------------------------------------------------------------------------
    def start(self) -> TrainingJob:
        """Start the process (raises OSError when the Python cannot be run)."""
        env = dict(os.environ if self.env is None else self.env)
        env.update(PYTHONUNBUFFERED="1", PYTHONIOENCODING="utf-8")
        self._proc = subprocess.Popen(
            self.argv, cwd=self.cwd, env=env, stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, encoding="utf-8",
            errors="replace", bufsize=1)
        self.started = time.monotonic()
        self.state = RUNNING
        threading.Thread(target=self._read, args=(self._proc.stdout,), daemon=True,
                         name="neurolens-trainer-output").start()
        return self

    def _read(self, stream) -> None:
        try:
            for line in stream:
                self._queue.put(line.rstrip("\r\n"))
        except (OSError, ValueError):
            pass
        finally:
            self._queue.put(None)

    @property
    def running(self) -> bool:
        return self.state in (PENDING, RUNNING)

    @property
    def done(self) -> bool:
        return not self.running

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def poll(self) -> list[str]:
        """Take the lines printed since the last call (never blocks) and update progress,
        status and state."""
        new = []
        while True:
            try:
                line = self._queue.get_nowait()
            except queue.Empty:
                break
            if line is None:
                self._eof = True
                continue
            new.append(line)
            self._line(line)
        self._check()
        return new

    def wait(self, timeout: float | None = None) -> str:
        """Block until the job ends (or `timeout` seconds pass); returns the state."""
        end = None if timeout is None else time.monotonic() + timeout
        while self.running:
            if end is not None and time.monotonic() >= end:
                break
            try:
                line = self._queue.get(timeout=0.1)
            except queue.Empty:
                self._check()
                continue
            if line is None:
                self._eof = True
            else:
                self._line(line)
            self.poll()
        return self.state

    def cancel(self) -> None:
        """Ask the trainer to stop (see the module docstring); poll()/wait() finish it."""
        if not self.running:
            return
        if self._proc is None:
            self.state = CANCELLED
            return
        if self._cancel_at is None:
            self._cancel_at = time.monotonic()
            self.status = "cancelling"
            self._signal()
        self._check()

    def _signal(self) -> None:
        proc = self._proc
        if proc is None or proc.poll() is not None:
            return
        try:
            if self._signals == 0 and os.name == "posix":
                proc.send_signal(signal.SIGINT)
            elif self._signals <= 1:
                proc.terminate()
            else:
                proc.kill()
        except OSError:
            pass
        self._signals += 1

    def _check(self) -> None:
        proc = self._proc
        if proc is None or not self.running:
            return
        rc = proc.poll()
        if rc is None:
            if self._cancel_at is not None:
                waited = time.monotonic() - self._cancel_at
                if waited > self.GRACE_S * self._signals:
                    self._signal()
            return
        if not self._eof and self._cancel_at is None:
            return              # exited: its last lines are still on their way
        self.returncode = rc
        if self._cancel_at is not None:
            self.state, self.status = CANCELLED, "cancelled"
        elif rc == 0 and self.result is not None:
            self.state, self.progress = FINISHED, 1.0
            self.status = "finished"
        else:
            self.state = FAILED
            errors = [ln for ln in self.lines if ln.startswith("error:")]
            tail = errors[-1:] or [ln for ln in self.lines if ln.strip()][-3:]
            self.error = (" / ".join(t.strip() for t in tail) or "no output") + \
                f" (exit status {rc})"
            self.status = "failed"

    def _line(self, line: str) -> None:
        if self.on_line is not None:
            self.on_line(line)
        self.lines.append(line)
        if len(self.lines) > 2000:
            del self.lines[:1000]
        text = line.strip()
        if not text:
            return
        if text.startswith("{"):
            try:
                data = json.loads(text)
            except ValueError:
                data = None
            if isinstance(data, dict) and "model" in data:
                self.result = data
                self.progress = 1.0
                return
        if text.startswith("wrote ") and " in " in text:
            self.written = text[len("wrote "):].rsplit(" in ", 1)[0]
        for marker, value in MILESTONES:
            if text.startswith(marker):
                self.progress = max(self.progress, value)
                break
        else:
            if text.startswith("scene model ") and "image error" in text:
                self.progress = max(self.progress, EVALUATED)
            elif text.startswith("cell "):       # a kd-tree cell: creep towards the next step
                nxt = min((v for _m, v in MILESTONES if v > self.progress), default=EVALUATED)
                self.progress += 0.25 * (nxt - self.progress)
        self.status = text[:120]

    def elapsed_s(self) -> float:
        return 0.0 if self.started is None else time.monotonic() - self.started


_ACTIVE: list = []       # [TrainingJob] while one runs (one at a time)


def active_job() -> TrainingJob | None:
    """The job started from Blender that has not ended yet (None when none)."""
    if _ACTIVE and _ACTIVE[0].running:
        return _ACTIVE[0]
    return None


def set_active(job: TrainingJob | None) -> None:
    _ACTIVE.clear()
    if job is not None:
        _ACTIVE.append(job)


def cancel_all() -> None:
    """Cancel and reap the running job (unregister, Blender quitting)."""
    for job in _ACTIVE:
        job.cancel()
        job.wait(timeout=3 * TrainingJob.GRACE_S + 1.0)
    _ACTIVE.clear()


__all__ = ["CANCELLED", "FAILED", "FINISHED", "RUNNING", "TrainingCommand", "TrainingError",
           "TrainingJob", "active_job", "cancel_all", "set_active", "trainer_command"]
