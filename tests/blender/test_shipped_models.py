"""The shipped preset models serve Blender's default camera: Automatic chooses them."""

import pytest

from neurolens_addon.neural.modelfile import read_header

from .conftest import ROOT

#: a fisheye's model stops at its stated field (the Muller fisheye's 156 degrees, 13.4 mm):
#: trained out to its image circle (film points looking 78-90 degrees off axis) the stage
#: fits diverge (trainer.data.EXTENSION_MAX_FIELD_DEG), so Automatic renders the full-frame
#: corners of a fisheye exactly (test_03 for the Muller fisheye)
FISHEYE = "fisheye_f4"
PRESETS = sorted(p.stem for p in (ROOT / "presets" / "lenses").glob("*.toml")
                 if not p.stem.startswith("fisheye"))


def _default_camera_state(addon, scene, lens: str):
    """A new camera as Blender makes it (36 mm sensor, fit Auto) at 1920 x 1080, set to `lens`
    in the Real Lens panel, model Automatic."""
    sc, camera = scene
    obj = camera("Default", lens_id=lens)
    assert obj.data.sensor_width == 36.0 and obj.data.neurolens.model == "AUTO"
    zoom = addon.lenses.load_lens_entry(addon.library.path_for(lens)).lens.zoom_gaps
    if zoom is not None:        # a zoom's models sit at its tabulated focal lengths: the wide end
        obj.data.lens = zoom.positions[0]
    return addon.camera_state.evaluate_camera(obj, sc)


@pytest.mark.slow
@pytest.mark.parametrize("lens", PRESETS)
def test_01_every_shipped_model_covers_blenders_default_camera(addon, scene, lens):
    """For every preset, the shipped model (presets/models/NAME.neurolens) covers the default
    camera's film, up to the lens's image circle: if Automatic passes it over, the reason is
    its error budget, never its film radius. (Other shipped variants, such as the double
    Gauss's deliberately small 'lean' model of the speed benchmarks, may cover less.)"""
    pytest.importorskip("onnxruntime")
    choice = _default_camera_state(addon, scene, lens).choice
    assert choice is not None
    own = f"learned model {lens}"
    if choice.kind == "learned" and choice.path.endswith(f"{lens}.neurolens"):
        return
    reasons = dict(choice.considered)
    assert own in reasons, choice.considered
    assert "film radius" not in (reasons[own] or ""), reasons[own]


@pytest.mark.parametrize("renderer", ["neurolens", "cycles"])
@pytest.mark.parametrize("lens", ["double_gauss_50mm_f2", "cooke_triplet_f4", "tessar_f4_5",
                                  "zoom_rf_70_200mm_f2_8", "zoom_16_35mm_f2_8"])
def test_02_automatic_renders_the_default_camera_as_the_shipped_costs_say(addon, scene, lens,
                                                                          renderer):
    """For the default camera, rendered by the engine or by Cycles, the preset's shipped model
    meets the budget and covers the scene; of the lens's shipped models that do (the full
    NeuroLens model, the sparse one of a lens of 25 surfaces or more), Automatic takes the one
    whose recorded cost a camera ray on that renderer is lowest against the exact trace's,
    where it is under 0.95x that (the zooms: in the engine both at their wide ends, in Cycles
    the sparse models), else the exact trace, and says which costs decided."""
    pytest.importorskip("onnxruntime")
    from neurolens_addon.neural.choice import RENDERER_NAMES
    scene[0].render.engine = "CYCLES" if renderer == "cycles" else "NEUROLENS"
    state = _default_camera_state(addon, scene, lens)
    choice = state.choice
    considered = dict(choice.considered)
    assert considered[f"learned model {lens}"] == ""                   # the preset's qualifies
    ratios = {}
    for name, why in considered.items():
        header = read_header(ROOT / "presets" / "models"
                             / f"{name.removeprefix('learned model ')}.neurolens")
        exact_us, learned_us = header.ray_cost_us(renderer)
        if not why:
            ratios[header.directory.name] = (learned_us / exact_us, learned_us, exact_us)
    best = min(ratios, key=lambda n: ratios[n][0])
    ratio, learned_us, exact_us = ratios[best]
    assert choice.renderer == renderer and choice.exact_cost_us == exact_us
    if ratio < 0.95:
        assert choice.kind == "learned", choice.reason
        assert choice.path.endswith(best) and choice.cost_us == learned_us
        assert "within the budget" in choice.reason and "a camera ray" in choice.reason
        assert state.setup.model == "learned" and state.setup.model_dir == choice.path
    else:
        assert choice.kind == "exact" and state.setup.model == "exact"
        where = RENDERER_NAMES[renderer]
        assert choice.reason.startswith((f"Exact trace: cheaper in {where}",
                                         f"Exact trace: as cheap in {where}")), choice.reason
        assert best in choice.reason


def test_03_the_fisheye_says_why_automatic_traces_it_exactly(addon, scene):
    """On a full-frame camera the fisheye's film reaches its 15.6 mm image circle, past its
    model's 13.4 mm: Automatic uses the exact trace and names both radii."""
    pytest.importorskip("onnxruntime")
    choice = _default_camera_state(addon, scene, FISHEYE).choice
    assert choice.kind == "exact"
    why = dict(choice.considered)[f"learned model {FISHEYE}"]
    assert "film radius 13.4 mm < the scene's 15.6 mm" in why
