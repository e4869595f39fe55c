"""Broken model.json documents for fuzzing (tests and the robustness benchmark).

`fuzz_model_documents()` is a hypothesis strategy of model.json texts made from a real shipped
model (the lean double Gauss, the smallest): random edits at random key paths (a value
replaced by one of another type or range, a key deleted, a list emptied or lengthened, a value
nested a thousand levels deep), written back as JSON, then sometimes damaged as text (NaN and
Infinity literals, a cut, stray bytes). `write_model(dir, text)` makes a model directory with
that model.json beside the real graphs.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "presets" / "models" / "double_gauss_50mm_f2.lean.neurolens"

_BASE: dict | None = None


def base_model() -> dict:
    global _BASE
    if _BASE is None:
        _BASE = json.loads((SOURCE / "model.json").read_text())
    return copy.deepcopy(_BASE)


def _paths(doc, prefix=(), depth=0):
    """Key paths into the document (a sample of them in long lists, to depth 7)."""
    yield prefix
    if depth >= 7:
        return
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,), depth + 1)
    elif isinstance(doc, list) and doc:
        for i in sorted({0, len(doc) // 2, len(doc) - 1}):
            yield from _paths(doc[i], prefix + (i,), depth + 1)


def _deep(n: int):
    v = 0
    for _ in range(n):
        v = [v]
    return v


VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-2 ** 70, 2 ** 70),
    st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([0, -1, 1e308, -1e-308]),
    st.text(max_size=8), st.sampled_from(["\n#define x 1", "a\x00b", "../../etc"]),
    st.lists(st.integers(-3, 3), max_size=4), st.dictionaries(st.text(max_size=3),
                                                              st.integers(), max_size=2),
    st.just("DEEP"))


@st.composite
def fuzz_model_documents(draw) -> str:
    doc = base_model()
    paths = list(_paths(doc))[1:]
    for _ in range(draw(st.integers(1, 4))):
        path = draw(st.sampled_from(paths))
        parent = doc
        try:
            for k in path[:-1]:
                parent = parent[k]
            key = path[-1]
            kind = draw(st.integers(0, 3))
            if kind == 0:
                v = draw(VALUES)
                parent[key] = _deep(1000) if v == "DEEP" else v
            elif kind == 1:
                del parent[key]
            elif kind == 2 and isinstance(parent[key], list):
                parent[key] = parent[key][:draw(st.integers(0, 2))]
            elif kind == 3 and isinstance(parent[key], list) and parent[key]:
                parent[key] = parent[key] + parent[key][:1] * draw(st.integers(1, 3))
        except (KeyError, IndexError, TypeError):
            continue
    text = json.dumps(doc)
    damage = draw(st.integers(0, 5))
    if damage == 0:
        number = draw(st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999"]))
        at = text.find(": ", draw(st.integers(0, max(len(text) - 1, 0))))
        if at >= 0:
            end = at + 2
            while end < len(text) and text[end] in "-0123456789.eE":
                end += 1
            if end > at + 2:
                text = text[:at + 2] + number + text[end:]
    elif damage == 1:
        text = text[:draw(st.integers(0, len(text)))]
    elif damage == 2:
        a = draw(st.integers(0, len(text)))
        text = text[:a] + draw(st.text(alphabet="[]{}:,\"\\0123456789e-.", max_size=6)) + text[a:]
    return text


def write_model(directory: Path, text: str) -> Path:
    """A model directory holding `text` as model.json and the real graphs beside it."""
    directory.mkdir(parents=True, exist_ok=True)
    for f in SOURCE.glob("*.onnx"):
        target = directory / f.name
        if not target.exists():
            shutil.copyfile(f, target)
    (directory / "model.json").write_text(text)
    return directory
