"""numpy 1.26 (Blender 5.0) and numpy 2 (Blender 5.2 LTS) behave alike for the add-on: the
trapezoid rule through core.np_compat, and no project code calling what numpy 2 removed
(this runs under numpy 1.26 too, where those names still work, so it fails there first)."""

import re
from pathlib import Path

import numpy as np

from neurolens_addon.core.np_compat import trapezoid

ROOT = Path(__file__).resolve().parents[2]
#: numpy 1 names numpy 2 removed (NumPy 2.0 migration guide; np.trapz later in 2.x)
REMOVED = ("trapz", "in1d", "row_stack", "product", "cumproduct", "sometrue", "alltrue",
           "float_", "complex_", "longfloat", "singlecomplex", "cfloat", "Inf", "Infinity",
           "NaN", "NINF", "PINF", "NZERO", "PZERO", "infty", "round_", "asfarray", "msort",
           "find_common_type", "cast", "mat", "unicode_", "string_", "issubclass_",
           "set_string_function", "safe_eval", "recfromcsv", "recfromtxt", "deprecate",
           "disp", "who", "source", "lookfor", "byte_bounds", "compare_chararrays",
           "format_parser", "fastCopyAndTranspose", "tracemalloc_domain")
CALL = re.compile(r"\b(?:np|numpy)\.(" + "|".join(REMOVED) + r")\b(?!\w)|\bnumpy\.core\b")
FOLDERS = ("neurolens_addon", "trainer", "onnx_export", "tests", "benchmarks", "scripts",
           "testdata", "presets")


def test_01_trapezoid_is_the_trapezoid_rule_on_this_numpy():
    """On an uneven grid, along either axis and with a step, trapezoid() is the sum of the
    trapezoids written out by hand (numpy 1.26 through np.trapz, numpy 2 np.trapezoid)."""
    x = np.array([0.0, 0.5, 1.5, 1.75, 3.0])
    y = np.stack([x ** 2, np.sin(x)], axis=1)                    # (5, 2)
    by_hand = (0.5 * (y[1:] + y[:-1]) * np.diff(x)[:, None]).sum(axis=0)
    np.testing.assert_allclose(trapezoid(y, x, axis=0), by_hand, rtol=1e-15)
    np.testing.assert_allclose(trapezoid(y.T, x), by_hand, rtol=1e-15)
    assert trapezoid([1.0, 3.0, 5.0], dx=0.5) == 0.5 * (2.0 + 4.0)
    assert trapezoid is getattr(np, "trapezoid", getattr(np, "trapz", None))


def test_02_no_project_code_calls_what_numpy_2_removed():
    """No Python file of the project calls a numpy name numpy 2 removed (np.trapz, np.in1d,
    np.product, np.NaN, ...), core.np_compat aside: the add-on must run on Blender 5.0's
    numpy 1.26 and 5.2's numpy 2."""
    shim = ROOT / "neurolens_addon" / "core" / "np_compat.py"
    bad = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path == shim or path == Path(__file__).resolve():
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                code = line.split("#", 1)[0]
                if CALL.search(code):
                    bad.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not bad, "\n".join(bad)


def test_03_the_check_sees_a_removed_name():
    """The pattern of test_02 finds what it looks for (and not longer names that merely start
    the same, such as np.product_like or np.NaNs)."""
    assert CALL.search("y = np.trapz(a, b)") and CALL.search("np.in1d(a, b)")
    assert CALL.search("x = numpy.NaN") and CALL.search("import numpy.core.multiarray")
    assert not CALL.search("np.trapezoid(a)") and not CALL.search("np.isin(a, b)")
    assert not CALL.search("np.nan + np.inf") and not CALL.search("np.matmul(a, b)")
