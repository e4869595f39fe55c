"""The learned Cycles camera on a model the trainer writes with the sparse skip basis (a
trainer-side test: it trains the model; tests/cycles/ holds the camera's own)."""

from __future__ import annotations

import pytest

pytest.importorskip("bpy")

from neurolens_addon.cycles import CameraSpec  # noqa: E402
from tests.cycles.test_render import (  # noqa: E402
    assert_learned_probes_equal_the_onnx_model, lens)


@pytest.mark.slow
def test_01_a_sparse_skip_model_renders_its_onnx_rays_in_cycles(tmp_path):
    """A model of the sparse skip basis (mirror-symmetric monomials, the wavelength as
    mu = (550 nm / lambda)^2: `trainer fit --skip-basis sparse`), trained small on the Cooke
    triplet: the OSL learned camera (each output's terms a range of the monomials) reproduces
    the model's ONNX evaluation ray for ray as tests/cycles/test_render.py's test_11 does for
    the full basis, directions to 3e-5 (the ONNX graph sums the sparse skip factored by its
    multipliers, the shader term by term: float32 sums in another order; measured 1.2e-5 at
    most)."""
    pytest.importorskip("onnxruntime")
    import json

    from neurolens_addon.cycles import generate_osl
    from trainer.fit import FitConfig
    from trainer.pipeline import fit_lens
    L = lens("cooke_triplet_f4")
    out = tmp_path / "sparse.neurolens"
    fit_lens(L, out, FitConfig(skip_basis="sparse", skip_degree=4, max_depth=0),
             n_rays=20_000, log=lambda *a: None)
    meta = json.loads((out / "model.json").read_text())
    assert all("skip_terms" in m for st in meta["stages"] for c in st.get("cells", ())
               for m in c["members"])
    spec = CameraSpec("learned", lens=L, model_dir=str(out), sensor_z_mm=0.0,
                      dispersion=True, sensor_width_mm=24.0, sensor_height_mm=16.0,
                      probe_sample=(0.3, 0.6))
    assert "COEF[" in generate_osl(spec) and "LIN[" not in generate_osl(spec)
    assert_learned_probes_equal_the_onnx_model(spec, tmp_path, direction_atol=3e-5)
