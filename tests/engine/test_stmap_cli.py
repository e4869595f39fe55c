"""The render command's --stmap (the scene camera's map: its lens, focus and sensor) and
--overscan (the frame grown at the same pixel pitch), with one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow          # opens the demo scene from the command line

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "presets" / "scenes" / "demo.blend"


def cli(*args):
    return subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(DEMO),
                           *map(str, args)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)


def _setup(*args) -> dict:
    p = cli(*args, "--show-setup")
    assert p.returncode == 0, p.stderr
    return json.JSONDecoder().raw_decode(p.stdout[p.stdout.index("{"):])[0]


def test_01_the_cameras_map_is_its_lens_at_its_focus_on_its_sensor(tmp_path):
    """`--stmap distort` writes the map core.stmap makes for the camera's lens as it stands at
    the camera's focus, on its film (the scene's sensor and pixels), and its lens data beside
    it; no frame is rendered."""
    from neurolens_addon.core.exr import read_exr
    from neurolens_addon.core.lensfile import load_lens
    from neurolens_addon.core.stmap import MapFrame, chief_ray_table, st_map
    out = tmp_path / "m.exr"
    args = ("--lens", "wide_20mm_f2_8", "--focus", "2.5", "--resolution", "240x135")
    p = cli(*args, "--stmap", "distort", "--out", out)
    assert p.returncode == 0, p.stderr
    assert "distort map of" in p.stdout and "needs overscan" in p.stdout
    setup = _setup(*args)
    f = setup["film"]
    frame = MapFrame(f["width_px"], f["height_px"], f["width_mm"])
    lens = load_lens(ROOT / "presets" / "lenses" / "wide_20mm_f2_8.toml")
    want = st_map(chief_ray_table(lens, setup["sensor_z_mm"], frame.film_radius_mm), frame,
                  "distort")
    chans, header = read_exr(out)
    np.testing.assert_allclose(chans["R"], want[..., 0], atol=1e-6)
    np.testing.assert_allclose(chans["G"], want[..., 1], atol=1e-6)
    assert header["neurolens/focus_mm"] == pytest.approx(2500.0, rel=1e-6)
    meta = json.loads(Path(f"{out}.json").read_text())
    assert meta["focus_distance_mm"] == pytest.approx(2500.0, rel=1e-6)


def test_02_overscan_grows_the_frame_at_the_same_pixel_pitch():
    """`--overscan 1.1`: 1.1 times the pixels and the sensor each way, the pitch unchanged."""
    base = _setup("--resolution", "200x100")["film"]
    grown = _setup("--resolution", "200x100", "--overscan", "1.1")["film"]
    assert (grown["width_px"], grown["height_px"]) == (220, 110)
    assert grown["width_mm"] == pytest.approx(1.1 * base["width_mm"], rel=1e-6)
    assert grown["height_mm"] == pytest.approx(1.1 * base["height_mm"], rel=1e-6)


@pytest.mark.parametrize("args, says", [
    (("--overscan", "5", "--show-setup"), "--overscan must be a number from 1 to 4"),
    (("--stmap", "distort", "--out", "{tmp}/m.png"), "one --out FILE.exr")])
def test_03_what_cannot_be_done_is_one_line(tmp_path, args, says):
    p = cli(*(a.format(tmp=tmp_path) for a in args))
    assert p.returncode == 2
    errors = [ln for ln in p.stderr.splitlines() if ln.startswith("neurolens.render: error:")]
    assert len(errors) == 1 and says in errors[0], p.stderr
    assert not (tmp_path / "m.exr").exists()


def test_03b_a_lens_known_only_from_a_ray_table_has_maps(tmp_path):
    """`--lens MODEL.neurolens --stmap undistort`: a ray-table lens's map through its chief
    rays (camera.table_lens), with its lens data beside it."""
    from neurolens_addon.core.exr import read_exr
    from testdata.table_lens import MODEL
    out = tmp_path / "m.exr"
    p = cli("--lens", MODEL, "--resolution", "240x160", "--stmap", "undistort", "--out", out)
    assert p.returncode == 0, p.stderr
    chans, header = read_exr(out)
    assert chans["R"].shape == (160, 240) and (chans["A"] > 0).mean() > 0.99
    meta = json.loads(Path(f"{out}.json").read_text())
    assert meta["distortion"]["brown_conrady"]["max_residual_px"] < 1.0
    assert header["neurolens/pinhole_focal_length_mm"] == pytest.approx(101.0, rel=0.01)


def test_04_a_rendered_frame_carries_its_lens_data(tmp_path):
    """A frame rendered from the command line has its lens data beside it (FRAME.exr.json)
    and in its EXR header (the metadata note): the camera, the f-number and focus it rendered
    at, the sensor, the entrance pupil and the fitted distortion models; the header its gist
    (Blender keeps a note of 500 characters)."""
    import OpenEXR
    out = tmp_path / "f.exr"
    p = cli("--lens", "wide_20mm_f2_8", "--focus", "2", "--fstop", "4", "--resolution", "32x18",
            "--samples", "1", "--quiet", "--no-denoise", "--out", out)
    assert p.returncode == 0, p.stderr
    meta = json.loads(Path(f"{out}.json").read_text())
    assert meta["f_number"] == 4.0 and meta["focus_distance_mm"] == pytest.approx(2000.0)
    assert meta["resolution_px"] == [32, 18] and meta["model"] in ("exact", "learned")
    assert meta["distortion"]["brown_conrady"]["max_residual_px"] < 1.0
    with OpenEXR.File(str(out)) as f:
        note = json.loads(f.parts[0].header["Note"])
    bc = meta["distortion"]["brown_conrady"]
    assert note["f_number"] == 4.0 and note["lens"] == meta["lens"]
    assert note["opencv_k"] == pytest.approx([bc["k1"], bc["k2"], bc["k3"]], rel=1e-6)
