"""Peak memory of large frames and large aperture masks (issue 27, item 7).

Each figure is the resident-set high-water mark (ru_maxrss, from os.wait4 on the one child
process) of a fresh process:
* renders: `python -m neurolens_addon.render presets/scenes/demo.blend --lens
  double_gauss_50mm_f2 --model exact --samples 1 --resolution WxH --out frame.png` at
  3840 x 2160 (4K) and 7680 x 4320 (8K), the engine's defaults otherwise (dispersion, three
  colour rays a sample, Open Image Denoise on, the scene's one bounce); next to each, the
  engine's own estimate of what the render adds (engine.memory.estimate) and a 64 x 36 render
  of the same scene (the process without the frame);
* masks: an 8192 x 8192 RGBA PNG (a disc) read as an aperture mask through the core
  (core.aperture ImageMaskAperture(load_mask_image(path))) and through Blender
  (bpy.data.images.load, then blender.camera_reader.mask_aperture, as the panel does); the
  figure is the rise of the child's high-water mark over its resident set just before
  loading (the modules imported), so it counts only the mask.
"Before" figures come from the code of another checkout (the tree before this change, e.g.
`git archive 5e4b185 | tar -x -C /tmp/nl-before`) run with the same interpreter: set
NEUROLENS_BENCH_BEFORE=/tmp/nl-before; without it the kept "before" figures of the last run
(docs/bench/memory_peak.json) are shown again, with their date. Runs are sequential (an 8K
frame takes minutes).

    python -m benchmarks.run memory_peak
"""

from __future__ import annotations

import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import ROOT, md_table

FRAMES = (("4K", 3840, 2160), ("8K", 7680, 4320))
SMALL = (64, 36)
MASK_SIDE = 8192
GB = 1e9

_MASK_CHILD = r"""
import json, sys
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
way, path = sys.argv[1], sys.argv[2]
if way == "core":
    from neurolens_addon.core.aperture import ImageMaskAperture, load_mask_image
    before = status("VmRSS")
    ap = ImageMaskAperture(load_mask_image(path), source=path)
else:
    import bpy
    from neurolens_addon.blender.camera_reader import mask_aperture
    image = bpy.data.images.load(path)
    before = status("VmRSS")
    ap, _key = mask_aperture(image)
print(json.dumps({"before": before, "hwm": status("VmHWM"), "shape": list(ap.mask.shape),
                  "area": ap.area()}))
"""


def _run_child(cmd, cwd) -> tuple[int, str, int]:
    """(exit status, output, peak RSS in bytes) of one child process."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", PYTHONPATH=str(cwd))
    with tempfile.TemporaryFile() as out:
        p = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
        _pid, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read().decode("utf-8", "replace")
    kib = usage.ru_maxrss          # Linux: kibibytes
    return p.returncode, text, kib * 1024


def render_peak(root: Path, width: int, height: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "neurolens_addon.render",
               str(root / "presets" / "scenes" / "demo.blend"), "--lens",
               "double_gauss_50mm_f2", "--model", "exact", "--samples", "1",
               "--resolution", f"{width}x{height}", "--quiet", "--out",
               str(Path(tmp) / "frame.png")]
        rc, text, peak = _run_child(cmd, root)
    last = [ln for ln in text.splitlines() if ln.strip()][-3:]
    return {"rc": rc, "peak_bytes": peak, "tail": " | ".join(last)[-400:]}


def write_mask(path: Path, side: int = MASK_SIDE) -> None:
    """An RGBA PNG of side^2 pixels: an opaque white disc of radius 0.45 side."""
    from testdata.mask_images import write_disc_png
    write_disc_png(path, side)


def mask_peak(root: Path, path: Path, way: str) -> dict:
    rc, text, _peak = _run_child([sys.executable, "-c", _MASK_CHILD, way, str(path)], root)
    line = next((ln for ln in reversed(text.splitlines()) if ln.startswith("{")), None)
    if rc != 0 or line is None:
        return {"rc": rc, "error": text.strip().splitlines()[-1][-300:] if text.strip() else ""}
    d = json.loads(line)
    return {"rc": rc, "rise_bytes": d["hwm"] - d["before"], "shape": d["shape"]}


def estimates() -> dict:
    """This code's estimate of each render (engine.memory, the settings the command uses)."""
    from neurolens_addon.engine import memory
    from neurolens_addon.engine.settings import RenderSettings
    s = RenderSettings(samples=1)
    out = {}
    for name, w, h in FRAMES:
        streamed = memory.streamed_film(w, h, s, 3)
        e = memory.estimate(w, h, s, rays_per_sample=3, workers=os.cpu_count() or 1,
                            streamed=streamed, denoise=True)
        out[name] = {"bytes": e.total, "parts": e.parts, "streamed": streamed}
    return out


def measure(root: Path) -> dict:
    figs = {"renders": {}, "masks": {}}
    small = render_peak(root, *SMALL)
    figs["renders"]["small"] = small
    print(f"[memory_peak] {root}: {SMALL[0]}x{SMALL[1]} {small['peak_bytes'] / GB:.2f} GB",
          flush=True)
    for name, w, h in FRAMES:
        r = render_peak(root, w, h)
        figs["renders"][name] = r
        print(f"[memory_peak] {root}: {name} {r['peak_bytes'] / GB:.2f} GB (rc {r['rc']})",
              flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        mask = Path(tmp) / "mask8192.png"
        write_mask(mask)
        for way in ("core", "blender"):
            figs["masks"][way] = mask_peak(root, mask, way)
            print(f"[memory_peak] {root}: mask via {way}: {figs['masks'][way]}", flush=True)
    return figs


def _commit(root: Path) -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                              capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _gb(b) -> str:
    return "-" if b is None else f"{b / GB:.2f}"


def run():
    before_root = os.environ.get("NEUROLENS_BENCH_BEFORE")
    kept = ROOT / "docs" / "bench" / "memory_peak.json"
    if before_root:
        before = measure(Path(before_root))
        before["measured"] = datetime.date.today().isoformat()
        before["source"] = os.environ.get("NEUROLENS_BENCH_BEFORE_LABEL", before_root)
    else:
        try:
            before = json.loads(kept.read_text(encoding="utf-8"))["before"]
        except (OSError, ValueError, KeyError):
            before = None
    after = measure(ROOT)
    after["estimates"] = estimates()
    after["source"] = _commit(ROOT) or "this tree"
    figs = {"before": before, "after": after}

    def r(side, name, key="peak_bytes"):
        d = (side or {}).get("renders", {}).get(name) or {}
        return d.get(key) if d.get("rc") == 0 else None

    rows = []
    for label, w, h in ((f"{SMALL[0]} x {SMALL[1]} (the process)", *SMALL),
                        *((f"{n} {w} x {h}", w, h) for n, w, h in FRAMES)):
        name = "small" if (w, h) == SMALL else label.split()[0]
        est = after["estimates"].get(name, {}).get("bytes") if name != "small" else None
        rows.append((label, _gb(r(before, name)), _gb(r(after, name)),
                     "-" if est is None else f"{est / GB:.2f}"))
    mask_rows = []
    for way, what in (("core", "core: ImageMaskAperture(load_mask_image(png))"),
                      ("blender", "Blender: images.load + mask_aperture")):
        b = ((before or {}).get("masks") or {}).get(way) or {}
        a = after["masks"].get(way) or {}
        mask_rows.append((what, _gb(b.get("rise_bytes")), _gb(a.get("rise_bytes")),
                          "x".join(map(str, a.get("shape", []))) or "-"))
    est8 = after["estimates"]["8K"]
    parts = ", ".join(f"{k} {v / GB:.2f}" for k, v in est8["parts"].items() if v)
    when = (f"before: {before.get('source', '?')}, measured {before.get('measured', '?')}"
            if before else "before: not measured")
    text = "\n".join([
        "## Peak memory of large frames and masks",
        "",
        "Resident-set high-water mark of one process (`ru_maxrss` of the child): the command "
        "line rendering `presets/scenes/demo.blend` through the exact double Gauss at 1 sample "
        "a pixel to a PNG (the engine's defaults: dispersion with three colour rays a sample, "
        "Open Image Denoise, one bounce), and the rise of the high-water mark while an "
        "8192 x 8192 RGBA PNG is read as an aperture mask. The estimate is what "
        "`engine.memory.estimate` says the render adds to the process (the 64 x 36 row: the "
        f"process without the frame). {when}; after: {after['source']}.",
        "",
        md_table(("render", "before (GB)", "after (GB)", "estimate added (GB)"), rows),
        "",
        f"8K estimate by part (GB): {parts}; the film is "
        f"{'streamed (tile by tile)' if est8['streamed'] else 'frame-sized'}.",
        "",
        md_table(("8192 x 8192 mask read by", "before (GB)", "after (GB)", "mask kept"),
                 mask_rows),
        "",
        "Reproduce: `git archive 5e4b185 | (mkdir -p /tmp/nl-before && tar -x -C "
        "/tmp/nl-before)`, then `NEUROLENS_BENCH_BEFORE=/tmp/nl-before python -m "
        "benchmarks.run memory_peak` (without the variable the kept before figures are "
        "reused).",
    ])
    return text, figs


if __name__ == "__main__":
    t, _f = run()
    print(t)
