"""`python -m neurolens_addon.core`: info, index, trace, diagram and spot, run as a user would."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DG = ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml"


def cli(*args, check=True):
    proc = subprocess.run([sys.executable, "-m", "neurolens_addon.core", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_01_info_json_has_first_order_data_and_surfaces():
    """`info --json` reports EFL, BFD, f-number, both pupils and one row per surface with the
    fields the issue names (radius null when flat, n_d 1.0 for air, one stop)."""
    info = json.loads(cli("info", DG, "--json").stdout)
    for key in ("name", "efl_mm", "bfd_mm", "f_number", "entrance_pupil", "exit_pupil", "surfaces"):
        assert key in info
    assert info["efl_mm"] == pytest.approx(info["designed"]["focal_length_mm"], rel=0.02)
    assert set(info["entrance_pupil"]) == {"z_mm", "diameter_mm"}
    rows = info["surfaces"]
    assert sum(r["stop"] for r in rows) == 1
    for r in rows:
        assert set(r) >= {"radius_mm", "thickness_mm", "n_d", "semi_diameter_mm", "conic", "stop"}
        if r["material"] == "air":
            assert r["n_d"] == 1.0
        else:
            assert r["n_d"] > 1.3
    assert any(r["radius_mm"] is None for r in rows)        # the flat stop


def test_02_index_of_a_catalog_glass():
    """`index N-BK7 587.5618` prints the catalogue n_d 1.5168 to 4 decimals."""
    out = cli("index", "N-BK7", 587.5618).stdout.strip()
    assert float(out) == pytest.approx(1.5168, abs=1e-4)


def test_03_trace_round_trip_through_files(tmp_path):
    """`trace` reads N x 7 rays and writes N x 8 with a validity column; scene rays parallel to
    the axis land near the focus, a NaN ray is flagged and comes back finite."""
    rays = np.zeros((4, 7))
    rays[:, 0] = [0.0, 1.0, -2.0, np.nan]
    rays[:, 2] = 200.0
    rays[:, 5] = -1.0
    rays[:, 6] = 587.5618
    src, dst = tmp_path / "in.npy", tmp_path / "out.npy"
    np.save(src, rays)
    cli("trace", DG, "--in", src, "--out", dst, "--from", "scene")
    out = np.load(dst)
    assert out.shape == (4, 8)
    assert out[:, 7].tolist() == [1.0, 1.0, 1.0, 0.0]
    assert np.isfinite(out).all()
    assert np.abs(out[:3, 0]).max() < 0.05          # near the axis at the design focus
    assert np.allclose(out[:3, 2], 0.0)


def test_04_bad_lens_file_gives_one_clear_line(tmp_path):
    """A malformed lens file exits with status 2 and a message naming the file."""
    bad = tmp_path / "broken.toml"
    bad.write_text("name = 'x'\n[[surface]]\nradius = 'round'\n")
    proc = cli("info", bad, check=False)
    assert proc.returncode == 2
    assert "broken.toml" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_05_diagram_and_spot_write_pngs(tmp_path):
    """`diagram` and `spot` write non-trivial PNG images."""
    for cmd in ("diagram", "spot"):
        out = tmp_path / f"{cmd}.png"
        cli(cmd, DG, "--out", out)
        data = out.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20000


@pytest.mark.parametrize("command", [
    ("neurolens_addon.core", "info", str(DG), "--json"),
    ("neurolens_addon.core", "index", "N-BK7", "587.56"),
    ("neurolens_addon.render", str(ROOT / "presets" / "scenes" / "demo.blend"), "--show-setup")])
def test_06_output_its_reader_closed_ends_quietly(command):
    """`... | head`: the reader has gone (here before the first line): the command ends with
    the status a SIGPIPE death gives (141) and says nothing on stderr (it printed 'error:
    [Errno 32] Broken pipe' and exited 2)."""
    import os
    r, w = os.pipe()
    os.close(r)
    proc = subprocess.run([sys.executable, "-m", *command], cwd=ROOT, stdout=w,
                          stderr=subprocess.PIPE, text=True, timeout=300)
    os.close(w)
    assert proc.returncode == 141, proc.stderr
    assert "Broken pipe" not in proc.stderr and "error" not in proc.stderr, proc.stderr
