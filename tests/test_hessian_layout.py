"""The Hessian layout's scatters add into a few slots what a whole-length
bincount (or product with a sparse matrix) would, bit for bit."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from plush_opt.fem.hessian_layout import _RowScatter, _Scatter


def test_a_scatter_adds_what_a_whole_length_bincount_adds_bit_for_bit():
    rng = np.random.default_rng(0)
    slots = rng.integers(0, 50, size=400) * 7          # repeated slots, scattered over a long array
    weights = rng.standard_normal(400) * 10.0 ** rng.integers(-8, 8, size=400)
    data = rng.standard_normal(400)
    expected = data + np.bincount(slots, weights=weights, minlength=len(data))
    got = data.copy()
    _Scatter(slots).add(got, weights)
    assert np.array_equal(got, expected)
    assert _Scatter(slots).size == 400


def test_a_row_scatter_adds_what_the_whole_product_adds_bit_for_bit():
    rng = np.random.default_rng(1)
    S = sp.random(300, 40, density=0.02, random_state=2, format="csr")
    S = sp.vstack([S, sp.csr_matrix((50, 40))], format="csr")       # rows without entries too
    v = rng.standard_normal(40) * 10.0 ** rng.integers(-8, 8, size=40)
    data = rng.standard_normal(350)
    expected = data + S @ v
    got = data.copy()
    _RowScatter(S).add(got, v)
    assert np.array_equal(got, expected)
