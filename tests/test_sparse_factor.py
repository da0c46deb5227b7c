"""The tangent's sparse Cholesky factor (rtsim.mbs.sparse) against dense numpy linear algebra."""
from __future__ import annotations

import numpy as np
import pytest

from rtsim.mbs import envelope, sparse
from test_envelope import random_spd


def _layout(a: np.ndarray, ordering: str) -> dict:
    n = a.shape[0]
    pairs = np.argwhere(a != 0.0)
    perm = sparse.minimum_degree(n, pairs) if ordering == "min_degree" else envelope.symbolic(n, pairs)[0]
    return sparse.symbolic(n, pairs, perm)


def _values(a: np.ndarray, s: dict) -> np.ndarray:
    return np.array([a[s["perm"][r], s["perm"][c]] for r, c in zip(s["rowidx"], s["pcol"])])


@pytest.mark.parametrize("ordering", ["min_degree", "rcm"])
@pytest.mark.parametrize("n, density, seed", [(1, 1.0, 0), (7, 0.3, 2), (30, 0.08, 3), (60, 0.05, 4), (120, 0.02, 5)])
def test_factor_and_solve_match_dense(n, density, seed, ordering):
    a = random_spd(n, density, seed)
    s = _layout(a, ordering)
    assert sorted(s["perm"]) == list(range(n))
    l_val = np.zeros(s["rowidx"].size)
    work = np.zeros(n)
    assert sparse.cholesky(_values(a, s), s["colptr"], s["rowidx"], s["uptr"], s["upos"], s["uend"], l_val, work) == -1
    dense = np.zeros((n, n))
    dense[s["rowidx"], s["pcol"]] = l_val
    diag = s["colptr"][:-1]
    assert np.all(s["rowidx"][diag] == np.arange(n))
    dense[np.arange(n), np.arange(n)] = 1.0 / l_val[diag]       # stored inverted
    ap = a[np.ix_(s["perm"], s["perm"])]
    scale = np.max(np.abs(a))
    np.testing.assert_allclose(dense, np.linalg.cholesky(ap), rtol=0, atol=1e-12 * np.sqrt(scale))
    b = np.random.default_rng(seed).uniform(-1.0, 1.0, n)
    x = np.zeros(n)
    sparse.solve(l_val, s["colptr"], s["rowidx"], s["perm"], s["pinv"], b, x, work)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)


def test_fill_in_stays_in_pattern_and_not_positive_definite_is_reported():
    # an arrow matrix: eliminating the hub first would fill everything; minimum degree keeps it last
    n = 12
    a = 4.0 * np.eye(n)
    a[0, 1:] = a[1:, 0] = 1.0
    s = _layout(a, "min_degree")
    assert 0 in s["perm"][-2:] and s["rowidx"].size == 2 * n - 1   # no fill-in
    a[5, 5] = -1.0
    row = sparse.cholesky(_values(a, s), s["colptr"], s["rowidx"], s["uptr"], s["upos"], s["uend"],
                          np.zeros(s["rowidx"].size), np.zeros(n))
    assert s["perm"][row] == 5
