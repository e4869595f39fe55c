"""OSL generation without rendering: it compiles, it is deterministic, bad specs are refused,
and the pieces it is built from reproduce the core's equations."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.aperture import ImageMaskAperture, PolygonAperture
from neurolens_addon.core.errors import ApertureError, LensError, ModelError, NeuroLensError
from neurolens_addon.core.glass import default_catalog, resolve_medium
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.rays import Rays
from neurolens_addon.core.sensor_response import sensor_response
from neurolens_addon.core.trace import trace
from neurolens_addon.cycles import CameraSpec, CameraSpecError, generate_osl, source_hash
from neurolens_addon.core.pupil_slabs import slab_pupil
from neurolens_addon.cycles.spectral import (
    index_expression,
    sample_wavelength,
)

ROOT = Path(__file__).resolve().parents[2]
LENSES = sorted((ROOT / "presets" / "lenses").glob("*.toml"))
MODEL_DG = ROOT / "presets" / "models" / "double_gauss_50mm_f2.neurolens"


def evaluate_expression(expr: str, wavelength_nm) -> np.ndarray:
    """Evaluate a generated OSL index expression in numpy (float64), to check it against
    core.glass. Test-only: the add-on never evaluates strings."""
    L2 = (np.asarray(wavelength_nm, dtype=np.float64) * 1e-3) ** 2
    return np.asarray(eval(expr, {"__builtins__": {}}, {"sqrt": np.sqrt, "L2": L2}))


def lens(name):
    return load_lens(ROOT / "presets" / "lenses" / f"{name}.toml")


@pytest.fixture(scope="module")
def compile_osl():
    pytest.importorskip("bpy")
    from neurolens_addon.blender.cycles_camera import compile_osl
    return compile_osl


def test_01_every_preset_lens_compiles_with_cycles_oslc(compile_osl, monkeypatch):
    """The exact-lens shader of every preset (spheres, aspheres, cover glasses, dispersion on
    for every other lens) is accepted by Cycles' own OSL compiler (coarse pupil tables here:
    their size does not change the code)."""
    from neurolens_addon.core import pupil_slabs
    monkeypatch.setattr(pupil_slabs, "BANDS", 4)
    monkeypatch.setattr(pupil_slabs, "GRID", 16)
    for i, path in enumerate(LENSES):
        src = generate_osl(CameraSpec("exact", lens=load_lens(path), dispersion=bool(i % 2)))
        assert "shader neurolens_camera" in src
        assert compile_osl(src).strip(), path.name


def test_02_apertures_thin_and_learned_shaders_compile(compile_osl):
    """Blades (straight and curved), an image mask (reduced when large), the thin lens with
    each shape, and a learned model all compile."""
    dg = lens("double_gauss_50mm_f2")
    yy, xx = np.mgrid[-1:1:200j, -1:1:200j]
    mask = ImageMaskAperture(((xx ** 2 + yy ** 2) < 0.8) & (np.abs(xx) > 0.1))
    shapes = [PolygonAperture(6, 15.0), PolygonAperture(7, 0.0, 0.6), mask]
    for ap in shapes:
        compile_osl(generate_osl(CameraSpec("exact", lens=dg, f_number=4.0, aperture=ap)))
        compile_osl(generate_osl(CameraSpec("thin", focal_mm=35.0, f_number=2.0,
                                            focus_distance_m=3.0, aperture=ap)))
    compile_osl(generate_osl(CameraSpec("thin", focal_mm=35.0, f_number=2.0,
                                        focus_distance_m=math.inf)))
    compile_osl(generate_osl(CameraSpec("learned", lens=dg, model_dir=str(MODEL_DG),
                                        dispersion=True)))
    singlet = lens("biconvex_singlet")        # its front stage is free flight ("propagate")
    compile_osl(generate_osl(CameraSpec("learned", lens=singlet, model_dir=str(
        ROOT / "presets" / "models" / "biconvex_singlet.neurolens"))))


def test_03_generation_is_deterministic_and_follows_the_spec():
    """The same spec gives byte-identical source (the glue skips recompiling on that); a
    changed f-number, focus, shape or dispersion changes it."""
    dg = lens("double_gauss_50mm_f2")
    base = CameraSpec("exact", lens=dg, sensor_z_mm=0.5, f_number=2.8,
                      aperture=PolygonAperture(6))
    a, b = generate_osl(base), generate_osl(dataclasses.replace(base))
    assert a == b and source_hash(a) == source_hash(b)
    for change in ({"f_number": 4.0}, {"sensor_z_mm": 0.7}, {"dispersion": True},
                   {"aperture": PolygonAperture(5)}, {"sensor_width_mm": 24.0}):
        assert generate_osl(dataclasses.replace(base, **change)) != a, change


def test_04_invalid_specs_raise_the_projects_errors():
    """Bad specs raise NeuroLensError subclasses that say what is wrong: unknown model,
    missing lens, f-number wider than the lens, wrong aperture type, thin lens without focus,
    a model trained for another lens, a missing model directory."""
    dg = lens("double_gauss_50mm_f2")
    cases = [
        (CameraSpec("pinhole", lens=dg), CameraSpecError, "model"),
        (CameraSpec("exact"), LensError, "lens"),
        (CameraSpec("exact", lens=dg, f_number=1.0), ApertureError, "wider"),
        (CameraSpec("exact", lens=dg, f_number=-2.0), CameraSpecError, "f_number"),
        (CameraSpec("exact", lens=dg, aperture="hexagon"), ApertureError, "aperture"),
        (CameraSpec("exact", lens=dg, sensor_width_mm=0.0), CameraSpecError, "sensor_width"),
        (CameraSpec("thin", focal_mm=50.0, f_number=2.0), CameraSpecError, "focus"),
        (CameraSpec("thin", focal_mm=50.0, focus_distance_m=2.0), CameraSpecError, "f_number"),
        (CameraSpec("learned", lens=dg), ModelError, "model"),
        (CameraSpec("learned", lens=lens("tessar_f4_5"), model_dir=str(MODEL_DG)), ModelError,
         "trained for"),
        (CameraSpec("learned", lens=dg, model_dir=str(ROOT / "no_such.neurolens")), ModelError,
         "model.json"),
        (CameraSpec("exact", lens=dg, probe="colour"), CameraSpecError, "probe"),
    ]
    for spec, kind, words in cases:
        with pytest.raises(kind) as info:
            generate_osl(spec)
        assert isinstance(info.value, NeuroLensError)
        assert words in str(info.value), (spec, str(info.value))
    no_stop = dg.with_surfaces([dataclasses.replace(s, stop=False) for s in dg.surfaces])
    with pytest.raises(LensError, match="stop"):
        generate_osl(CameraSpec("exact", lens=no_stop))


def test_05_index_expressions_reproduce_core_glass():
    """The OSL index law of every catalog glass and every preset medium equals core.glass's
    index to 1e-6 across 380-780 nm (the same text evaluates in numpy)."""
    wl = np.linspace(380.0, 780.0, 41)
    media = list(default_catalog())
    for path in LENSES:
        media += [resolve_medium(m) for m in load_lens(path).media()]
    for m in media:
        got = evaluate_expression(index_expression(m), wl)
        np.testing.assert_allclose(got, m.index(wl), atol=1e-6, err_msg=m.name)


def test_06_wavelength_sampler_keeps_white_white_with_non_negative_weights():
    """The shader's wavelength sampler averages to RGB (1, 1, 1) for a flat spectrum, every
    weight is non-negative with R + G + B = 3, and it draws from the sensor density."""
    xi = (np.arange(400000) + 0.5) / 400000
    lam, w = sample_wavelength(xi)
    np.testing.assert_allclose(w.mean(axis=0), 1.0, atol=2e-4)
    assert w.min() >= 0.0
    np.testing.assert_allclose(w.sum(axis=1), 3.0, rtol=1e-12)
    r = sensor_response()
    hist, edges = np.histogram(lam, bins=80, range=(380.0, 780.0), density=True)
    mid = 0.5 * (edges[1:] + edges[:-1])
    np.testing.assert_allclose(hist, r.at(mid).sum(axis=1) / 3.0, atol=2e-4)


@pytest.mark.parametrize("name", ["double_gauss_50mm_f2", "fisheye_f4"])
def test_07_pupil_slabs_cover_every_passing_ray(name):
    """Pupil-aware sampling is unbiased and wastes few rays: at several sensor radii the slab
    estimate of the irradiance equals a brute-force estimate over a wide disc (within 2 %),
    and at least 70 % of the sampled rays pass the lens."""
    L = lens(name)
    film = 21.6
    table = slab_pupil(L, 0.0, film, L.stop_radius_mm)
    rng = np.random.default_rng(4)
    n = 60000
    for r in (0.0, 0.45 * film, 0.9 * film):
        band = min(int(r / film * table.bands), table.bands - 1)
        if not np.any(table.x_hi[band] > table.x_lo[band]):
            continue                                  # beyond the image circle
        sx, sy = np.full(n, r), np.zeros(n)
        d, w = table.directions(sx, sy, rng.random(n), rng.random(n))
        o = np.stack([sx, sy, np.zeros(n)])
        ok = trace(L, Rays(o, d, np.full(n, 587.5618)), from_sensor=True).valid
        assert ok.mean() >= 0.7, (r, ok.mean())
        wide = 2.0 * max(np.abs(table.y[band]).max(), np.abs(table.x_lo[band]).max(),
                         np.abs(table.x_hi[band]).max())
        a, rad = 2 * np.pi * rng.random(4 * n), wide * np.sqrt(rng.random(4 * n))
        dz = table.plane_z
        dd = np.stack([rad * np.cos(a) - r, rad * np.sin(a), np.full(4 * n, dz)])
        dd /= np.linalg.norm(dd, axis=0)
        o4 = np.stack([np.full(4 * n, r), np.zeros(4 * n), np.zeros(4 * n)])
        ok4 = trace(L, Rays(o4, dd, np.full(4 * n, 587.5618)), from_sensor=True).valid
        brute = np.mean(ok4 * dd[2] ** 4) * math.pi * wide ** 2 / dz ** 2
        assert np.mean(w * ok) == pytest.approx(brute, rel=0.02), r


BLOCKER = r"""
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('bpy', 'onnxruntime', 'torch', 'mathutils', '_cycles'):
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.cycles import CameraSpec, generate_osl
dg = load_lens('presets/lenses/double_gauss_50mm_f2.toml')
exact = generate_osl(CameraSpec('exact', lens=dg))
learned = generate_osl(CameraSpec('learned', lens=dg,
                                  model_dir='presets/models/double_gauss_50mm_f2.neurolens'))
print(len(exact) > 1000 and len(learned) > 1000)
"""


def test_08_generation_needs_neither_bpy_nor_onnxruntime():
    """neurolens_addon.cycles is pure Python: the exact and learned shaders are generated with
    bpy, onnxruntime and torch blocked."""
    import subprocess
    import sys
    proc = subprocess.run([sys.executable, "-c", BLOCKER], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "True"


def test_09_a_sparse_skip_runs_each_output_over_its_own_range_of_monomials(tmp_path):
    """A model whose members list their skip monomials (the sparse basis) and whose averaged
    skip has zero coefficients: the shader builds just the monomials the members use and
    their prefixes, placed so that outputs sharing terms (0 and 3 here) loop over one
    contiguous range of them and the others over their own (1), an output with none (2) is
    its bias, the prefixes no output uses last (COEF: each output's range, zeros within
    it); and it sees the wavelength as mu = (l0 / lambda)^2 where the cell says so; a
    full-basis model keeps the dense table (LIN)."""
    import json
    import re
    import shutil

    from neurolens_addon.cycles import CameraSpec, generate_osl
    root = Path(__file__).resolve().parents[2]
    src = root / "presets" / "models" / "biconvex_singlet.neurolens"
    lens = load_lens(root / "presets" / "lenses" / "biconvex_singlet.toml")
    full = generate_osl(CameraSpec("learned", lens=lens, model_dir=str(src), f_number=4.0))
    assert "LIN[" in full and "PSTART" not in full and "REF[cell]" not in full
    dst = tmp_path / "sparse.neurolens"
    shutil.copytree(src, dst)
    meta = json.loads((dst / "model.json").read_text())
    cell = meta["stages"][0]["cells"][0]
    assert meta["domain"]["dispersion"]
    cell["x_norm"]["wavelength_ref_nm"] = 550.0
    for m in cell["members"]:
        m["skip_terms"] = [[0], [1, 1], [0, 2, 4]]   # r, u_r^2, r u_t mu: prefixes (1), (0, 2)
        m["L"] = [[1.0, 0.0, 0.5], [0.0, 2.0, 0.0], [0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]
    (dst / "model.json").write_text(json.dumps(meta))
    code = generate_osl(CameraSpec("learned", lens=lens, model_dir=str(dst), f_number=4.0))
    assert "COEF[" in code and "LIN[" not in code
    coef = re.search(r"float COEF\[(\d+)\]", code)
    assert coef is not None and int(coef.group(1)) == 5          # outputs 0, 3: 2; 1: 1; 2: 0
    assert re.search(r"float m\[(\d+)\]", code).group(1) == "5"  # (0) (1) (0,2) (1,1) (0,2,4)
    # places: (0) 0 and (0,2,4) 1 (outputs 0, 3), (1,1) 2 (output 1), prefixes (1) 3, (0,2) 4
    for line in ("m[0] = xn[0];", "m[3] = xn[1];", "m[4] = m[0] * xn[2];",
                 "m[2] = m[3] * xn[1];", "m[1] = m[4] * xn[4];",
                 "for (int i = 0; i < 2; ++i) acc += COEF[base + i] * m[0 + i];",
                 "for (int i = 0; i < 1; ++i) acc += COEF[base + i] * m[2 + i];",
                 "Y[2] = BIAS[cell * 4 + 2];"):
        assert line in code, line
    assert "REF[cell]" in code and "float mu = REF[cell] / X[4];" in code


def _following(model="exact", **kw):
    from neurolens_addon.camera.setup import FocusFollow
    dg = lens("double_gauss_50mm_f2")
    extra = {"model_dir": str(MODEL_DG)} if model == "learned" else {}
    return CameraSpec(model, lens=dg, f_number=2.0, dispersion=True,
                      follow=FocusFollow(kw.get("focus", (1000.0, 4000.0)),
                                         kw.get("f_numbers", (2.0, 8.0))), **extra)


def test_10_following_cameras_read_blenders_focus_and_f_number_and_compile(compile_osl):
    """A camera with a follow range reads cam:focal_distance and cam:aperture_size, bakes no
    frame's own values (the source is the same whatever the current focus), and compiles,
    exact and learned."""
    import dataclasses
    spec = _following()
    src = generate_osl(spec)
    assert 'getattribute("cam:focal_distance"' in src and 'getattribute("cam:aperture_size"' in src
    moved = dataclasses.replace(spec, sensor_z_mm=-1.0, f_number=5.6)
    assert generate_osl(moved) == src
    assert compile_osl(src).strip()
    assert compile_osl(generate_osl(_following("learned"))).strip()
    assert 'getattribute("cam:focal_distance"' not in generate_osl(
        dataclasses.replace(spec, follow=None))


def test_11_the_focus_table_interpolates_the_focus_solve():
    """At its points the shader's sensor position is the still camera's (core.focus's solve at
    that focus and stop radius), and between them (linear in 1 / distance) within 2 um of it,
    across a 0.6 m to infinity pull, at every tabulated f-number."""
    from neurolens_addon.core.focus import focus_sensor_z
    spec = _following(focus=(600.0, math.inf))
    tab = spec.tables
    t = tab.t
    mid = 0.5 * (t[1:] + t[:-1])
    for m, r in enumerate(tab.stop_radii):
        z = tab.sensor_z[:, m]
        assert z[3] == pytest.approx(focus_sensor_z(spec.lens, 1.0 / t[3], stop_radius=r),
                                     abs=1e-9)
        got = np.interp(mid, t, z)
        want = [focus_sensor_z(spec.lens, 1.0 / x, stop_radius=r) for x in mid]
        np.testing.assert_allclose(got, want, atol=2e-3)


def test_12_following_pupil_slabs_cover_every_focus_of_the_range():
    """The slabs of a following camera hold the rays that pass from sensor planes between the
    tabulated ones: aim points of passing rays from off-axis film points, at focus distances
    halfway between table points, land inside a slab (99.5 %)."""
    from neurolens_addon.core.focus import focus_sensor_z
    from neurolens_addon.cycles.follow import lens_state
    spec = _following(focus=(700.0, 10000.0))
    table = lens_state(spec).table
    t = spec.tables.t
    rng = np.random.default_rng(12)
    for x in 0.5 * (t[1:] + t[:-1]):
        z_s = focus_sensor_z(spec.lens, 1.0 / x)
        n = 20000
        r = rng.uniform(0.0, 0.95 * table.film_radius, n)
        px, py = rng.uniform(-25, 25, (2, n))
        d = np.stack([px - r, py, np.full(n, table.plane_z - z_s)])
        d /= np.linalg.norm(d, axis=0)
        o = np.stack([r, np.zeros(n), np.full(n, z_s)])
        ok = trace(spec.lens, Rays(o, d, np.full(n, 587.5618)), from_sensor=True).valid
        band = np.clip((r * table.bands / table.film_radius).astype(int), 0, table.bands - 1)
        inside = np.zeros(n, dtype=bool)
        for b in np.unique(band[ok]):
            sel = ok & (band == b)
            yb = table.y[b]
            k = np.clip(np.searchsorted(yb, py[sel], side="right") - 1, 0, table.slabs - 1)
            inside[sel] = ((py[sel] >= yb[0]) & (py[sel] <= yb[-1])
                           & (px[sel] >= table.x_lo[b, k]) & (px[sel] <= table.x_hi[b, k]))
        assert ok.sum() > 500
        assert inside[ok].mean() >= 0.995, (z_s, inside[ok].mean())


def test_13_follow_ranges_are_checked():
    """A follow range on the thin lens, a near end beyond the far one, or an f-number wider
    than the lens is refused naming the field."""
    import dataclasses
    spec = _following()
    for bad in (dataclasses.replace(spec, model="thin", focal_mm=50.0, focus_distance_m=2.0),
                _following(focus=(4000.0, 1000.0)), _following(f_numbers=(1.4, 8.0))):
        with pytest.raises(CameraSpecError, match="'follow'"):
            generate_osl(bad)


HOSTILE = "x\n#define nl_pupil_sample broken\r\x00\u2028 trailing\\"


def _code_lines(src: str) -> list[str]:
    """The source's lines of code, every // comment removed: what the compiler sees."""
    code = (ln.split("//", 1)[0].rstrip() for ln in src.splitlines())
    return [ln for ln in code if ln]


def test_14_text_from_files_never_reaches_the_code(tmp_path, compile_osl):
    """A lens name and source, a glass name and a model's stage name carrying a newline, a
    '#define', a carriage return, a NUL, a Unicode line separator and a trailing backslash
    change only comments: the code is line for line that of the benign files (the comments
    may run over more lines), every line is
    printable ASCII, no line is a preprocessor directive, and the shader compiles."""
    import dataclasses
    import json
    import shutil
    dg = lens("double_gauss_50mm_f2")
    evil = dataclasses.replace(dg, name=HOSTILE, source=HOSTILE)
    model = tmp_path / "evil.neurolens"
    shutil.copytree(MODEL_DG, model)
    meta = json.loads((model / "model.json").read_text())
    meta["stages"][0]["name"] = HOSTILE
    (model / "model.json").write_text(json.dumps(meta))
    for benign, hostile in (
            (CameraSpec("exact", lens=dg, dispersion=True),
             CameraSpec("exact", lens=evil, dispersion=True)),
            (CameraSpec("learned", lens=dg, model_dir=str(MODEL_DG)),
             CameraSpec("learned", lens=dg, model_dir=str(model)))):
        good, bad = generate_osl(benign), generate_osl(hostile)
        assert _code_lines(bad) == _code_lines(good)
        assert all(ln.isascii() and ln.isprintable() for ln in bad.splitlines())
        assert not any(ln.lstrip().startswith("#") for ln in bad.splitlines())
        assert "#define" in bad                      # still there, inside a comment
    assert compile_osl(generate_osl(CameraSpec("exact", lens=evil))).strip()


def test_15_asphere_functions_fall_back_to_the_vertex_plane():
    """Every even-asphere function of the exact shader starts Newton from the vertex plane
    where its base conic has no forward root, instead of dropping the ray (issue 25: the
    28 mm F/1.4's resin asphere); the Cycles probe render test_25 in test_render.py runs it."""
    L = lens("aspheric_28mm_f1_4")
    src = generate_osl(CameraSpec("exact", lens=L))
    zs = L.vertex_z
    aspheres = [i for i, s in enumerate(L.surfaces) if s.aspheric]
    assert aspheres == [4, 22, 25, 26]
    for i in aspheres:
        head = src.index(f"int nl_asphere_{i}(")
        body = src[head:src.index("\n}", head)].splitlines()
        at = next(k for k, ln in enumerate(body) if "nl_conic_root(" in ln)
        assert body[at].rstrip().endswith(")"), body[at]          # no "return 0" on a miss
        zv = body[at].split("nl_conic_root(p, d, ", 1)[1].split(",", 1)[0]
        assert float(zv) == pytest.approx(float(zs[i]), rel=1e-6)
        assert body[at + 1].strip() == f"t = d[2] == 0.0 ? 0.0 : ({zv} - p[2]) / d[2];"


def _with_shape(L, index, **change):
    """L with surface `index`'s shape fields changed (no lens-file checks: the shader's own
    check is what is tested)."""
    s = L.surfaces[index]
    surfaces = list(L.surfaces)
    surfaces[index] = dataclasses.replace(s, shape=dataclasses.replace(s.shape, **change))
    return L.with_surfaces(surfaces)


def _asphere(L, index, aspheric):
    from neurolens_addon.core.surfaces.asphere import EvenAsphere
    s = L.surfaces[index]
    surfaces = list(L.surfaces)
    surfaces[index] = dataclasses.replace(s, shape=EvenAsphere(s.shape.radius_mm, 0.0,
                                                                aspheric))
    return L.with_surfaces(surfaces)


def test_16_numbers_beyond_float32_are_refused_naming_surface_and_field(compile_osl):
    """Cycles' camera is float32: a conic of -1e45 or -1e300, a toroid's sweep radius of
    1e40 mm, a huge asphere coefficient or a thickness of 1e39 mm is refused with the lens's
    file, the surface and the field named (issue 27: "unexpected ValueError: constant 1e+40
    overflows float32", naming nothing); a 1e20 mm window, which clips nothing, is written at
    the largest semi-diameter float32 holds squared, and compiles."""
    dg = lens("double_gauss_50mm_f2")
    ana = lens("anamorphic_2x_60mm_f1_9")
    turned = next(i for i, s in enumerate(ana.surfaces) if type(s.shape).__name__ == "Cylinder")
    cases = [
        (_with_shape(dg, 0, conic=-1e45), 1, "conic"),
        (_with_shape(dg, 2, conic=-1e300), 3, "conic"),
        (_asphere(dg, 3, ((10, 1e39),)), 4, "aspheric"),
        (_asphere(dg, 3, ((20, 1e20),)), 4, "aspheric"),     # 1e20 rho^10 at the rim: 1e41
        (dg.with_surfaces([dataclasses.replace(s, thickness_mm=1e39) if i == 4 else s
                           for i, s in enumerate(dg.surfaces)]), 5, "thickness"),
        (_with_shape(ana, turned, conic_u=-1e45, conic_v=-1e45), turned + 1, "conic"),
    ]
    for L, surface, field in cases:
        with pytest.raises(LensError) as info:
            generate_osl(CameraSpec("exact", lens=L))
        assert info.value.surface == surface and info.value.field == field, str(info.value)
        assert "float32" in str(info.value) and "\n" not in str(info.value)
    window = dg.with_surfaces([dataclasses.replace(dg.surfaces[0], shape=dataclasses.replace(
        dg.surfaces[0].shape, radius_mm=math.inf), thickness_mm=5.0,
        material=dg.surfaces[1].material, semi_diameter_mm=1e20)]
        + list(dg.surfaces))
    src = generate_osl(CameraSpec("exact", lens=window))
    assert "1e+24" in src and "inf" not in src.replace("inside", "")
    assert compile_osl(src).strip()
