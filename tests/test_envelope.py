"""Envelope (skyline) storage and Cholesky factorization against dense numpy linear algebra."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

from rtsim.mbs import envelope


def random_symmetric(n: int, density: float, seed: int) -> np.ndarray:
    """A random sparse symmetric matrix with a full diagonal (dense storage)."""
    rng = np.random.default_rng(seed)
    a = scipy.sparse.random(n, n, density=density, random_state=rng,
                            data_rvs=lambda k: rng.uniform(-1.0, 1.0, k)).toarray()
    a = a + a.T
    a[np.diag_indices(n)] += rng.uniform(-1.0, 1.0, n)
    return a


def random_spd(n: int, density: float, seed: int, min_eig: float = 0.5) -> np.ndarray:
    """Shift the spectrum (not to diagonal dominance) so that the smallest eigenvalue is min_eig."""
    a = random_symmetric(n, density, seed)
    return a + (min_eig - np.linalg.eigvalsh(a)[0]) * np.eye(n)


def layout(a: np.ndarray):
    pairs = np.argwhere(a != 0.0)
    return envelope.symbolic(a.shape[0], pairs)


def dense_factor(l_env, first, ptr) -> np.ndarray:
    """The envelope factor as a dense lower-triangular matrix in permuted indices."""
    n = first.shape[0]
    out = np.zeros((n, n))
    for r in range(n):
        out[r, first[r]:r + 1] = l_env[ptr[r]:ptr[r + 1]]
    return out


CASES = [(1, 1.0, 0), (2, 0.5, 1), (7, 0.3, 2), (30, 0.08, 3), (60, 0.05, 4), (120, 0.02, 5)]


@pytest.mark.parametrize("n, density, seed", CASES)
def test_symbolic_layout_covers_pattern(n, density, seed):
    a = random_spd(n, density, seed)
    perm, pinv, first, ptr = layout(a)
    assert sorted(perm) == list(range(n))
    np.testing.assert_array_equal(pinv[perm], np.arange(n))
    assert np.all(first <= np.arange(n)) and np.all(first >= 0)
    assert ptr[0] == 0 and np.all(np.diff(ptr) == np.arange(n) - first + 1)
    # every structural nonzero (in the lower triangle of the permuted matrix) is inside the envelope
    i, j = np.nonzero(a)
    r, c = np.maximum(pinv[i], pinv[j]), np.minimum(pinv[i], pinv[j])
    assert np.all(first[r] <= c)
    # to_envelope / from_envelope round trip is exact
    env = envelope.to_envelope(a, first, ptr, perm)
    assert env.shape == (ptr[n],)
    np.testing.assert_array_equal(envelope.from_envelope(env, first, ptr, perm), a)


@pytest.mark.parametrize("n, density, seed", CASES)
def test_cholesky_matches_numpy(n, density, seed):
    a = random_spd(n, density, seed)
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    l_env = np.zeros_like(env)
    assert envelope.cholesky(env, first, ptr, l_env) == -1
    lp = dense_factor(l_env, first, ptr)
    ap = a[np.ix_(perm, perm)]
    scale = np.max(np.abs(a))
    np.testing.assert_allclose(lp @ lp.T, ap, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(lp, np.linalg.cholesky(ap), rtol=0, atol=1e-10 * np.sqrt(scale))
    # in place (out aliasing a) gives the same factor
    inplace = env.copy()
    assert envelope.cholesky(inplace, first, ptr, inplace) == -1
    np.testing.assert_allclose(inplace, l_env, rtol=0, atol=1e-14 * np.sqrt(scale))


@pytest.mark.parametrize("n, density, seed", CASES)
def test_solve_matches_numpy(n, density, seed):
    a = random_spd(n, density, seed)
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    l_env = np.zeros_like(env)
    assert envelope.cholesky(env, first, ptr, l_env) == -1
    rng = np.random.default_rng(100 + seed)
    work = np.zeros(n)
    for _ in range(3):
        b = rng.standard_normal(n)
        expect = np.linalg.solve(a, b)
        x = np.zeros(n)
        envelope.solve(l_env, first, ptr, perm, pinv, b.copy(), x, work)
        np.testing.assert_allclose(x, expect, rtol=0, atol=1e-10 * max(1.0, np.max(np.abs(expect))))
        # b may alias x
        y = b.copy()
        envelope.solve(l_env, first, ptr, perm, pinv, y, y, work)
        np.testing.assert_allclose(y, expect, rtol=0, atol=1e-10 * max(1.0, np.max(np.abs(expect))))
        np.testing.assert_allclose(a @ x, b, rtol=0, atol=1e-10 * max(1.0, np.max(np.abs(b))))


@pytest.mark.parametrize("n, density, seed", CASES)
@pytest.mark.parametrize("scale", [1.0, -0.25])
def test_matvec_add_matches_numpy(n, density, seed, scale):
    a = random_symmetric(n, density, seed)          # any symmetric matrix, definite or not
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    rng = np.random.default_rng(200 + seed)
    x = rng.standard_normal(n)
    y0 = rng.standard_normal(n)
    y = y0.copy()
    envelope.matvec_add(env, first, ptr, perm, pinv, x, y, scale)
    np.testing.assert_allclose(y, y0 + scale * (a @ x), rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(a))) * n)


def test_add_entry_symmetric():
    a = random_spd(20, 0.15, 11)
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    i, j = np.argwhere((a != 0.0) & ~np.eye(20, dtype=bool))[0]
    envelope.add_entry(env, first, ptr, pinv, i, j, 0.5)     # one unordered pair, stored once
    envelope.add_entry(env, first, ptr, pinv, 3, 3, 2.0)
    b = a.copy()
    b[i, j] += 0.5
    b[j, i] += 0.5
    b[3, 3] += 2.0
    np.testing.assert_array_equal(envelope.from_envelope(env, first, ptr, perm), b)


def _first_failing_leading_minor(ap: np.ndarray) -> int:
    for k in range(ap.shape[0]):
        if np.linalg.eigvalsh(ap[:k + 1, :k + 1])[0] <= 0.0:
            return k
    return -1


@pytest.mark.parametrize("n, density, seed", CASES[2:])
def test_cholesky_reports_indefinite_row(n, density, seed):
    # (1) SPD except one strongly negative diagonal entry: exactly that (permuted) row fails
    a = random_spd(n, density, seed)
    i0 = n // 2
    a[i0, i0] = -1.0
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    row = envelope.cholesky(env, first, ptr, np.zeros_like(env))
    assert row >= 0
    assert row == pinv[i0] == _first_failing_leading_minor(a[np.ix_(perm, perm)])
    # (2) a generic indefinite matrix (smallest eigenvalue -1): the first non-positive leading minor
    a = random_spd(n, density, seed + 50, min_eig=-1.0)
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    row = envelope.cholesky(env, first, ptr, np.zeros_like(env))
    assert row >= 0
    assert row == _first_failing_leading_minor(a[np.ix_(perm, perm)])


def test_cholesky_zero_pivot_is_failure():
    a = np.diag([1.0, 0.0, 2.0])
    perm, pinv, first, ptr = layout(a)
    env = envelope.to_envelope(a, first, ptr, perm)
    assert envelope.cholesky(env, first, ptr, np.zeros_like(env)) == pinv[1]


def test_chain_profile_is_linear():
    """A chain (tridiagonal pattern) in scrambled order is reordered to a profile of 2n - 1 entries:
    the N-four-bar's factorization stays O(N)."""
    n = 200
    rng = np.random.default_rng(3)
    label = rng.permutation(n)
    pairs = np.array([(label[k], label[k + 1]) for k in range(n - 1)])
    perm, pinv, first, ptr = envelope.symbolic(n, pairs)
    assert ptr[n] == 2 * n - 1
