"""One camera, one lens set-up: the panel (and the Cycles camera it applies), the NEUROLENS
engine rendering the camera, and the render command line reading the saved .blend resolve the
same lens set-up, field by field, over many camera settings: sensor fits, aspect ratios, pixel
aspects, shifts, percentages, focus distances, focus objects and bones, focus nearer than the
closest focus, f-numbers wider than the lens, blades with curvature, image masks, panel and
command-line (custom property) cameras, every preset.

All cameras go into one .blend (a scene each); the engine renders each scene at one sample;
one process runs the command line (`--scene NAME --show-setup`) over every scene."""

from __future__ import annotations

import importlib
import json
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from .conftest import PACKAGE, ROOT, USER_RESOURCES

pytestmark = pytest.mark.slow          # renders through every renderer

bpy = pytest.importorskip("bpy")

# The first twelve presets and one of each kind the library added since (a zoom, a macro and a
# telephoto that focus by moving groups, a fisheye, an aspheric prime): every setting meets
# every kind, and the suite stays within its time (the Cycles shader of every preset compiles
# in tests/cycles/test_generate.py).
ORIGINAL = ("biconvex_singlet", "cooke_triplet_f4", "double_gauss_50mm_f2", "double_gauss_f1_35",
            "double_gauss_f1_4_takumar", "fisheye_f4", "noct_58mm_f0_95_aspheric", "petzval_f1_4",
            "retrofocus_35mm_f2_8", "telephoto_f5_6", "tessar_f4_5", "wide_angle_f3_4")
ADDED = ("zoom_rf_24_70mm_f2_8", "macro_100mm_f2_8", "tele_400mm_f2_8_if",
         "fisheye_16mm_f2_8_diagonal", "aspheric_50mm_f1_2")
PRESETS = sorted(ORIGINAL + ADDED)
FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
SIZES = ((24, 16), (16, 24), (20, 20), (30, 12))
FOCUS = ("distance", "nearer", "object", "bone")
APERTURES = ("circle", "blades", "mask")


def _case(k: int, preset: str) -> dict:
    """A mix of settings for case k (every value of each setting appears across the cases)."""
    w, h = SIZES[k % len(SIZES)]
    model = ("exact", "learned", "auto", "thin", "dir")[k % 5]
    if model == "dir" and not (ROOT / "presets" / "models" / f"{preset}.neurolens").is_dir():
        model = "learned"
    return {
        "name": f"case{k:02d}-{preset}", "preset": preset,
        "source": "custom" if k % 4 == 3 or model == "dir" else "panel",
        "model": model,
        "fit": FITS[k % 3], "size": (w, h), "percentage": (100, 50, 200, 75)[k % 4],
        "pixel_aspect": ((1.0, 1.0), (2.0, 1.0), (1.0, 1.5))[k % 3],
        "shift": ((0.0, 0.0), (0.1, -0.05), (-0.2, 0.15))[k % 3],
        "sensor": ((36.0, 24.0), (23.5, 15.6), (8.0, 6.0))[k % 3],
        "focus": FOCUS[k % 4],
        "fstop_factor": (1.0, 0.5, 2.0, 0.9999999)[(k // 2) % 4],   # x the lens's widest
        "aperture": APERTURES[k % 3],
        "unit_scale": (1.0, 0.01)[k % 2],
    }


CASES = [_case(k, p) for k, p in enumerate(PRESETS + PRESETS[:4])]


def _mask_image():
    img = bpy.data.images.get("nl-mask") or bpy.data.images.new("nl-mask", 16, 16, alpha=True)
    yy, xx = np.mgrid[-1:1:16j, -1:1:16j]
    lum = ((xx ** 2 + (1.5 * yy) ** 2) < 0.9).astype(np.float32)
    img.pixels.foreach_set(np.repeat(lum.ravel(), 4))
    img.pack()
    return img


def _focus_bone(sc, location):
    arm = bpy.data.armatures.new("nl-rig")
    ob = bpy.data.objects.new("nl-rig", arm)
    sc.collection.objects.link(ob)
    vl = sc.view_layers[0]
    with bpy.context.temp_override(scene=sc, view_layer=vl, active_object=ob, object=ob,
                                   selected_objects=[ob]):
        vl.objects.active = ob
        bpy.ops.object.mode_set(mode="EDIT")
        bone = arm.edit_bones.new("focus")
        bone.head = location
        bone.tail = (location[0], location[1] + 0.1, location[2])
        bpy.ops.object.mode_set(mode="OBJECT")
    return ob


def _build(addon, c: dict):
    """A scene with one camera configured as case `c` says (and a light to render)."""
    sc = bpy.data.scenes.new(c["name"])
    r = sc.render
    r.resolution_x, r.resolution_y = c["size"]
    r.resolution_percentage = c["percentage"]
    r.pixel_aspect_x, r.pixel_aspect_y = c["pixel_aspect"]
    sc.unit_settings.scale_length = c["unit_scale"]
    data = bpy.data.cameras.new(c["name"])
    obj = bpy.data.objects.new(c["name"], data)
    sc.collection.objects.link(obj)
    sc.camera = obj
    obj.location = (0.1, -0.2, 0.3)
    obj.rotation_euler = (0.2, 0.0, 0.3)
    data.sensor_fit = c["fit"]
    data.sensor_width, data.sensor_height = c["sensor"]
    data.shift_x, data.shift_y = c["shift"]
    entry = addon.lenses.load_lens_entry(addon.library.path_for(c["preset"]))
    if entry.lens.zoom_gaps is not None:
        # a zoom at its middle position: that position's own widest f-number and model
        data.lens = entry.lens.zoom_gaps.positions[1]
        entry = addon.lenses.zoomed_entry(entry, data.lens)
    c["widest"] = entry.f_number
    dof = data.dof
    dof.use_dof = True
    dof.aperture_fstop = entry.f_number * c["fstop_factor"]
    per_unit = 1.0 / c["unit_scale"]
    if c["focus"] == "nearer":
        dof.focus_distance = 0.5 * entry.closest_focus_mm / 1000.0 * per_unit
    else:
        dof.focus_distance = max(3.0, 2.0 * entry.closest_focus_mm / 1000.0) * per_unit
    target = (0.3 * per_unit, 0.2 * per_unit, -4.0 * per_unit)
    if c["focus"] == "object":
        empty = bpy.data.objects.new(c["name"] + "-target", None)
        sc.collection.objects.link(empty)
        empty.location = target
        dof.focus_object = empty
    elif c["focus"] == "bone":
        dof.focus_object = _focus_bone(sc, target)
        dof.focus_subtarget = "focus"
    props = data.neurolens
    props.aperture_shape = {"circle": "CIRCLE", "blades": "BLADES", "mask": "MASK"}[c["aperture"]]
    if c["aperture"] == "blades":
        dof.aperture_blades, dof.aperture_rotation = 5, 0.3
        props.blade_curvature = 0.4
    elif c["aperture"] == "mask":
        props.mask_image = _mask_image()
    if c["source"] == "panel":
        props.lens_id = c["preset"]
        props.model = c["model"].upper()
        props.enabled = True
    else:
        data["neurolens_lens"] = c["preset"]
        data["neurolens_model"] = (str(ROOT / "presets" / "models" / f"{c['preset']}.neurolens")
                                   if c["model"] == "dir" else c["model"])
    light = bpy.data.objects.new(c["name"] + "-sun", bpy.data.lights.new(c["name"], "SUN"))
    sc.collection.objects.link(light)
    return sc, obj


def _plain(d) -> dict:
    return json.loads(json.dumps(d))


@pytest.fixture(scope="module")
def resolved(addon, tmp_path_factory):
    """{case name: {"panel", "spec", "engine", "engine_size", "cli"}} for every case."""
    engine = importlib.import_module(PACKAGE + ".neurolens_addon.blender.render_engine")
    traced = importlib.import_module(PACKAGE + ".neurolens_addon.camera").traced
    out, scenes = {}, []
    for c in CASES:
        sc, obj = _build(addon, c)
        scenes.append(sc)
        sc.view_layers[0].update()      # world matrices, as the UI has them when it draws
        state = addon.camera_state.evaluate_camera(obj, sc)
        assert state.setup is not None, (c, state.messages)
        rec = {"panel": _plain(state.setup.as_dict()),
               "traced": _plain(traced(state.setup).as_dict()),
               "spec": addon.sync.camera_spec(obj, sc)}
        sc.render.engine = "NEUROLENS"
        sc.neurolens_engine.samples, sc.cycles.max_bounces = 1, 0
        engine.LAST["config"] = engine.LAST["stats"] = None
        bpy.ops.render.render(scene=sc.name)
        assert engine.LAST["stats"] is not None, (c, engine.LAST.get("error"))
        rec["engine"] = _plain(engine.LAST["config"].as_dict())
        rec["engine_size"] = (engine.LAST["stats"].width, engine.LAST["stats"].height)
        out[c["name"]] = rec
    blend = tmp_path_factory.mktemp("one-setup") / "cases.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    driver = (
        "import contextlib, io, json, sys\n"
        "from neurolens_addon.render.cli import main\n"
        "res = {}\n"
        "for name in sys.argv[2:]:\n"
        "    buf = io.StringIO()\n"
        "    with contextlib.redirect_stdout(buf):\n"
        "        rc = main([sys.argv[1], '--scene', name, '--show-setup', '--quiet'])\n"
        "    res[name] = [rc, buf.getvalue()]\n"
        "print('RESULT' + json.dumps(res))\n")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(USER_RESOURCES), PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", driver, str(blend)] + [c["name"] for c in CASES],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    line = [s for s in proc.stdout.splitlines() if s.startswith("RESULT")]
    assert proc.returncode == 0 and line, proc.stderr[-3000:]
    for name, (rc, text) in json.loads(line[0][len("RESULT"):]).items():
        assert rc == 0, (name, proc.stderr[-2000:])
        out[name]["cli"] = json.loads(text)
    for sc in scenes:
        for obj in list(sc.collection.objects):
            bpy.data.objects.remove(obj)
        bpy.data.scenes.remove(sc)
    return out


def case_closest_mm(case) -> float:
    from neurolens_addon.camera.lenses import load_lens_entry
    return load_lens_entry(ROOT / "presets" / "lenses" / f"{case['preset']}.toml").closest_focus_mm


def _without_paths(d: dict) -> dict:
    """The set-up with file locations made relative to the add-on (the extension's copy and
    the checkout the command line imports are the same files)."""
    d = dict(d)
    for key in ("lens_file", "model_dir"):
        if d.get(key):
            parts = d[key].replace("\\", "/").split("/")
            d[key] = "/".join(parts[parts.index("presets"):]) if "presets" in parts else d[key]
    if d.get("messages"):       # "no model ... in YOUR MODELS FOLDER": each process its own
        d["messages"] = [[level, re.sub(r" in \S*neurolens[/\\]models:", " in <models>:", text)]
                         for level, text in d["messages"]]
    return d


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_panel_engine_and_command_line_resolve_the_same_setup(resolved, case):
    rec = resolved[case["name"]]
    traced, engine, cli = (_without_paths(rec[k]) for k in ("traced", "engine", "cli"))
    assert engine == traced             # the engine renders the thin lens exactly
    assert cli == traced                # --show-setup shows what --engine neurolens renders
    if case["model"] != "thin":
        assert traced == _without_paths(rec["panel"])


def test_some_cases_do_use_a_learned_model(resolved):
    """Without onnxruntime or the shipped models every learned case would be exact and the
    comparisons above would prove less: make sure they do not."""
    used = {resolved[c["name"]]["panel"]["model"] for c in CASES}
    assert {"learned", "exact", "thin"} <= used


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_the_cycles_camera_is_the_setup(resolved, case):
    panel, spec = resolved[case["name"]]["panel"], resolved[case["name"]]["spec"]
    assert spec.model == panel["model"]
    assert (spec.f_number, spec.sensor_z_mm, spec.dispersion) == (
        panel["f_number"], panel["sensor_z_mm"], panel["dispersion"])
    assert spec.focus_distance_m == pytest.approx(panel["focus_mm"] / 1000.0, rel=1e-15)
    assert _without_paths({"model_dir": spec.model_dir})["model_dir"] == \
        _without_paths(panel)["model_dir"]
    assert type(spec.aperture).__name__ == {"circle": "CircularAperture",
                                            "polygon": "PolygonAperture",
                                            "mask": "ImageMaskAperture"}[panel["aperture"][0]]


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_every_renderer_frames_the_same_film(resolved, case):
    """Cycles' camera gets the film the engine renders, which is Blender's sensor fit."""
    rec = resolved[case["name"]]
    film, spec = rec["panel"]["film"], rec["spec"]
    assert (spec.sensor_width_mm, spec.sensor_height_mm) == (film["width_mm"], film["height_mm"])
    assert rec["engine_size"] == (film["width_px"], film["height_px"])
    w, h = case["size"]
    pct = case["percentage"] / 100.0
    assert (film["width_px"], film["height_px"]) == (int(w * pct), int(h * pct))
    ax, ay = int(w * pct) * case["pixel_aspect"][0], int(h * pct) * case["pixel_aspect"][1]
    fit = case["fit"] if case["fit"] != "AUTO" else ("HORIZONTAL" if ax >= ay else "VERTICAL")
    sw, sh = case["sensor"]
    if fit == "HORIZONTAL":
        expected = (sw, sw * ay / ax)
    else:
        expected = ((sh if case["fit"] == "VERTICAL" else sw) * ax / ay,
                    sh if case["fit"] == "VERTICAL" else sw)
    assert (film["width_mm"], film["height_mm"]) == pytest.approx(expected)
    big = max(expected)
    assert film["shift_x_mm"] == pytest.approx(case["shift"][0] * big)
    assert film["shift_y_mm"] == pytest.approx(case["shift"][1] * big)


@pytest.mark.parametrize("case", CASES, ids=[c["name"] for c in CASES])
def test_the_clamps_and_messages_are_the_panels(resolved, case):
    """f-numbers wider than the lens and focus nearer than its closest focus are clamped with
    the same message everywhere; curvature and masks reach every renderer."""
    panel = resolved[case["name"]]["panel"]
    texts = " ".join(t for _l, t in panel["messages"])
    widest = case["widest"]         # the lens's (a zoom's at its focal length)
    if case["fstop_factor"] == 0.5:
        assert "wider than this lens allows" in texts and panel["f_number"] == widest
    else:
        assert "wider than this lens allows" not in texts
        assert panel["f_number"] == pytest.approx(widest * case["fstop_factor"], rel=1e-6)
    if case["fstop_factor"] == 0.9999999:
        assert panel["f_number"] == widest          # single precision: the widest itself
    if case["focus"] == "nearer":
        assert "focuses no closer" in texts
        assert panel["focus_mm"] == case_closest_mm(case)
    if case["focus"] in ("object", "bone") and "focuses no closer" not in texts:
        # along the view axis to the target (the bone's head, not the armature's origin)
        from mathutils import Euler, Vector
        axis = Euler((0.2, 0.0, 0.3)).to_matrix() @ Vector((0.0, 0.0, -1.0))
        per_unit = 1.0 / case["unit_scale"]
        t = Vector((0.3 * per_unit, 0.2 * per_unit, -4.0 * per_unit)) - Vector((0.1, -0.2, 0.3))
        expected = abs(t.dot(axis)) * case["unit_scale"] * 1000.0
        assert panel["focus_mm"] == pytest.approx(expected, rel=1e-6)
    kind = panel["aperture"][0]
    assert kind == {"circle": "circle", "blades": "polygon", "mask": "mask"}[case["aperture"]]
    if case["aperture"] == "blades":
        blades, rotation, curvature = (float(v) for v in panel["aperture"][1:])
        assert (blades, rotation, curvature) == pytest.approx((5, math.degrees(0.3), 0.4),
                                                              rel=1e-6)
