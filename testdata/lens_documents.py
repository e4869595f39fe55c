"""Lens-file documents for tests and benchmarks: a valid prescription, a small TOML writer,
and a fuzzer of damaged documents.

base_doc()       a valid 4-surface lens as a dict (front stop, cemented doublet, a conic
                 asphere last), in the fields of docs/lens-format.md;
to_toml(doc)     the dict as TOML text (surfaces as [[surface]] tables when they are all
                 tables; NaN and infinities as TOML's nan / inf), enough for these documents;
fuzz_documents   a hypothesis strategy: base_doc() with 0-4 random edits (a key set to a
                 random value, deleted, a surface edited, duplicated or deleted) and, one time
                 in four, up to 20 characters of the TOML text replaced by TOML punctuation.
"""

from __future__ import annotations

import copy
import json
import math

from hypothesis import strategies as st


def base_doc():
    """Front stop, cemented doublet; the last surface is a mild conic asphere."""
    return {
        "name": "test doublet",
        "source": "tests (made up)",
        "focal_length_mm": 50.0,
        "f_number": 4.0,
        "field_of_view_deg": 30.0,
        "notes": "a \"quoted\" note\nwith two lines",
        "surface": [
            {"radius": "flat", "thickness": 3.0, "material": "air", "semi_diameter": 6.0,
             "stop": True},
            {"radius": 30.0, "thickness": 6.0, "material": {"nd": 1.6, "vd": 55.0},
             "semi_diameter": 10.0},
            {"radius": -25.0, "thickness": 2.0, "material": {"nd": 1.7, "vd": 30.0},
             "semi_diameter": 10.0},
            {"radius": -120.0, "thickness": 40.0, "material": "air", "semi_diameter": 10.0,
             "conic": -1.0, "aspheric": {"a4": 1e-6, "a6": -2e-9}},
        ],
    }


def toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}"
                                for k, x in v.items()) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(v)


def to_toml(doc):
    lines = []
    surfaces = doc.get("surface", None)
    tables = isinstance(surfaces, list) and surfaces and all(isinstance(s, dict) for s in surfaces)
    for k, v in doc.items():
        if k == "surface" and tables:
            continue
        lines.append(f"{json.dumps(str(k))} = {toml_value(v)}")
    if tables:
        for s in surfaces:
            lines += ["", "[[surface]]"] + [f"{json.dumps(str(k))} = {toml_value(v)}"
                                            for k, v in s.items()]
    return "\n".join(lines) + "\n"


KEYS = ["name", "source", "focal_length_mm", "f_number", "field_of_view_deg", "scale", "notes",
        "surface", "radius", "thickness", "material", "semi_diameter", "conic", "aspheric",
        "stop", "nd", "vd", "a4", "a3", "a22", "radus", "foo"]
scalars = st.one_of(
    st.booleans(), st.integers(-10, 10), st.integers(), st.floats(),
    st.floats(-100, 100), st.sampled_from([0.0, -0.0, 1e308, -1e-300, 1e-320]),
    st.sampled_from(["flat", "air", "N-BK7", "inf", "", "unknown glass", "nan"]),
    st.text(max_size=8))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=3),
    st.dictionaries(st.sampled_from(KEYS), inner, max_size=3)), max_leaves=8)


@st.composite
def fuzz_documents(draw):
    doc = base_doc()
    if draw(st.booleans()):
        doc["scale"] = draw(st.sampled_from([1.0, 0.5, 2, 1e-3]))
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.integers(0, 5))
        surfaces = doc.get("surface")
        if kind == 0:
            doc[draw(st.sampled_from(KEYS))] = draw(values)
        elif kind == 1 and doc:
            del doc[draw(st.sampled_from(sorted(doc)))]
        elif isinstance(surfaces, list) and surfaces and all(isinstance(s, dict) for s in surfaces):
            i = draw(st.integers(0, len(surfaces) - 1))
            if kind == 2:
                surfaces[i][draw(st.sampled_from(KEYS))] = draw(values)
            elif kind == 3 and surfaces[i]:
                del surfaces[i][draw(st.sampled_from(sorted(surfaces[i])))]
            elif kind == 4:
                surfaces.insert(i, copy.deepcopy(surfaces[draw(st.integers(0, len(surfaces) - 1))]))
            else:
                del surfaces[i]
    text = to_toml(doc)
    if draw(st.integers(0, 3)) == 0:  # text-level damage
        a = draw(st.integers(0, len(text)))
        b = draw(st.integers(a, min(len(text), a + 20)))
        text = text[:a] + draw(st.text(alphabet="[]{}=\"'.,#\n 0123456789abe-+", max_size=6)) \
            + text[b:]
    return text
