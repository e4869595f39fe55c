"""Hostile model directories: FIFOs, devices, oversize files, non-finite numbers, deep nesting
and random damage get one ModelError naming the file, never a hang or another exception."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

from neurolens_addon.core.errors import ModelError
from neurolens_addon.neural.modelfile import read_header, read_model_json
from testdata.deadline import finishes
from testdata.model_documents import SOURCE, fuzz_model_documents, write_model

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def model_copy(tmp_path):
    out = tmp_path / "m.neurolens"
    shutil.copytree(SOURCE, out)
    return out


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name", ["model.json", "forward.onnx"])
def test_01_a_fifo_in_a_model_is_refused_without_blocking(model_copy, name):
    """A FIFO named model.json or forward.onnx: a ModelError saying it is a FIFO, at once
    (opening it for reading used to block forever)."""
    pytest.importorskip("onnxruntime")
    from neurolens_addon.neural.model import LearnedLens
    target = model_copy / name
    target.unlink()
    os.mkfifo(target)
    with pytest.raises(ModelError, match="FIFO"):
        finishes(lambda: LearnedLens.load(model_copy))


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_02_a_link_to_an_endless_device_is_refused(model_copy):
    """model.json linked to /dev/zero: refused as a device, nothing read."""
    (model_copy / "model.json").unlink()
    (model_copy / "model.json").symlink_to("/dev/zero")
    with pytest.raises(ModelError, match="device"):
        finishes(lambda: read_header(model_copy))


def test_03_an_oversize_model_json_is_refused_before_reading(model_copy, monkeypatch):
    """A model.json over the size limit is refused naming the limit."""
    from neurolens_addon.neural import modelfile
    monkeypatch.setattr(modelfile, "MAX_MODEL_JSON_BYTES", 1000)
    with pytest.raises(ModelError, match="limit"):
        read_header(model_copy)


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_04_nan_and_infinity_literals_are_refused(model_copy, literal):
    """JSON has no NaN or Infinity; Python's reader accepts them, this one refuses them."""
    meta = json.loads((model_copy / "model.json").read_text())
    text = json.dumps(meta).replace('"film_radius_mm": ' + json.dumps(
        meta["domain"]["film_radius_mm"]), f'"film_radius_mm": {literal}')
    (model_copy / "model.json").write_text(text)
    with pytest.raises(ModelError, match=literal.lstrip("-")):
        read_header(model_copy)


@pytest.mark.parametrize("field,value,match", [
    (("domain", "film_radius_mm"), 1e300, "domain.film_radius_mm"),
    (("domain", "wavelength_range_nm"), [10.0, 20.0], "domain.wavelength_range_nm"),
    (("planes", "stop_z"), 1e300, "planes.stop_z"),
    (("evaluation", "image_error_um_p99"), -1.0, "evaluation.image_error_um_p99"),
    (("evaluation", "onnx_rays_per_s"), "fast", "evaluation.onnx_rays_per_s"),
    (("theta",), 2 ** 40, "theta"),
])
def test_05_numbers_out_of_their_physical_range_name_the_field(model_copy, field, value, match):
    """Finite but impossible numbers, and wrong types in the recorded evaluation, are refused
    naming the field."""
    meta = json.loads((model_copy / "model.json").read_text())
    d = meta
    for k in field[:-1]:
        d = d.setdefault(k, {})
    d[field[-1]] = value
    (model_copy / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ModelError, match=match.replace(".", r"\.")):
        read_model_json(model_copy)


def test_06_deep_nesting_is_one_error(model_copy):
    """A model.json nested 100 000 levels deep: a ModelError, not a RecursionError."""
    (model_copy / "model.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ModelError, match="nested too deeply"):
        read_header(model_copy)


@settings(max_examples=150, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(text=fuzz_model_documents())
def test_07_fuzz_model_json_gives_a_model_or_a_model_error(tmp_path_factory, text):
    """Random damage to a real model.json: read_model_json returns the model or raises one
    ModelError naming the file; any other exception fails."""
    d = write_model(tmp_path_factory.mktemp("fuzz") / "f.neurolens", text)
    try:
        directory, meta, guards, files = read_model_json(d)
    except ModelError as exc:
        assert "model.json" in str(exc)
        return
    assert isinstance(meta, dict) and len(guards) == 2 and files
