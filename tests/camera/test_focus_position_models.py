"""Models per focus position: a lens with focusing groups uses the model trained with its
groups where it stands (scripts/train_presets.py), and the exact trace between positions."""

from __future__ import annotations

import math

import numpy as np

from neurolens_addon.camera import CameraSettings, resolve_camera
from neurolens_addon.camera.lenses import PRESET_MODELS_DIR, PRESETS_DIR, load_lens_entry


def settings(**kw) -> CameraSettings:
    return CameraSettings(**dict(dict(camera="Cam", model="exact", f_number=4.0,
                                      focus_distance_mm=3000.0), **kw))


def texts(setup) -> str:
    return " | ".join(t for _level, t in setup.messages)



def test_a_focusing_preset_uses_its_close_focus_model_there_and_the_exact_trace_between():
    """A lens with focusing groups ships a model per tabulated close distance: focused there
    the learned lens is that model (trained with the groups where the patent puts them),
    at infinity the infinity model, between the two the exact trace, saying why."""
    stem = "macro_100mm_f2_8"
    path = str(PRESETS_DIR / f"{stem}.toml")
    lens = load_lens_entry(path).lens
    candidates = (str(PRESET_MODELS_DIR),)

    def at(distance_mm):
        return resolve_camera(settings(lens_path=path, lens_id=stem, model="learned",
                                       f_number=4.0, focus_distance_mm=distance_mm,
                                       model_candidates=candidates))
    def most_accurate(tag):
        """The position's model with the lowest recorded p99 (the full or the sparse one)."""
        from neurolens_addon.neural.modelfile import read_header
        dirs = [PRESET_MODELS_DIR / f"{stem}{tag}.neurolens",
                PRESET_MODELS_DIR / f"{stem}{tag}.sparse.neurolens"]
        return min((d for d in dirs if d.is_dir()),
                   key=lambda d: read_header(d).image_error_um_p99).name
    for d in lens.focus_gaps.positions[1:]:
        setup = at(float(np.float32(d / 1000.0)) * 1000.0)     # as Blender stores it
        assert setup.model == "learned", texts(setup)
        assert setup.model_dir.endswith(most_accurate(f".focus{d:g}mm"))
        assert setup.lens.content_hash() == setup.model_info.lens_content_hash
    assert at(math.inf).model_dir.endswith(most_accurate(""))
    between = at(0.5 * (lens.focus_gaps.positions[1] + lens.focus_gaps.positions[2]))
    assert between.model == "exact" and "moves this lens's focusing groups" in texts(between)


def test_automatic_between_focus_positions_counts_no_model_of_the_infinity_lens():
    """Automatic between two tabulated focus distances: the lens's models know it focused at
    infinity (their groups elsewhere), so none renders the frame, and the choice lists each
    as not qualifying, for that reason (not just the one it first picked)."""
    stem = "macro_100mm_f2_8"
    path = str(PRESETS_DIR / f"{stem}.toml")
    lens = load_lens_entry(path).lens
    between = 0.5 * (lens.focus_gaps.positions[1] + lens.focus_gaps.positions[2])
    from neurolens_addon.core.scene_needs import RenderNeeds
    needs = RenderNeeds(1920, 1080, 36.0, 24.0, f_numbers=(4.0,),
                        focus_distances_m=(between / 1000.0,))
    setup = resolve_camera(settings(lens_path=path, lens_id=stem, model="auto",
                                    focus_distance_mm=between, needs=needs,
                                    model_candidates=(str(PRESET_MODELS_DIR),)))
    assert setup.model == "exact"
    learned = [(name, why) for name, why in setup.choice.considered
               if name.startswith("learned model")]
    assert len(learned) >= 2                     # the full and the sparse model
    assert all(why for _name, why in learned), learned
    assert any("infinity focus" in why for _name, why in learned)


def test_a_named_model_of_another_position_gives_way_to_the_exact_trace_with_a_warning():
    """A model directory named for the camera (LEARNED, a path) that learned this lens at
    another tabulated position is not an error: the exact trace renders, and says why."""
    stem = "macro_100mm_f2_8"
    path = str(PRESETS_DIR / f"{stem}.toml")
    one_to_one = str(PRESET_MODELS_DIR / f"{stem}.focus297.67mm.neurolens")
    infinity = str(PRESET_MODELS_DIR / f"{stem}.neurolens")
    half = resolve_camera(settings(lens_path=path, lens_id=stem, model="learned",
                                   model_dir=one_to_one, focus_distance_mm=380.8))
    assert half.model == "exact" and "another focus position (297.67 mm)" in texts(half)
    near = resolve_camera(settings(lens_path=path, lens_id=stem, model="learned",
                                   model_dir=infinity, focus_distance_mm=297.67))
    assert near.model == "exact" and "focused at infinity" in texts(near)
    there = resolve_camera(settings(lens_path=path, lens_id=stem, model="learned",
                                    model_dir=one_to_one, focus_distance_mm=297.67))
    assert there.model == "learned" and there.model_dir == one_to_one
