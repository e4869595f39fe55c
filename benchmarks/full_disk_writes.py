"""Writes on a nearly full disk (issue 27): does any writer lose the file it replaces?

Every command that writes a user's file (lens conversion to .toml and .zmx, the cross-section
diagram and spot diagram PNGs, engine frames as PNG, EXR and both at once, a trace's .npy, a
learned model's directory) runs with every file it writes capped at each of CAPS bytes
(testdata.full_disk: RLIMIT_FSIZE, a write past it fails as on a full disk), over an old file
holding known bytes. A case is:
  * written: exit 0 and every output complete (it reads back: core.filecheck), or
  * refused cleanly: a non-zero exit, one error line, no traceback, every old file byte for
    byte and no temporary file left;
anything else is counted: a traceback, a hang (no exit within HANG_S), a lost file (an old
file changed without a complete new one in its place, or a temporary file left behind).
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path

from .common import ROOT

#: bytes a file may reach; the last is no cap at all (every writer must then write)
CAPS = (0, 100, 1024, 4096, 16384, 65536, 1 << 30)
HANG_S = 300.0
DG = ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml"
DEMO = ROOT / "presets" / "scenes" / "demo.blend"
SINGLET = ROOT / "presets" / "lenses" / "biconvex_singlet.toml"
SINGLET_MODEL = ROOT / "presets" / "models" / "biconvex_singlet.neurolens"
OLD = b"the good old file"
FRAME = ("--lens", "double_gauss_50mm_f2", "--samples", "1", "--resolution", "64x36",
         "--engine", "neurolens", "--quiet")


def _cases():
    """(name, module, arguments before the outputs, output names, output option)."""
    return [
        ("convert .toml", "neurolens_addon.core", ("convert", DG), ["lens.toml"], "--out"),
        ("convert .zmx", "neurolens_addon.core", ("convert", DG), ["lens.zmx"], "--out"),
        ("diagram .png", "neurolens_addon.core", ("diagram", DG), ["lens.png"], "--out"),
        ("spot .png", "neurolens_addon.core", ("spot", DG), ["spot.png"], "--out"),
        ("render .png", "neurolens_addon.render", (DEMO, *FRAME), ["frame.png"], "--out"),
        ("render .exr", "neurolens_addon.render", (DEMO, *FRAME), ["frame.exr"], "--out"),
        ("render .png + .exr", "neurolens_addon.render", (DEMO, *FRAME),
         ["frame.png", "frame.exr"], "--out"),
    ]


def _model_case(limit: int, folder: Path):
    """trainer.pipeline.write_model over an old model directory."""
    import shutil

    from testdata.full_disk import run_with_file_limit, write_model_script
    out = folder / "x.neurolens"
    shutil.copytree(SINGLET_MODEL, out)
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    script = write_model_script(SINGLET_MODEL / "model.json", out)
    proc = run_with_file_limit(limit, "-c", script, timeout=HANG_S)
    after = {f.name: f.read_bytes() for f in out.iterdir()} if out.is_dir() else {}
    if proc.returncode == 0:
        from neurolens_addon.core.lensfile import load_lens
        from neurolens_addon.neural.model import LearnedLens
        try:
            LearnedLens.load(out, lens=load_lens(SINGLET))
            complete = True
        except Exception:  # noqa: BLE001 - any failure to load is a lost model
            complete = False
    else:
        complete = after == before
    leftovers = sorted(p.name for p in folder.iterdir() if p.name != "x.neurolens")
    return proc, complete and not leftovers, [str(out)]


def _judge(proc, outs, olds_kept: bool, complete: bool, hidden: list[str]) -> str:
    text = proc.stdout + proc.stderr
    if "Traceback" in text:
        return "traceback"
    if proc.returncode == 0:
        return "written" if complete and not hidden else "lost"
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln.lower()
              and not ln.startswith(("Error: ", "ERROR "))]        # Blender's own log lines
    if not olds_kept or hidden:
        return "lost"
    return "refused" if errors else "refused without a line"


def run_cases(caps=CAPS) -> dict:
    from neurolens_addon.core.filecheck import check_file
    from neurolens_addon.core.lensfile import load_lens
    from testdata.full_disk import hidden_files, run_with_file_limit
    counts = {"cases": 0, "written": 0, "refused": 0, "refused without a line": 0,
              "traceback": 0, "hang": 0, "lost": 0}
    rows = []
    for limit in caps:
        for name, module, args, names, opt in _cases():
            with tempfile.TemporaryDirectory() as d:
                folder = Path(d)
                outs = [folder / n for n in names]
                for o in outs:
                    o.write_bytes(OLD)
                try:
                    proc = run_with_file_limit(limit, module, *args,
                                               *[a for o in outs for a in (opt, o)],
                                               timeout=HANG_S)
                except subprocess.TimeoutExpired:
                    verdict = "hang"
                else:
                    kept = all(o.read_bytes() == OLD for o in outs)
                    complete = True
                    for o in outs:
                        try:
                            if o.suffix in (".toml", ".zmx"):
                                load_lens(o)            # a lens file is complete if it loads
                            else:
                                check_file(o)
                        except Exception:  # noqa: BLE001 - the check's refusal is the answer
                            complete = False
                    verdict = _judge(proc, outs, kept, complete, hidden_files(folder))
            counts["cases"] += 1
            counts[verdict] += 1
            rows.append((name, limit, verdict))
            print(f"  full disk: {name} at {limit} B: {verdict}", flush=True)
        with tempfile.TemporaryDirectory() as d:
            try:
                proc, ok, _outs = _model_case(limit, Path(d))
            except subprocess.TimeoutExpired:
                verdict = "hang"
            else:
                verdict = ("traceback" if "Traceback" in proc.stderr else
                           ("written" if proc.returncode == 0 else "refused") if ok else "lost")
        counts["cases"] += 1
        counts[verdict] += 1
        rows.append(("model directory", limit, verdict))
        print(f"  full disk: model directory at {limit} B: {verdict}", flush=True)
    counts["rows"] = rows
    return counts


if __name__ == "__main__":
    print(json.dumps({k: v for k, v in run_cases().items() if k != "rows"}, indent=1))
