"""The committed model of every preset loads for that prescription and agrees with it."""

from pathlib import Path

import numpy as np
import pytest

from neurolens_addon.core.irf import propagate_to_z
from neurolens_addon.core.lensfile import load_lens
from neurolens_addon.core.trace import trace
from neurolens_addon.neural.model import LearnedLens
from trainer.data import default_domain
from trainer.evaluate import camera_rays_at_focus

ROOT = Path(__file__).resolve().parents[2]
PRESETS = sorted((ROOT / "presets" / "lenses").glob("*.toml"))


@pytest.mark.parametrize("path", PRESETS, ids=[p.stem for p in PRESETS])
def test_01_every_preset_has_a_model_that_matches_it(path):
    """presets/models/NAME.neurolens loads for its prescription (same content hash); on 4000
    camera rays focused at 2 m it agrees with the exact trace on validity for >= 94 % of rays
    (the occupancy grid's boundary cells pass some rays the lens vignettes: docs/learned-lenses.md)
    and, where both pass, the median position error on Pi_2 is under 50 um and the median
    direction error under 5e-5 (a regression guard; BENCHMARKS.md has the measured figures)."""
    lens = load_lens(path)
    model = LearnedLens.load(ROOT / "presets" / "models" / f"{path.stem}.neurolens", lens=lens)
    rays, z_s = camera_rays_at_focus(lens, default_domain(lens), 4000, 2000.0, seed=7)
    ex = trace(lens, rays)
    le = model.trace_from_sensor(rays, sensor_z=z_s)
    assert (ex.valid == le.valid).mean() >= 0.94
    v = ex.valid & le.valid
    eo = propagate_to_z(ex.rays.o[:, v], ex.rays.d[:, v], model.planes["output_z"])
    assert np.median(np.hypot(*(eo[:2] - le.rays.o[:2, v]))) < 0.05
    assert np.median(np.linalg.norm(ex.rays.d[:, v] - le.rays.d[:, v], axis=0)) < 5e-5
