"""The render command line renders a camera set up in the Real Lens panel as the panel would;
each flag changes only what it names; without a panel the default model is the panel's
Automatic. Checked with `--show-setup` (the set-up the render would use) in another process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from .conftest import ROOT, USER_RESOURCES

bpy = pytest.importorskip("bpy")

MODELS = ROOT / "presets" / "models"
RUNS = {
    "as_saved": [],
    "fstop": ["--fstop", "8"],
    "focus": ["--focus", "2.5"],
    "lens": ["--lens", "tessar_f4_5"],
    "model": ["--model", "learned"],
    "model_dir": ["--model", str(MODELS / "cooke_triplet_f4.neurolens")],
    "bare_camera": ["--camera", "Bare", "--lens", "cooke_triplet_f4"],
    "auto": ["--model", "auto"],
    "auto_cycles": ["--model", "auto", "--engine", "cycles"],
}


@pytest.fixture(scope="module")
def shown(addon, tmp_path_factory):
    sc = bpy.data.scenes.new("cli-panel")
    sc.render.resolution_x, sc.render.resolution_y = 64, 48
    objs = []
    for name in ("Panel", "Bare"):
        data = bpy.data.cameras.new(name)
        obj = bpy.data.objects.new(name, data)
        sc.collection.objects.link(obj)
        objs.append(obj)
    sc.camera = objs[0]
    data = objs[0].data
    data.sensor_width = 24.0
    data.dof.aperture_fstop, data.dof.focus_distance = 5.6, 3.0
    data.dof.aperture_blades, data.dof.aperture_rotation = 5, 0.2
    props = data.neurolens
    props.lens_id, props.model = "cooke_triplet_f4", "EXACT"
    props.blade_curvature, props.dispersion = 0.3, False
    props.enabled = True
    blend = tmp_path_factory.mktemp("cli-panel") / "panel.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    for obj in objs:
        bpy.data.objects.remove(obj)
    bpy.data.scenes.remove(sc)
    driver = (
        "import contextlib, io, json, sys\n"
        "from neurolens_addon.render.cli import main\n"
        "runs = json.loads(sys.argv[2])\n"
        "res = {}\n"
        "for name, flags in runs.items():\n"
        "    buf = io.StringIO()\n"
        "    with contextlib.redirect_stdout(buf):\n"
        "        rc = main([sys.argv[1], '--scene', 'cli-panel', '--show-setup'] + flags)\n"
        "    res[name] = json.loads(buf.getvalue()) if rc == 0 else rc\n"
        "print('RESULT' + json.dumps(res))\n")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(USER_RESOURCES), PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", driver, str(blend), json.dumps(RUNS)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    line = [s for s in proc.stdout.splitlines() if s.startswith("RESULT")]
    assert proc.returncode == 0 and line, proc.stderr[-3000:]
    return json.loads(line[0][len("RESULT"):])


def test_the_panels_camera_renders_as_the_panel_says(shown):
    s = shown["as_saved"]
    assert s["lens"].startswith("Cooke") and s["model"] == "exact"
    assert s["f_number"] == pytest.approx(5.6) and s["focus_mm"] == pytest.approx(3000.0)
    assert s["aperture"][0] == "polygon" and float(s["aperture"][3]) == pytest.approx(0.3)
    assert s["dispersion"] is False and s["film"]["width_mm"] == 24.0


@pytest.mark.parametrize("run, changed", [
    ("fstop", {"f_number": 8.0}), ("focus", {"focus_mm": 2500.0}),
    ("lens", {"lens": "Tessar"}), ("model", {"model": "learned"}),
    ("model_dir", {"model": "learned"})])
def test_each_flag_changes_only_what_it_names(shown, run, changed):
    base, s = shown["as_saved"], shown[run]
    for key, value in changed.items():
        if isinstance(value, str) and key == "lens":
            assert s[key].startswith(value)
        else:
            assert s[key] == pytest.approx(value)
    kept = {"aperture", "dispersion", "film", "f_number", "focus_mm", "model"} - set(changed)
    if run == "lens":
        kept -= {"f_number"}            # the Tessar opens to f/4.5 only: 5.6 stays 5.6
    for key in kept:
        assert s[key] == base[key], key


def test_a_camera_without_the_panel_defaults_to_automatic(shown):
    s = shown["bare_camera"]
    assert s["lens"].startswith("Cooke") and s["choice"] is not None     # model AUTO chose


@pytest.mark.parametrize("run, renderer", [("auto", "neurolens"), ("auto_cycles", "cycles")])
def test_automatic_names_the_costs_on_the_renderer_that_renders(shown, run, renderer):
    """--show-setup with model AUTO on each --engine: the choice says its renderer, the costs
    a camera ray (the chosen way's and the exact trace's, from the model's recorded figures
    for that renderer), the models considered (the preset's, within the budget at 64 px on
    the 24 mm film) and why; the learned model is taken only where its recorded cost is
    under 0.95x the exact trace's."""
    s = shown[run]
    cost = s["choice_cost"]
    assert cost["renderer"] == renderer
    meta = json.loads((MODELS / "cooke_triplet_f4.neurolens" / "model.json").read_text())
    recorded = meta["costs"][renderer]
    assert cost["exact_us_per_camera_ray"] == pytest.approx(recorded["exact_us"])
    learned = recorded["learned_us"] < 0.95 * recorded["exact_us"]
    assert s["model"] == ("learned" if learned else "exact")
    assert cost["us_per_camera_ray"] == pytest.approx(
        recorded["learned_us"] if learned else recorded["exact_us"])
    assert ["learned model cooke_triplet_f4", ""] in s["choice_considered"]
    where = "Cycles" if renderer == "cycles" else "the NEUROLENS engine"
    assert f"a camera ray in {where}" in s["choice_why"]
