"""The compiled kernels behind LLT (and VFC) give the bits of their documented summation order.

The EM of LLT amplifies the last bits of its products into decisions, so its kernels are checked
for exact equality against references written with numpy operations whose order is fixed: elementwise
products, and ``np.cumsum`` (a running sum, one addition after the other).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numba.core.errors import TypingError

from ctxmatch_lib._numerics.simd import load4 as _load4
from ctxmatch_lib.filters._common import knn_without_self
from ctxmatch_lib.filters._em_kernels import matmul_t, solve_batched, weighted_gram, weighted_gram_t
from ctxmatch_lib.filters.llt._kernels import em_residuals, lle_solve, offset_norms
from ctxmatch_lib.filters.llt import lle_weights


def _running_sum(v: np.ndarray) -> float:
    """``((v0 + v1) + v2) + ...`` (0.0 when empty)."""
    return float(np.cumsum(v)[-1]) if len(v) else 0.0


def _gram_reference(H: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``H' diag(w) H`` in the kernels' order: entry (i, j), i <= j, sums ``(w_k H_ki) H_kj`` in four running
    sums over the rows k = 0, 1, 2, 3 mod 4 (the last K mod 4 rows appended to the first), then
    ``(s0 + s1) + (s2 + s3)``; the lower triangle mirrors the upper."""
    K, n = H.shape
    K4 = K - K % 4
    out = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            p = (w * H[:, i]) * H[:, j]
            s = [_running_sum(p[r:K4:4]) for r in range(4)]
            s[0] = _running_sum(np.r_[s[0], p[K4:]])
            out[i, j] = out[j, i] = (s[0] + s[1]) + (s[2] + s[3])
    return out


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 9])
@pytest.mark.parametrize("K", [0, 1, 3, 4, 7, 1024, 1027, 2051])
def test_weighted_gram_matches_its_summation_order(n, K):
    rng = np.random.default_rng(10 * n + K)
    # Columns of very different scales, so that another order of the same sums would round differently.
    H = rng.normal(size=(K, n)) * 10.0 ** rng.integers(-4, 5, size=n)
    w = rng.uniform(1e-5, 1.0, size=K)
    ref = _gram_reference(H, w)
    np.testing.assert_array_equal(weighted_gram(H, w), ref)
    np.testing.assert_array_equal(weighted_gram_t(np.ascontiguousarray(H.T), w), ref)


def test_weighted_gram_differs_from_a_plain_running_sum():
    # The four interleaved sums are an order of their own: on these inputs a single running sum (another
    # valid order) rounds differently, so the test above does tell orders apart.
    rng = np.random.default_rng(3)
    H = rng.normal(size=(2051, 4)) * 10.0 ** rng.integers(-4, 5, size=4)
    w = rng.uniform(size=2051)
    plain = np.array([[_running_sum((w * H[:, i]) * H[:, j]) for j in range(4)] for i in range(4)])
    assert not np.array_equal(weighted_gram(H, w), plain)


def test_lane_loads_need_a_contiguous_float64_array():
    @numba.njit
    def first_lanes(a):
        return _load4(a, 0)

    with pytest.raises(TypingError, match="contiguous 1-d float64"):
        first_lanes(np.zeros(16)[::2])
    with pytest.raises(TypingError, match="contiguous 1-d float64"):
        first_lanes(np.zeros(8, np.float32))


def _points(n, seed):
    """Points with coincident copies and a zero offset, so that signed zeros and equal rows occur."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 2)) * 10.0 ** rng.integers(-3, 3, size=(n, 1))
    x[n // 2:n // 2 + 5] = x[0]
    x[-3:, 1] = x[1, 1]
    return x


@pytest.mark.parametrize("n, k", [(2, 15), (40, 3), (300, 15)])
def test_lle_solve_is_numpys_gram_and_solve_batched(n, k):
    x = _points(n, n)
    nb = knn_without_self(x, np.arange(n), k)
    kk = nb.shape[1]
    z = x[nb] - x[:, None, :]
    gram = z[:, :, None, 0] * z[:, None, :, 0] + z[:, :, None, 1] * z[:, None, :, 1]
    trace = np.trace(gram, axis1=1, axis2=2)
    sq = offset_norms(x, nb)
    np.testing.assert_array_equal(sq, np.diagonal(gram, axis1=1, axis2=2))
    np.testing.assert_array_equal(sq.sum(1), trace)  # the trace as numpy sums it
    t = 1e-5 * np.maximum(trace, 1e-12)
    gram += t[:, None, None] * np.eye(kk)
    w, ok = lle_solve(x, nb, t)
    assert ok.all()
    np.testing.assert_array_equal(w, solve_batched(gram, np.ones((n, kk, 1)))[..., 0])


def test_lle_solve_flags_singular_systems():
    # Four coincident points without a regulariser: their local Gram matrices are zero. The others have one.
    x = np.r_[np.zeros((4, 2)), [[1.0, 0.0], [0.0, 2.0], [3.0, 1.0], [2.0, 2.0]]]
    nb = knn_without_self(x, np.arange(8), 3)
    w, ok = lle_solve(x, nb, np.r_[np.zeros(4), np.full(4, 1e-3)])
    assert not ok[:4].any()
    assert ok[4:].all() and np.isfinite(w[4:]).all()


@pytest.mark.parametrize("n", [1, 7, 1024, 1025, 5000])
def test_em_residuals_are_the_products_and_einsums_bits(n):
    rng = np.random.default_rng(n)
    m = 15
    G = rng.normal(size=(n, 2 * m)) * 10.0 ** rng.integers(-3, 3, size=2 * m)
    GT = np.ascontiguousarray(G.reshape(2 * n, m).T)
    C = rng.normal(size=(m, 2)) * 10.0 ** rng.integers(-6, 2, size=(m, 1))
    target, BX = rng.normal(size=(n, 2)), rng.normal(size=(n, 2)) * 1e-3
    F = matmul_t(GT, C).reshape(n, 2, 2)
    res, loc = target - F[:, 0], BX + F[:, 1]
    r2, local = em_residuals(GT, C, target, BX)
    np.testing.assert_array_equal(r2, np.einsum("ij,ij->i", res, res))
    np.testing.assert_array_equal(local, np.einsum("ij,ij->i", loc, loc))


def test_lle_weights_match_the_numpy_steps_with_singular_neighbourhoods():
    # Points on a line (collinear offsets: singular 2 x 2 Gram matrices without a regulariser) and others.
    rng = np.random.default_rng(5)
    x = np.r_[np.c_[np.arange(6.0), np.zeros(6)], rng.normal(size=(20, 2)) * 10]
    nb = knn_without_self(x, np.arange(len(x)), 2)
    z = x[nb] - x[:, None, :]
    gram = z[:, :, None, 0] * z[:, None, :, 0] + z[:, :, None, 1] * z[:, None, :, 1]
    ref = solve_batched(gram, np.ones((len(x), 2, 1)))[..., 0]
    ref /= ref.sum(1, keepdims=True)
    assert not lle_solve(x, nb, np.zeros(len(x)))[1][:6].all()  # the fallback is exercised
    W = lle_weights(x, 2, reg=0.0).toarray()
    np.testing.assert_array_equal(np.take_along_axis(W, nb, 1), ref)
