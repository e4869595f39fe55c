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


# --- issue 27: a nearly full disk, modes, links, special files, several files at once -------

DG = ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml"
posix_only = pytest.mark.skipif(os.name != "posix", reason="RLIMIT_FSIZE, FIFOs, modes: POSIX")


def _one_error_naming(proc, target: Path) -> str:
    """The one line on stderr (a command of neurolens_addon.core prints `error: ...`); it names
    the file asked for, not a temporary one; no traceback."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), proc.stderr
    assert str(target) in lines[0] and ".tmp" not in lines[0], lines[0]
    return lines[0]


@posix_only
@pytest.mark.parametrize("command,name,limit", [
    (("convert", DG), "lens.zmx", 512),
    (("diagram", DG), "lens.png", 4096),
])
def test_05_a_full_disk_leaves_the_old_file(tmp_path, command, name, limit):
    """`convert` and `diagram` with every file capped at a few hundred bytes (a nearly full
    disk, testdata.full_disk): the old file stays byte for byte, exit status 2, one line
    naming the file asked for (it used to name the vanished temporary file), no "wrote", no
    temporary file left."""
    from testdata.full_disk import hidden_files, run_with_file_limit
    target = tmp_path / name
    target.write_bytes(b"the good old file")
    p = run_with_file_limit(limit, "neurolens_addon.core", *command, "--out", target)
    assert p.returncode == 2, p.stderr
    _one_error_naming(p, target)
    assert "wrote" not in p.stdout + p.stderr
    assert target.read_bytes() == b"the good old file" and hidden_files(tmp_path) == []


def _real_files():
    """{suffix: bytes} of small real files: a PNG (the cross-section writer's), an OpenEXR
    (OpenEXR's own writer, ZIP as Blender writes it) and a .npy."""
    import io

    import numpy as np

    from neurolens_addon.core.crosssection import png_bytes
    rng = np.random.default_rng(1)
    out = {".png": png_bytes(rng.random((23, 31, 4)))}
    OpenEXR = pytest.importorskip("OpenEXR")
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        exr = Path(d) / "f.exr"
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"R": rng.random((40, 24)).astype("f"),
                      "Z": rng.random((40, 24)).astype("e")}).write(str(exr))
        out[".exr"] = exr.read_bytes()
    buf = io.BytesIO()
    np.save(buf, rng.random((50, 7)), allow_pickle=False)
    out[".npy"] = buf.getvalue()
    return out


@pytest.mark.parametrize("suffix", [".png", ".exr", ".npy"])
def test_06_a_writer_that_cuts_its_file_short_replaces_nothing(tmp_path, suffix):
    """A writer that returns normally with its file cut short (Blender's image writer on a
    full disk): the file is read back (core.filecheck) and refused with one line naming the
    target; the old file stays, no temporary file is left. The whole file then replaces it."""
    data = _real_files()[suffix]
    target = tmp_path / f"frame{suffix}"
    target.write_bytes(b"old frame")
    with pytest.raises(OSError, match="does not read back") as err:
        with atomic.atomic_path(target) as tmp:
            tmp.write_bytes(data[:len(data) * 2 // 3])
    assert str(target) in str(err.value) and "\n" not in str(err.value)
    assert target.read_bytes() == b"old frame" and leftovers(tmp_path) == []
    with atomic.atomic_path(target) as tmp:
        tmp.write_bytes(data)
    assert target.read_bytes() == data and leftovers(tmp_path) == []


def _exr_variants(tmp_path):
    """Real OpenEXR files of every layout the checker reads: scan lines in each codec and
    pixel type, a tiled image (edge tiles cut by the image), and a two-part file."""
    import numpy as np
    E = pytest.importorskip("OpenEXR")
    rng = np.random.default_rng(2)
    h, w = 37, 29
    tiles = E.TileDescription()
    tiles.xSize, tiles.ySize, tiles.mode, tiles.roundingMode = 8, 5, E.ONE_LEVEL, E.ROUND_DOWN
    files = []
    for codec in (E.NO_COMPRESSION, E.RLE_COMPRESSION, E.ZIPS_COMPRESSION, E.ZIP_COMPRESSION,
                  E.PIZ_COMPRESSION, E.DWAA_COMPRESSION):
        for dtype in ("f", "e", "I"):
            f = E.File({"compression": codec, "type": E.scanlineimage},
                       {"R": (rng.random((h, w)) * 50).astype(dtype),
                        "G": np.zeros((h, w), dtype)})
            files.append((f"{codec} {dtype}", f))
    for codec in (E.NO_COMPRESSION, E.ZIP_COMPRESSION, E.PIZ_COMPRESSION):
        files.append((f"tiled {codec}", E.File({"compression": codec, "type": E.tiledimage,
                                                "tiles": tiles},
                                               {"R": rng.random((h, w)).astype("f")})))
    files.append(("two parts", E.File([
        E.Part({"compression": E.ZIP_COMPRESSION, "type": E.scanlineimage},
               {"Z": rng.random((h, w)).astype("f")}, name="a"),
        E.Part({"compression": E.PIZ_COMPRESSION, "type": E.tiledimage, "tiles": tiles},
               {"Z": rng.random((h, w)).astype("f")}, name="b")])))
    out = []
    for name, f in files:
        path = tmp_path / "v.exr"
        f.write(str(path))
        out.append((name, path.read_bytes()))
    return out


def test_07_every_cut_of_a_real_image_is_refused(tmp_path):
    """core.filecheck on real files: whole PNGs (ours, matplotlib's) and OpenEXR files in
    every layout and codec are accepted with their size; every shorter prefix of them is
    refused, as is a PNG with one byte changed (its CRC, or zlib's check of the data)."""
    from neurolens_addon.core import filecheck
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.plots import lens_diagram
    lens_diagram(load_lens(DG), tmp_path / "plot.png", dpi=40)
    pngs = [("ours", _real_files()[".png"]),
            ("matplotlib", (tmp_path / "plot.png").read_bytes())]
    cases = [(n, ".png", d) for n, d in pngs] + [(n, ".exr", d) for n, d in
                                                  _exr_variants(tmp_path)]
    probe = tmp_path / "probe"
    for name, suffix, data in cases:
        probe.write_bytes(data)
        w, h = filecheck.check_file(probe, suffix)
        assert w > 0 and h > 0, name
        # cuts all through the file, and at every byte of its last 40 (the trailers), made
        # from the longest down by truncating the one copy
        step = max(1, len(data) // 100)
        for n in sorted({*range(0, len(data), step), *range(max(0, len(data) - 40),
                                                             len(data))}, reverse=True):
            os.truncate(probe, n)
            with pytest.raises(filecheck.FileCheckError):
                filecheck.check_file(probe, suffix)
    bent = bytearray(pngs[1][1])
    bent[len(bent) // 2] ^= 0x10
    probe.write_bytes(bytes(bent))
    with pytest.raises(filecheck.FileCheckError, match="CRC|corrupt"):
        filecheck.check_png(probe)


@posix_only
def test_08_outputs_keep_the_old_mode_or_get_the_umasks(tmp_path):
    """A replaced file keeps its mode (a 0644 frame stays readable to a farm's other users;
    mkstemp's 0600 used to replace it), a new one gets 0666 & ~umask, as open() gives it."""
    old_mask = os.umask(0o027)
    try:
        shared, private, new = tmp_path / "shared.png", tmp_path / "private.toml", \
            tmp_path / "new.toml"
        shared.write_bytes(b"x")
        os.chmod(shared, 0o644)
        private.write_bytes(b"x")
        os.chmod(private, 0o600)
        with atomic.atomic_path(shared) as tmp:
            tmp.write_bytes(_real_files()[".png"])
        atomic.atomic_write_text(private, "new")
        atomic.atomic_write_text(new, "new")
        modes = {p.name: oct(p.stat().st_mode & 0o777) for p in (shared, private, new)}
        assert modes == {"shared.png": "0o644", "private.toml": "0o600", "new.toml": "0o640"}
    finally:
        os.umask(old_mask)


@posix_only
def test_09_a_link_is_followed_to_its_target(tmp_path):
    """Writing through a symbolic link replaces the file it names (the link stays a link; it
    used to be replaced by a regular file); a dangling link gets its target created."""
    (tmp_path / "shots").mkdir()
    real = tmp_path / "shots" / "lens.toml"
    real.write_text("old")
    link = tmp_path / "lens.toml"
    link.symlink_to("shots/lens.toml")
    atomic.atomic_write_text(link, "new")
    assert link.is_symlink() and os.readlink(link) == "shots/lens.toml"
    assert real.read_text() == "new"
    dangling = tmp_path / "later.toml"
    dangling.symlink_to("shots/later.toml")
    atomic.atomic_write_text(dangling, "made")
    assert dangling.is_symlink() and (tmp_path / "shots" / "later.toml").read_text() == "made"
    assert leftovers(tmp_path) == [] and leftovers(tmp_path / "shots") == []


@posix_only
def test_10_a_fifo_device_socket_or_directory_is_refused(tmp_path):
    """An output that names a FIFO, a device (through a link), a socket or a directory is
    refused before anything is written, with one line naming it, and stays what it was
    (`convert --out FIFO` used to turn the FIFO into a regular file)."""
    import socket
    import stat

    from testdata.full_disk import run_with_file_limit
    fifo = tmp_path / "lens.zmx"
    os.mkfifo(fifo)
    p = run_with_file_limit(1 << 30, "neurolens_addon.core", "convert", DG, "--out", fifo)
    assert p.returncode == 2 and "a FIFO" in _one_error_naming(p, fifo), p.stderr
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    device = tmp_path / "null.toml"
    device.symlink_to(os.devnull)
    sock_path = tmp_path / "s.toml"
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(sock_path))
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    try:
        for path, kind in ((device, "a device"), (sock_path, "a socket"),
                           (folder, "a directory")):
            before = os.lstat(path).st_mode
            with pytest.raises(atomic.WriteError, match=kind) as err:
                atomic.atomic_write_text(path, "new")
            assert str(path) in str(err.value) and "\n" not in str(err.value)
            assert os.lstat(path).st_mode == before
    finally:
        sock.close()
    assert leftovers(tmp_path) == []


def test_11_several_files_are_replaced_all_or_none(tmp_path):
    """atomic_paths writes and checks every file before renaming any; when a rename fails
    (here the last target became a directory after the checks), the files already renamed
    are put back: the old ones with their bytes, a new one removed; no temporary file or
    backup is left. The same write then succeeds whole."""
    a, b, c = tmp_path / "a.toml", tmp_path / "b.toml", tmp_path / "c.toml"
    a.write_text("old a")
    c.write_text("old c")
    with pytest.raises(atomic.WriteError, match="c.toml") as err:
        with atomic.atomic_paths([a, b, c]) as tmps:
            for tmp, text in zip(tmps, ("new a", "new b", "new c")):
                tmp.write_text(text)
            c.unlink()                      # a rename that will fail: onto a full directory
            c.mkdir()
            (c / "keep").write_text("x")
    assert "nothing was replaced" in str(err.value)
    assert a.read_text() == "old a" and not b.exists() and c.is_dir()
    assert leftovers(tmp_path) == []
    (c / "keep").unlink()
    c.rmdir()
    with atomic.atomic_paths([a, b, c]) as tmps:
        for tmp, text in zip(tmps, ("new a", "new b", "new c")):
            tmp.write_text(text)
    assert [p.read_text() for p in (a, b, c)] == ["new a", "new b", "new c"]
    assert leftovers(tmp_path) == []
