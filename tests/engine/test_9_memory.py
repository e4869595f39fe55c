"""The engine's memory: an estimate before a render starts that refuses, with the figure, a
frame the machine cannot hold; a streamed (tile by tile) film that gives the same image as the
progressive frame film; the denoiser's and the diffraction's work bounded (engine.memory,
engine.film, engine.denoise, core.diffraction). Real renders (bpy, the demo scene, the
command line), kept tiny; figures of memory come from the processes themselves."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
pytestmark = pytest.mark.slow          # engine renders and child processes

from neurolens_addon.blender.render_engine import LAST  # noqa: E402
from testdata import engine_scenes as scenes  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "presets" / "scenes" / "demo.blend"
GB = 1e9
#: "WxH at S samples needs about X GB, this machine has Y GB available" (engine.memory.check)
REFUSAL = re.compile(r"(\d+)x(\d+) at 1 sample needs about ([0-9.]+) GB, this machine has "
                     r"([0-9.]+) GB available")


#: A small process that runs the command and writes its exit status and peak resident set
#: (bytes) to argv[1]. The render is measured from here, not from pytest: Linux starts a
#: (v)forked child's ru_maxrss at its parent's high-water mark, and late in the suite pytest
#: itself holds ~2 GB.
_MEASURE = ("import os, subprocess, sys, threading\n"
            "p = subprocess.Popen(sys.argv[3:])\n"
            "timer = threading.Timer(float(sys.argv[2]), p.kill)\n"
            "timer.start()\n"
            "_pid, status, usage = os.wait4(p.pid, 0)\n"
            "timer.cancel()\n"
            "rc = os.waitstatus_to_exitcode(status)\n"
            "open(sys.argv[1], 'w').write(f'{rc} {usage.ru_maxrss * 1024}')\n")


def _peak_of(cmd, timeout):
    """(exit status, stdout + stderr, peak resident set in bytes of the command's own process)
    of a child process, killed (and the test failed) past `timeout` seconds."""
    import tempfile
    # the numpy lens trace: a fresh clone's first call would compile the numba kernels, whose
    # LLVM work (a few hundred MB, once per cache) is not the frame memory measured here
    env = dict(os.environ, PYTHONPATH=str(ROOT), NEUROLENS_KERNELS="numpy")
    with tempfile.TemporaryDirectory() as tmp:
        peak_file = Path(tmp) / "peak"
        done = subprocess.run([sys.executable, "-c", _MEASURE, str(peak_file), str(timeout),
                               *cmd], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT)
        text = done.stdout.decode(errors="replace")
        assert done.returncode == 0, text[-800:]
        rc, peak = map(int, peak_file.read_text().split())
        if rc == -9:
            pytest.fail(f"no refusal within {timeout} s: the render started ({text[-300:]})")
        return rc, text, peak


def test_01_a_frame_the_machine_cannot_hold_is_refused_before_it_is_allocated(tmp_path):
    """The largest frame the engine renders (16384 x 16384, 1 sample, the demo scene from the
    command line) needs more than this machine has: the render is refused with one line naming
    the estimate and the memory available (MemAvailable), status 1, no output written, and the
    process never grows to the frame (its peak stays under 2 GB, against the 21 GB Blender's
    result alone would take). Before the estimate, the render started and ran on."""
    from neurolens_addon.engine import memory
    from neurolens_addon.engine.settings import RenderSettings
    avail, _source = memory.available_bytes()
    side = 16384
    est = memory.estimate(side, side, RenderSettings(samples=1), rays_per_sample=3,
                          workers=os.cpu_count() or 1, streamed=True, denoise=True)
    extra = [] if avail is not None and est.total > 1.2 * avail else ["--memory-limit", "1"]
    out = tmp_path / "huge.png"
    rc, text, peak = _peak_of([sys.executable, "-m", "neurolens_addon.render", str(DEMO),
                               "--lens", "double_gauss_50mm_f2", "--model", "exact",
                               "--samples", "1", "--resolution", f"{side}x{side}", "--quiet",
                               *extra, "--out", str(out)], timeout=240)
    errors = [ln for ln in text.splitlines() if ln.startswith("neurolens.render: error:")]
    assert rc == 1 and len(errors) == 1 and "Traceback" not in text, text[-800:]
    assert not out.exists()
    if extra:                                          # a machine that could hold it
        assert "over the Memory Limit of 1 GB" in errors[0]
    else:
        m = REFUSAL.search(errors[0])
        assert m is not None, errors[0]
        needs, has = float(m.group(3)), float(m.group(4))
        assert (int(m.group(1)), int(m.group(2))) == (side, side)
        assert needs > has > 0
        assert abs(has - avail / GB) < 0.25 * avail / GB + 0.5   # the machine's own figure
    assert peak < 2 * GB, peak


def test_02_the_memory_limit_setting_refuses_a_render_in_blender(tmp_path):
    """The render settings' Memory Limit replaces the machine's figure: a 64 x 48 render
    under a limit of 0.01 GB ends with one line naming the estimate and the limit (nothing is
    rendered); with no limit it renders, and its statistics hold the estimate."""
    scenes.reset()
    scenes.emitter_sphere((0.0, 0.0, -2.0))
    scenes.camera(focus=2.0, fstop=2.8, sensor_width=8.0, model="exact")
    with pytest.raises(RuntimeError) as err:
        scenes.render(tmp_path / "a.exr", 64, 48, 1, memory_limit_gb=0.01)
    line = str(err.value).strip().splitlines()[-1]
    assert re.search(r"64x48 at 1 sample needs about [0-9.]+ GB, over the Memory Limit of "
                     r"0\.01 GB", line), line
    assert LAST["stats"] is None
    scenes.render(tmp_path / "b.exr", 64, 48, 1, memory_limit_gb=0.0)
    st = LAST["stats"]
    assert st.samples_done == 64 * 48 and 0.01 * GB < st.memory_estimate < 2 * GB


@pytest.mark.parametrize("denoise", [False, True])
def test_03_tile_by_tile_with_tiny_tiles_gives_the_progressive_image(tmp_path, denoise):
    """The same 40 x 30 frame at 4 samples, (a) progressive on a frame film in one tile and
    one bundle, (b) tile by tile on a streamed film with 8-pixel tiles and 1024-sample
    bundles: every pass of the written EXR is the same, bit for bit, denoised or not; the
    streamed film never held more than one tile's sums."""
    scenes.sphere_on_plane()
    a = scenes.render(tmp_path / "a.exr", 40, 30, 4, tile_order="PROGRESSIVE", tile_size=64,
                      max_bundle_rays=65536, denoise=denoise)
    sa = LAST["stats"]
    b = scenes.render(tmp_path / "b.exr", 40, 30, 4, tile_order="TILES", tile_size=8,
                      max_bundle_rays=1024, denoise=denoise)
    sb = LAST["stats"]
    assert not sa.streamed and sb.streamed
    assert sa.bundles == 3 and sb.bundles == 3 * 20        # one bundle a pass (of a tile)
    assert sb.max_film_tiles == 1
    assert set(a) == set(b)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert luminance_spread(a) > 0.01                       # an image, not an empty frame


def luminance_spread(ch) -> float:
    lum = 0.2126 * ch["Combined.R"] + 0.7152 * ch["Combined.G"] + 0.0722 * ch["Combined.B"]
    return float(lum.std())


def test_04_a_one_pass_frame_streams_by_itself():
    """Auto: a frame of one pass (1 sample) streams, a frame of several passes whose film fits
    the budget stays progressive, one whose film would pass it streams."""
    from neurolens_addon.engine import memory
    from neurolens_addon.engine.settings import RenderSettings
    assert memory.streamed_film(3840, 2160, RenderSettings(samples=1), 3)
    assert not memory.streamed_film(640, 480, RenderSettings(samples=16), 3)
    assert memory.streamed_film(3840, 2160, RenderSettings(samples=16), 3)
    assert not memory.streamed_film(3840, 2160, RenderSettings(samples=1,
                                                                tile_order="PROGRESSIVE"), 3)


def test_05_the_estimate_counts_what_grows_with_the_frame():
    """Blender's result grows with the frame (20 float channels a pixel), the bundles do not;
    a streamed film is one tile plus the passes kept for post-processing; an 8K frame at one
    sample with the denoiser is estimated at a few GB, a 4K one at about a quarter of that; the
    refusal is one line with both figures; what is available is read from the machine."""
    from neurolens_addon.engine import memory
    from neurolens_addon.engine.settings import RenderSettings
    s = RenderSettings(samples=1)
    e4 = memory.estimate(3840, 2160, s, rays_per_sample=3, workers=2, streamed=True,
                         denoise=True)
    e8 = memory.estimate(7680, 4320, s, rays_per_sample=3, workers=2, streamed=True,
                         denoise=True)
    assert e8.parts["result"] == 4 * e4.parts["result"] == 4 * 80 * 3840 * 2160
    assert e8.parts["bundles"] == e4.parts["bundles"]
    plain = memory.estimate(7680, 4320, s, streamed=True)
    assert plain.parts["film"] == 64 * 64 * 64                 # one 64 x 64 tile, nothing kept
    frame = memory.estimate(7680, 4320, s, streamed=False)
    assert frame.parts["film"] == 64 * 7680 * 4320
    assert 2 * GB < e8.total < 7 * GB and e4.total < 0.35 * e8.total + 0.6 * GB
    with pytest.raises(Exception, match=r"needs about 6\.\d GB, this machine has 2\.0 GB "
                                        r"available"):
        memory.check(memory.Estimate(10, 10, 1, {"x": 6.05 * GB}), available=int(2 * GB))
    avail, source = memory.available_bytes()
    total = next(int(ln.split()[1]) * 1024 for ln in open("/proc/meminfo")
                 if ln.startswith("MemTotal:"))
    assert source in ("MemAvailable", "cgroup memory limit") and 0 < avail <= total


def test_06_diffraction_in_strips_is_the_one_fft_convolution():
    """core.diffraction.convolve a strip of rows at a time (a tiny strip budget: many strips),
    into a new array or in place, gives the whole-frame FFT convolution to float rounding; the
    kernel computed a block of rows at a time is the same kernel."""
    from neurolens_addon.core import diffraction as D
    from neurolens_addon.core.aperture import PolygonAperture
    pattern = D.pattern_for(PolygonAperture(6))
    k = D.film_kernel(pattern, pixel_mm=0.006, working_f_number=11.0, dispersion=True,
                      max_radius_px=40)
    r = k.kernels.shape[1] // 2
    img = np.random.default_rng(0).random((157, 203, 4)).astype(np.float32)
    whole = D.convolve(img, k, strip_points=1 << 30)
    assert D.strip_rows(157, 203, r, 1 << 12)[0] < 157 // 3          # several strips
    strips = D.convolve(img, k, strip_points=1 << 12)
    np.testing.assert_allclose(strips, whole, rtol=0, atol=1e-6)
    inplace = img.copy()
    D.convolve(inplace, k, out=inplace, strip_points=1 << 12)
    np.testing.assert_allclose(inplace, whole, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(inplace[..., 3], img[..., 3])
    np.testing.assert_array_equal(D.monochrome_kernel(pattern, 0.7, 25, block_points=500),
                                  D.monochrome_kernel(pattern, 0.7, 25, block_points=1 << 30))


_DENOISE_CHILD = r"""
import json, numpy as np
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
from neurolens_addon.engine import denoise as dn
import pyoidn
side = 3000
rng = np.random.default_rng(0)
c = (rng.random((side, side, 3), dtype=np.float32) * 4).astype(np.float32)
a = np.full((side, side, 3), 0.5, np.float32)
n = np.zeros((side, side, 3), np.float32); n[..., 2] = 1
small = dn.denoise(c[:64, :64].copy(), a[:64, :64].copy(), n[:64, :64].copy())  # libraries in
before = status("VmRSS")
out = dn.denoise(c, a, n)
print(json.dumps({"rise": status("VmHWM") - before, "finite": bool(np.isfinite(out).all())}))
"""


def test_07_the_denoisers_scratch_is_bounded():
    """Open Image Denoise on a 3000 x 3000 frame in a fresh process: the process grows by its
    bounded scratch (OIDN_MAX_MEMORY_MB) and the copies of the inputs, under 1.3 GB (0.8 GB
    measured), where OIDN's own default grew it by 1.9 GB."""
    pytest.importorskip("pyoidn")
    p = subprocess.run([sys.executable, "-c", _DENOISE_CHILD], cwd=ROOT, capture_output=True,
                       text=True, timeout=600, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == 0, p.stderr[-600:]
    d = json.loads(p.stdout.strip().splitlines()[-1])
    assert d["finite"] and d["rise"] < 1.3 * GB, d


def test_08_the_command_line_checks_its_memory_limit(tmp_path):
    """--memory-limit must be a size in GB >= 0: anything else is one error line, status 2."""
    p = subprocess.run([sys.executable, "-m", "neurolens_addon.render", str(DEMO),
                        "--memory-limit", "-1", "--out", str(tmp_path / "o.png")], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    errors = [ln for ln in p.stderr.splitlines() if ln.startswith("neurolens.render: error:")]
    assert p.returncode == 2 and len(errors) == 1 and "--memory-limit" in errors[0], p.stderr


def _png_of(w: int, h: int, value: int, rgba: bool) -> bytes:
    """A valid 8-bit PNG of w x h pixels all `value` (grey, or RGBA opaque), compressed a
    block of rows at a time with zlib: a 9000 x 8000 image is a file of a few hundred KB."""
    import struct
    import zlib
    comp = zlib.compressobj(1)
    px = bytes([value, value, value, 255]) if rgba else bytes([value])
    row = b"\0" + px * w
    parts = [comp.compress(row * min(64, h - i)) for i in range(0, h, 64)] + [comp.flush()]

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I",
                                                                         zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 6 if rgba else 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", b"".join(parts))
            + chunk(b"IEND", b""))


def test_09_a_huge_mask_image_in_blender_is_refused_before_it_is_decoded(tmp_path):
    """A 9000 x 8000 PNG chosen as a camera's aperture mask (bpy.data.images.load, as the
    panel's image picker loads it) is refused in one line naming the image, its file and its
    size, and Blender never decodes it (the image has no pixel data afterwards; before, its
    size was asked of Blender, which decodes the whole file: 288 MB here, 1.6 GB for 20000^2)."""
    from neurolens_addon.blender.camera_reader import mask_aperture
    from neurolens_addon.core.errors import ApertureError
    scenes.reset()
    path = tmp_path / "huge_mask.png"
    path.write_bytes(_png_of(9000, 8000, 0, rgba=False))
    image = bpy.data.images.load(str(path))
    assert not image.has_data
    with pytest.raises(ApertureError) as err:
        mask_aperture(image)
    text = str(err.value)
    assert "\n" not in text and "huge_mask.png" in text and "9000 x 8000 pixels" in text, text
    assert not image.has_data


_BLENDER_MASK_CHILD = r"""
import json, sys
def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1]) * 1024
import bpy, numpy as np
from neurolens_addon.blender.camera_reader import mask_aperture
image = bpy.data.images.load(sys.argv[1])
before = status("VmRSS")
ap, _key = mask_aperture(image)
rise = status("VmHWM") - before
print(json.dumps({"rise": rise, "shape": list(ap.mask.shape), "area": ap.area(),
                  "loaded_after": bool(image.has_data)}))
"""


def test_10_a_large_mask_image_in_blender_is_reduced_without_float64_copies(tmp_path):
    """A 4096 x 4096 RGBA mask image read through Blender in a fresh process: the process
    grows by less than 36 bytes a pixel (Blender's decoding, the float32 pixels its API gives,
    then blocks of rows: 27.5 measured), where the whole image's bytes and float64 copies took
    78; the 1024 x 1024 mask kept has the image's area, and Blender's decoded copy is
    released."""
    side = 4096
    path = tmp_path / "open.png"
    path.write_bytes(_png_of(side, side, 255, rgba=True))
    p = subprocess.run([sys.executable, "-c", _BLENDER_MASK_CHILD, str(path)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert p.returncode == 0, p.stderr[-600:]
    d = json.loads(p.stdout.strip().splitlines()[-1])
    assert d["shape"] == [1024, 1024] and d["area"] == pytest.approx(4.0)
    assert not d["loaded_after"]
    assert d["rise"] < 36 * side * side, d
