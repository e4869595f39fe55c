"""`python -m neurolens_addon.render`: clear one-line errors for a missing file, camera or lens,
and a real headless render of the shipped demo scene to EXR and PNG (what `make demo` runs)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow          # renders from the command line

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "presets" / "scenes" / "demo.blend"


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "neurolens_addon.render", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout)


def one_error_line(proc) -> str:
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("neurolens.render: error:")]
    assert len(errors) == 1, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    return errors[0]


def test_17_missing_scene_file_is_one_clear_error(tmp_path):
    """A .blend that does not exist: exit status 2 and one line naming the file."""
    p = cli(tmp_path / "nope.blend", "--lens", "double_gauss_50mm_f2", "--out",
            tmp_path / "o.exr")
    assert p.returncode == 2
    assert "nope.blend: no such file" in one_error_line(p)


def test_18_scene_without_a_camera_is_one_clear_error(tmp_path):
    """A scene with no active camera: exit status 2 and one line saying so."""
    bpy = pytest.importorskip("bpy")
    from testdata import engine_scenes as scenes
    scenes.reset()
    bpy.ops.mesh.primitive_cube_add()
    path = tmp_path / "nocam.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    p = cli(path, "--lens", "double_gauss_50mm_f2", "--out", tmp_path / "o.exr")
    assert p.returncode == 2
    assert "has no active camera" in one_error_line(p)


def test_19_unknown_lens_is_one_clear_error(tmp_path):
    """A lens that is neither a preset nor a file: exit status 2, one line listing presets."""
    p = cli(DEMO, "--lens", "no_such_lens", "--out", tmp_path / "o.exr")
    assert p.returncode == 2
    line = one_error_line(p)
    assert "lens 'no_such_lens' not found" in line and "double_gauss_50mm_f2" in line


def test_20_cli_renders_the_demo_scene_to_exr_and_png(tmp_path):
    """The demo scene through the learned double Gauss, headless: exit status 0, a progress
    bar on stderr, a multilayer EXR with every pass and a PNG, both from Blender's writer;
    --pass adds the data passes (the demo scene stands still: its vectors are 0)."""
    from testdata.engine_scenes import read_exr
    exr, png = tmp_path / "demo.exr", tmp_path / "demo.png"
    p = cli(DEMO, "--lens", "double_gauss_50mm_f2", "--focus", "1.6", "--fstop", "2",
            "--samples", "2", "--resolution", "96x54", "--engine", "neurolens", "--out", exr,
            "--out", png, "--pass", "vector", "--pass", "position", "--pass", "uv")
    assert p.returncode == 0, p.stderr
    assert "100.0%" in p.stderr and "samples/s" in p.stderr
    ch = read_exr(exr)
    for name in ("Combined.R", "Depth.Z", "Normal.X", "Vignetting.X", "Lens Uncertainty.X",
                 "Vector.X", "Vector.W", "Position.Z", "UV.U", "UV.A"):
        assert name in ch and ch[name].shape == (54, 96)
    assert np.abs(ch["Vector.X"]).max() < 1e-3 and np.ptp(ch["Position.Z"]) > 0.1
    assert ch["Combined.G"].mean() > 0.01
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_24_a_stopped_render_leaves_the_old_output(tmp_path):
    """SIGTERM while the engine renders: the command stops at its next bundle, exits with 143,
    says nothing was written, and the frame already at --out is unchanged (no temporary
    file is left beside it)."""
    import signal
    import time
    out = tmp_path / "frame.exr"
    out.write_bytes(b"the previous frame")
    proc = subprocess.Popen([sys.executable, "-m", "neurolens_addon.render", str(DEMO),
                             "--lens", "double_gauss_50mm_f2", "--samples", "64",
                             "--resolution", "320x180", "--engine", "neurolens",
                             "--out", str(out)], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    seen = ""
    t0 = time.time()
    while "Sample" not in seen and "%" not in seen and time.time() - t0 < 120:
        seen += proc.stderr.read(1)
    proc.send_signal(signal.SIGTERM)
    err = seen + proc.stderr.read()
    assert proc.wait(timeout=120) == 128 + signal.SIGTERM, err
    assert "nothing written" in err and "Traceback" not in err
    assert out.read_bytes() == b"the previous frame"
    assert [p.name for p in tmp_path.iterdir()] == ["frame.exr"]


@pytest.mark.parametrize("args,match", [
    (("--samples", "2147483648"), "--samples"),
    (("--seed", "-1"), "--seed"),
    (("--bounces", "99999999999"), "--bounces"),
    (("--percentage", "1000000"), "--percentage"),
    (("--resolution", "100000x100000"), "at most 65536 pixels a side"),
    (("--fstop", "inf"), "--fstop"),
    (("--fstop", "1e30"), "--fstop"),
    (("--ghosts", "--ghost-intensity", "inf"), "--ghost-intensity"),
    (("--ghosts", "--ghost-intensity", "1e30"), "--ghost-intensity"),
])
def test_25_numbers_out_of_range_are_one_line(tmp_path, args, match):
    """Integers of 2^31 and more, negative seeds, 1 000 000 %, 100 000 x 100 000 pixels, an
    infinite f-number or ghost intensity (Blender stores them as 3.4e38, which passed every
    finiteness check: issue 27): exit status 2 and one line naming the option, before
    anything is allocated."""
    p = cli(DEMO, "--lens", "double_gauss_50mm_f2", *args, "--out", tmp_path / "o.exr")
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr and match in p.stderr
    assert not (tmp_path / "o.exr").exists()


def _cycles_args(tmp_path, *more):
    return (DEMO, "--lens", "double_gauss_50mm_f2", "--model", "exact", "--focus", "1.6",
            "--fstop", "16", "--samples", "20", "--resolution", "96x54", "--engine", "cycles",
            "--no-denoise", "--seed", "3", *more)


def _point_light_scene(tmp_path):
    """testdata's far lights seen by a camera with a 2 mm sensor (31 um pixels at 64 px: a
    diffraction pattern spans pixels) and lights shrunk to a fifth of a pixel: the middle one
    is a point in the frame."""
    bpy = pytest.importorskip("bpy")
    from testdata import agreement_scenes
    blend = agreement_scenes.write("far_lights", tmp_path)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    sc = bpy.context.scene
    sc.camera.data.sensor_width = 2.0
    for ob in sc.objects:
        if ob.type == "MESH":
            ob.scale = (0.02, 0.02, 0.02)
    em = bpy.data.materials["glow"].node_tree.nodes["Emission"].inputs["Strength"]
    em.default_value /= 0.02 ** 2
    out = tmp_path / "point.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out), copy=True)
    return out


def test_26_cycles_draws_starbursts_from_the_command_line(tmp_path):
    """`--diffraction` with the README's `--lens PRESET` (a camera without the Real Lens
    panel) gives Cycles' starbursts: a point light at f/16 spreads its light beyond 6 pixels
    (at least 10x the render without), the frame's light within 5 % (the add-on's handler
    used to remove the compositor the command line had set up: identical frames)."""
    from testdata.engine_scenes import read_exr
    from testdata.starburst import far_light
    blend = _point_light_scene(tmp_path)
    lum = {}
    for flag in ("--diffraction", "--no-diffraction"):
        out = tmp_path / f"{flag}.exr"
        p = cli(blend, "--lens", "double_gauss_50mm_f2", "--model", "exact", "--focus", "40",
                "--fstop", "16", "--samples", "16", "--resolution", "64x40", "--engine",
                "cycles", "--no-denoise", "--no-dispersion", flag, "--quiet", "--out", out,
                timeout=300)
        assert p.returncode == 0, p.stderr
        ch = read_exr(out)
        # the compositor's output (Cycles convolves there); the view layer's is the raw image
        lum[flag] = sum(w * ch.get(f"Composite.Combined.{c}", ch[f"Combined.{c}"])
                        for w, c in zip((0.2126, 0.7152, 0.0722), "RGB"))
    on, off = lum["--diffraction"], lum["--no-diffraction"]
    assert far_light(on) > 10.0 * far_light(off) and far_light(on) > 1e-3 * on.sum()
    assert on.sum() == pytest.approx(off.sum(), rel=0.05)


def test_27_a_cycles_render_shows_its_progress(tmp_path):
    """Cycles from the command line (stderr not a terminal): progress lines as it renders (a
    line per 10 % of its tiles and samples), not one line at the end."""
    p = cli(*_cycles_args(tmp_path, "--resolution", "320x180", "--out", tmp_path / "c.exr"),
            timeout=300)
    assert p.returncode == 0, p.stderr
    shown = {int(float(m)) for m in re.findall(r"\] +([0-9.]+)% ", p.stderr)}
    assert len([v for v in shown if 0 < v < 100]) >= 3, p.stderr


def test_28_the_engine_says_each_note_once(tmp_path):
    """Every note of the set-up is printed once by the command line ("note: ..."), not again
    as Blender's "Warning: ..." of the engine's report."""
    p = cli(DEMO, "--lens", "double_gauss_50mm_f2", "--model", "exact", "--focus", "0.01",
            "--samples", "1", "--resolution", "32x18", "--engine", "neurolens", "--quiet",
            "--out", tmp_path / "o.exr")
    assert p.returncode == 0, p.stderr
    text = p.stdout + p.stderr
    assert text.count("focuses no closer than") == 1, text


# --- issue 27: a nearly full disk; modes, links and outputs that cannot be written ----------

TINY = ("--lens", "double_gauss_50mm_f2", "--samples", "1", "--resolution", "32x18",
        "--engine", "neurolens", "--quiet")


@pytest.mark.parametrize("limit,suffixes", [(1024, (".png",)), (8192, (".png", ".exr"))])
def test_29_a_full_disk_leaves_the_old_frames(tmp_path, limit, suffixes):
    """The render with every file capped at a few KB (a nearly full disk: testdata.full_disk;
    Blender's image writer then logs an error and leaves a truncated file without raising):
    exit status 1, one line naming the output that did not read back, no "wrote", every old
    frame byte for byte and no temporary file. With a PNG that fits and an EXR that does not,
    neither is replaced (it used to print "wrote" twice and exit 0: a new PNG beside a
    truncated EXR)."""
    from testdata.full_disk import hidden_files, run_with_file_limit
    outs = [tmp_path / f"frame{s}" for s in suffixes]
    for o in outs:
        o.write_bytes(b"the good old " + o.suffix.encode())
    p = run_with_file_limit(limit, "neurolens_addon.render", DEMO, *TINY,
                            *[a for o in outs for a in ("--out", o)])
    assert p.returncode == 1, p.stderr
    line = one_error_line(p)
    assert str(outs[-1]) in line and "does not read back" in line and ".tmp" not in line
    assert "wrote" not in p.stderr + p.stdout
    for o in outs:
        assert o.read_bytes() == b"the good old " + o.suffix.encode()
    assert hidden_files(tmp_path) == []


def test_30_frames_keep_their_mode_and_links(tmp_path):
    """A 0644 frame replaced through a symbolic link: the link stays a link, the frame it names
    is the new PNG and still 0644; a new EXR gets 0666 & ~umask (mkstemp's 0600 used to stay,
    and the link used to become a regular file)."""
    from testdata.full_disk import run_with_file_limit
    (tmp_path / "shots").mkdir()
    frame = tmp_path / "shots" / "frame.png"
    frame.write_bytes(b"old")
    os.chmod(frame, 0o644)
    link = tmp_path / "latest.png"
    link.symlink_to(frame)
    p = run_with_file_limit(1 << 30, "neurolens_addon.render", DEMO, *TINY, "--out", link,
                            "--out", tmp_path / "new.exr", umask=0o022)
    assert p.returncode == 0, p.stderr
    assert link.is_symlink() and os.readlink(link) == str(frame)
    assert frame.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert oct(frame.stat().st_mode & 0o777) == "0o644"
    assert oct((tmp_path / "new.exr").stat().st_mode & 0o777) == "0o644"


@pytest.mark.parametrize("kind", ["directory", "fifo", "socket", "same file twice"])
def test_31_an_out_that_cannot_be_written_is_refused_before_the_render(tmp_path, kind):
    """--out naming a directory, a FIFO, a socket, or one file twice (the second time through
    a link): exit status 2 and one line naming it before the scene is rendered (no progress,
    no samples/s); the FIFO or socket stays what it was (a directory used to be found only
    after the whole render, a FIFO or socket turned into a regular file)."""
    import socket
    good = tmp_path / "good.exr"
    bad = tmp_path / "bad.png"
    sock = None
    if kind == "directory":
        bad.mkdir()
    elif kind == "fifo":
        os.mkfifo(bad)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(bad))
    else:
        bad = tmp_path / "again.exr"
        bad.symlink_to(good)
    before = os.lstat(bad).st_mode
    try:
        p = cli(DEMO, *TINY[:-1], "--out", good, "--out", bad)
    finally:
        if sock is not None:
            sock.close()
    assert p.returncode == 2, p.stderr
    assert str(bad) in one_error_line(p)
    assert "samples/s" not in p.stderr and "%" not in p.stderr and not good.exists()
    assert os.lstat(bad).st_mode == before
