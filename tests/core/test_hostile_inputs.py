"""Hostile inputs to the core: FIFOs, devices, oversize and lying files, lenses that image
nothing, frames that cannot fit, JSON that is not JSON. One clear error each, never a hang."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.errors import ApertureError, LensError, NeuroLensError
from testdata.deadline import finishes

ROOT = Path(__file__).resolve().parents[2]
DG = ROOT / "presets" / "lenses" / "double_gauss_50mm_f2.toml"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_01_a_fifo_named_as_a_lens_file_is_refused_at_once(tmp_path):
    from neurolens_addon.core.lensfile import load_lens
    fifo = tmp_path / "lens.toml"
    os.mkfifo(fifo)
    with pytest.raises(LensError, match="FIFO"):
        finishes(lambda: load_lens(fifo))


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_02_a_link_to_an_endless_device_is_refused(tmp_path):
    from neurolens_addon.core.lensfile import load_lens
    link = tmp_path / "lens.toml"
    link.symlink_to("/dev/zero")
    with pytest.raises(LensError, match="device"):
        finishes(lambda: load_lens(link))


def _npy_header(shape, descr="<f8") -> bytes:
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    text = repr(header).encode("latin1")
    pad = 64 - (10 + len(text) + 1) % 64
    body = text + b" " * pad + b"\n"
    return b"\x93NUMPY\x01\x00" + len(body).to_bytes(2, "little") + body


@pytest.mark.parametrize("make,match", [
    (lambda p: np.save(p, np.zeros((0, 7))), "empty"),
    (lambda p: np.save(p, np.zeros(3, dtype=[("x", "f8"), ("y", "f8")])), "plain numbers"),
    (lambda p: p.write_bytes(_npy_header((10 ** 12, 7)) + b"\0" * 56), "10000000000"),
    (lambda p: p.write_bytes(_npy_header((5, 7)) + b"\0" * 56), "truncated"),
    (lambda p: np.save(p, np.zeros((4, 6))), "N x 7"),
])
def test_03_ray_arrays_are_checked_from_their_header(tmp_path, make, match):
    """An empty array, a structured dtype, a header claiming 10^12 rows, a truncated file and
    the wrong width: one error naming the file, before any large allocation."""
    from neurolens_addon.core.cli import load_ray_rows
    p = tmp_path / "rays.npy"
    make(p)
    with pytest.raises(NeuroLensError, match=match) as err:
        load_ray_rows(p)
    assert str(p) in str(err.value)


def test_04_a_lens_that_images_nothing_is_refused_when_loaded(tmp_path):
    """A flat window with a stop: refused on load naming the file (it used to divide by zero
    in the paraxial data)."""
    from neurolens_addon.core.lensfile import load_lens
    p = tmp_path / "window.toml"
    p.write_text('name = "window"\nsource = "test"\nfocal_length_mm = 50.0\nf_number = 4.0\n'
                 '[[surface]]\nradius = "flat"\nthickness = 1.0\nmaterial = "air"\n'
                 'semi_diameter = 10\nstop = true\n'
                 '[[surface]]\nradius = "flat"\nthickness = 5\n'
                 'material = { nd = 1.5168, vd = 64.17 }\nsemi_diameter = 10\n'
                 '[[surface]]\nradius = "flat"\nthickness = 20\nmaterial = "air"\n'
                 'semi_diameter = 10\n')
    with pytest.raises(LensError, match="no optical power") as err:
        load_lens(p)
    assert "window.toml" in str(err.value)


def test_05_masks_are_bounded_and_area_averaged():
    """A mask over the pixel limit is refused before use; a large one is area-averaged to
    MAX_MASK_SIDE on a side, keeping its open area."""
    from neurolens_addon.core.aperture.image_mask import (MAX_MASK_SIDE, ImageMaskAperture,
                                                          area_average)
    yy, xx = np.mgrid[-1:1:3000j, -1:1:2000j]
    disc = ((xx ** 2 + yy ** 2) < 0.81).astype(np.float64)
    ap = ImageMaskAperture(disc, source="big")
    assert max(ap.mask.shape) == MAX_MASK_SIDE
    assert ap.mask.mean() == pytest.approx(disc.mean(), rel=2e-3)
    assert area_average(np.ones((10, 10))).shape == (10, 10)
    huge = np.broadcast_to(np.float32(1.0), (20000, 20000))    # a view: no memory behind it
    with pytest.raises(ApertureError, match="over the limit"):
        ImageMaskAperture(huge, source="huge")


def test_06_frames_that_cannot_fit_are_refused_before_allocating():
    """1 000 000 % of 1920 x 1080, or 100 000 x 100 000 pixels: a FilmError naming the size."""
    from neurolens_addon.core.film import FilmError, pixel_counts
    with pytest.raises(FilmError, match="larger than"):
        pixel_counts(1920, 1080, 1_000_000)
    with pytest.raises(FilmError, match="larger than"):
        pixel_counts(100_000, 100_000, 100)
    assert pixel_counts(1920, 1080, 100) == (1920, 1080)


def _strict(text: str):
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_07_info_json_is_json(tmp_path):
    """`info --json` of a lens focused at infinity prints JSON a strict reader accepts (no
    NaN or Infinity)."""
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.core", "info", str(DG), "--json"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert isinstance(_strict(p.stdout), dict)


def test_08_an_unexpected_failure_is_one_line(capsys, monkeypatch):
    """run_command: a bug is one line naming the exception, exit status 70, no traceback
    unless NEUROLENS_TRACEBACK=1."""
    from neurolens_addon.core.errors import run_command
    monkeypatch.delenv("NEUROLENS_TRACEBACK", raising=False)

    def broken():
        return {}["missing"]
    assert run_command(broken, "prog") == 70
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unexpected KeyError" in err and "Traceback" not in err
