"""The add-on's tests build small random models without the trainer (tests/neural/synthetic.py
must run where torch is not): what they copy of the trainer must stay the trainer's."""

import pytest

pytest.importorskip("torch", reason="the trainer needs torch (the project's Python 3.11 "
                    "environment, .venv)")

from tests.neural.synthetic import sparse_skip_terms  # noqa: E402
from trainer.mlp import sparse_skip_terms as trainer_terms  # noqa: E402


@pytest.mark.parametrize("d_in,degree,w_column", [(4, 2, 3), (5, 2, 3), (5, 3, 3), (5, 4, 3),
                                                  (6, 3, 4), (6, 4, 4), (5, 3, 4)])
def test_synthetic_sparse_skip_is_the_trainers(d_in, degree, w_column):
    """synthetic.sparse_skip_terms lists the trainer's sparse skip monomials, in its order, for
    radial (w at column 3) and cartesian (column 4) stages, with and without the wavelength."""
    assert sparse_skip_terms(d_in, degree, w_column) == trainer_terms(d_in, degree, w_column)
