"""neural.modelfile: the checked header reader, its stat cache, and model discovery (only
model.json is read, so these models need no ONNX graphs)."""

from __future__ import annotations

import json
import os

import pytest

from neurolens_addon.core.errors import ModelError
from neurolens_addon.neural import modelfile as mf
from tests.neural.synthetic import make_model

EVALUATION = {"image_error_um_p99": 2.5, "onnx_rays_per_s": 3.0e6, "provider": "CPU"}


def _model(directory, lens_hash="a" * 16, **extra):
    directory.mkdir(parents=True)
    meta = {**make_model(lens_hash=lens_hash, cells=(1, 1)), **extra}
    (directory / mf.MODEL_FILE).write_text(json.dumps(meta))
    return directory


def test_01_header_fields_and_stat_cache(tmp_path):
    """The header carries what choosing a model needs; a second read is a cache hit; a
    rewritten model.json (new size) is read again."""
    d = _model(tmp_path / "m.neurolens", evaluation=EVALUATION)
    h = mf.read_header(d)
    assert h.directory == d and h.name == "m.neurolens" and h.lens_name == "synthetic"
    assert h.lens_content_hash == "a" * 16 and h.dispersion is True
    assert h.sensor_z_range == (-1.0, 0.0) and h.film_radius_mm == 18.0
    assert h.wavelength_range_nm == (400.0, 760.0) and h.domain["film_radius_mm"] == 18.0
    assert h.image_error_um_p99 == 2.5 and h.onnx_rays_per_s == 3.0e6
    assert mf.read_header(d / mf.MODEL_FILE) is h                   # its model.json: same
    meta = json.loads((d / mf.MODEL_FILE).read_text())
    del meta["evaluation"]
    (d / mf.MODEL_FILE).write_text(json.dumps(meta))
    h2 = mf.read_header(d)
    assert h2.evaluation is None and h2.image_error_um_p99 is None and h2.onnx_rays_per_s is None


@pytest.mark.parametrize("edit, pattern", [
    (lambda m: m["domain"].pop("film_radius_mm"), r"field 'domain\.film_radius_mm': missing"),
    (lambda m: m["lens"].update(content_hash=7), r"field 'lens\.content_hash'.*a string"),
    (lambda m: m.update(version=2), r"field 'version'.*not supported"),
    (lambda m: m.update(evaluation={"image_error_um_p99": "small"}),
     r"field 'evaluation\.image_error_um_p99'.*a number"),
])
def test_02_header_errors_name_the_file_and_field(tmp_path, edit, pattern):
    d = tmp_path / "bad.neurolens"
    d.mkdir()
    meta = make_model(cells=(1, 1))
    edit(meta)
    (d / mf.MODEL_FILE).write_text(json.dumps(meta))
    with pytest.raises(ModelError, match=pattern) as e:
        mf.read_header(d)
    assert "bad.neurolens" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ModelError, match="no model.json"):
        mf.read_header(tmp_path / "missing.neurolens")


def test_03_model_dirs_lists_each_model_once(tmp_path):
    """Model directories and folders of *.neurolens, each model once, in candidate order
    (a folder's in path order); missing candidates, None, folders without model.json and
    other files are passed over; the stat key follows model.json."""
    folder = tmp_path / "models"
    b = _model(folder / "b.neurolens")
    a = _model(folder / "a.neurolens")
    (folder / "partial.neurolens").mkdir()                     # no model.json: not a model
    (folder / "notes.txt").write_text("x")
    single = _model(tmp_path / "single.neurolens")
    found = mf.model_dirs([single, None, tmp_path / "nowhere", folder, a, str(folder)])
    assert [p for p, _ in found] == [single, a, b]
    st = os.stat(a / mf.MODEL_FILE)
    assert found[1][1] == (str(a / mf.MODEL_FILE), st.st_mtime_ns, st.st_size)
    assert mf.model_dirs([]) == [] and mf.model_dirs([tmp_path / "nowhere"]) == []


def test_04_find_model_by_lens_hash(tmp_path):
    """The model made for the lens (the most accurate of several); unreadable models are
    passed over."""
    folder = tmp_path / "models"
    broken = folder / "a_broken.neurolens"
    broken.mkdir(parents=True)
    (broken / mf.MODEL_FILE).write_text("{not json")
    _model(folder / "b_other.neurolens", lens_hash="b" * 16)
    mine = _model(folder / "c_mine.neurolens", lens_hash="c" * 16)
    h = mf.find_model("c" * 16, [tmp_path / "nowhere", folder])
    assert h is not None and h.directory == mine
    assert mf.find_model("d" * 16, [folder]) is None
    # of several made for one lens, the most accurate; one never evaluated comes last
    _model(folder / "a_mine_lean.neurolens", lens_hash="c" * 16,
           evaluation={**EVALUATION, "image_error_um_p99": 27.0})
    best = _model(folder / "d_mine_best.neurolens", lens_hash="c" * 16,
                  evaluation={**EVALUATION, "image_error_um_p99": 2.0})
    assert mf.find_model("c" * 16, [folder]).directory == best
