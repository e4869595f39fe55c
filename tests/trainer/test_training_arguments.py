"""The panel's "Train a model for this scene" hands the trainer the scene's needs as options
(scene_needs_bpy.cli_arguments); `python -m trainer fit-scene` must read back the very same
RenderNeeds, or the model it trains covers another film than the one rendered."""

from __future__ import annotations

import pytest

from neurolens_addon.blender.scene_needs_bpy import cli_arguments
from neurolens_addon.core.scene_needs import RenderNeeds
from trainer.__main__ import build_parser, needs_from_args

CASES = [
    RenderNeeds(1920, 1080, 36.0, 24.0),
    RenderNeeds(1001, 333, 23.5, 15.6, "VERTICAL", 37.0, (0.1, 0.2, 0.9, 0.7), (2.8, 5.6),
                (1.25, 7.0), False, 0.25),
    RenderNeeds(640, 480, 8.0, 6.0, "HORIZONTAL", 200.0, pixel_aspect_x=2.0, shift_x=0.1,
                shift_y=-0.05),
]


@pytest.mark.parametrize("needs", CASES)
def test_fit_scene_reads_back_the_needs_the_panel_writes(needs):
    argv = ["fit-scene", "lens.toml", "--models-dir", "models", *cli_arguments(needs)]
    back = needs_from_args(build_parser().parse_args(argv))
    assert back.as_dict() == needs.as_dict()
    assert back.film() == needs.film()
