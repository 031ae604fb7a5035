"""Tests of PGM's compiled pairwise-affinity kernel (``ctxmatch_lib.filters.pgm._kernels``)."""

from __future__ import annotations

import numpy as np
import pytest

from ctxmatch_lib.filters.pgm._kernels import pair_affinity, sinkhorn
from ctxmatch_lib.filters.pgm import _local_affines


def _pair_affinity_arrays(x, y, T, a, b, tau, rho):
    """The array formulation the kernel replaced (PGM before the kernel), the reference for exactness."""
    dx, dy = x[b] - x[a], y[b] - y[a]
    if T is None:
        l1, l2 = np.hypot(dx[:, 0], dx[:, 1]), np.hypot(dy[:, 0], dy[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(l1 + l2 > 0, 2.0 * np.abs(l1 - l2) / (l1 + l2), 0.0)
        return np.maximum(1.0 - d / rho, 0.0)
    Ta, Tb = T.reshape(-1, 4)[a], T.reshape(-1, 4)[b]
    with np.errstate(invalid="ignore"):
        e_a = np.hypot(dy[:, 0] - Ta[:, 0] * dx[:, 0] - Ta[:, 1] * dx[:, 1],
                       dy[:, 1] - Ta[:, 2] * dx[:, 0] - Ta[:, 3] * dx[:, 1])
        e_b = np.hypot(dy[:, 0] - Tb[:, 0] * dx[:, 0] - Tb[:, 1] * dx[:, 1],
                       dy[:, 1] - Tb[:, 2] * dx[:, 0] - Tb[:, 3] * dx[:, 1])
        d = 0.5 * (e_a + e_b)
    d = np.where(np.isfinite(d), d, np.inf)
    return np.maximum(1.0 - d / tau, 0.0)


def test_pair_affinity_exact_small():
    # Edge (0, 0) -> (10, 0) in image 1, (5, 5) -> (25, 5) in image 2: twice as long. With identity local
    # transformations each predicts (10, 0) and misses by 10 pixels: d = 10, affinity 1 - 10 / 50 = 0.8.
    # Without shapes the relative length distortion is |10 - 20| / 15 = 2/3 > rho: affinity 0.
    x = np.array([[0.0, 0.0], [10.0, 0.0]])
    y = np.array([[5.0, 5.0], [25.0, 5.0]])
    T = np.tile(np.eye(2), (2, 1, 1))
    a, b = np.array([0, 1]), np.array([1, 0])
    np.testing.assert_allclose(pair_affinity(x, y, T, a, b, 50.0, 0.5), [0.8, 0.8])
    np.testing.assert_array_equal(pair_affinity(x, y, None, a, b, 50.0, 0.5), [0.0, 0.0])
    # A pure translation: both predictions exact, affinity 1; coincident keypoints without shapes too.
    y = x + (5.0, 5.0)
    np.testing.assert_array_equal(pair_affinity(x, y, T, a, b, 50.0, 0.5), [1.0, 1.0])
    np.testing.assert_array_equal(pair_affinity(x, y, None, np.array([0]), np.array([0]), 50.0, 0.5), [1.0])


def test_pair_affinity_empty():
    x = np.zeros((3, 2))
    out = pair_affinity(x, x, None, np.empty(0, np.int64), np.empty(0, np.int64), 50.0, 0.5)
    assert out.shape == (0,)


@pytest.mark.parametrize("with_shapes", [True, False])
def test_pair_affinity_bit_identical_to_arrays(with_shapes):
    # Random pairs, singular shapes (infinite transformations) and coincident keypoints included: the
    # kernel must give exactly the array formulation's values (PGM's keep masks depend on it).
    rng = np.random.default_rng(3)
    n, npairs = 400, 5000
    x = rng.uniform(0, 800, (n, 2))
    y = rng.uniform(0, 800, (n, 2))
    x[1::5], y[1::5] = x[::5][: len(x[1::5])], y[::5][: len(y[1::5])]
    T = None
    if with_shapes:
        A1 = rng.normal(size=(n, 2, 2)) + 3.0 * np.eye(2)
        A2 = A1 @ (np.eye(2) + 0.05 * rng.normal(size=(n, 2, 2)))
        A1[::17] = 0.0  # singular image-1 shape: no transformation
        T = _local_affines(A1, A2)
    a, b = rng.integers(0, n, npairs), rng.integers(0, n, npairs)
    got = pair_affinity(x, y, T, a, b, 50.0, 0.5)
    want = _pair_affinity_arrays(x, y, T, a, b, 50.0, 0.5)
    np.testing.assert_array_equal(got, want)
    assert 0 < np.count_nonzero(got) < npairs


def _sinkhorn_arrays(a, g1, g2, tol, max_iter):
    """The array formulation of PGM's Sinkhorn normalisation that the kernel replaced (the reference)."""
    n1, n2 = int(g1.max()) + 1, int(g2.max()) + 1
    if n1 > n2:
        g1, g2, n1, n2 = g2, g1, n2, n1
    extra = n2 - n1
    dummy = np.ones(n2)
    for _ in range(max_iter):
        a = a / np.bincount(g1, a, n1)[g1]
        if extra:
            dummy = dummy / dummy.sum()
        col = np.bincount(g2, a, n2) + extra * dummy
        b = a / col[g2]
        dummy = dummy / col
        done = np.abs(b - a).max() < tol
        a = b
        if done:
            break
    return a


def test_sinkhorn_exact_small():
    # Two candidates of one image-1 keypoint on two image-2 keypoints, weights 3 and 1: the row sums to 1
    # (0.75, 0.25); the second image has one more keypoint, so one dummy row (1/2, 1/2) joins the columns,
    # which then hold 1.25 and 0.75: 0.75 / 1.25 = 0.6 and 0.25 / 0.75 = 1/3 after one iteration.
    out = sinkhorn(np.array([3.0, 1.0]), np.array([0, 0]), np.array([0, 1]), 1e-3, 1)
    np.testing.assert_allclose(out, [0.6, 1.0 / 3.0])
    a = np.array([3.0, 1.0])
    sinkhorn(a, np.array([0, 0]), np.array([0, 1]), 1e-3, 1)
    np.testing.assert_array_equal(a, [3.0, 1.0])  # the input is left alone


@pytest.mark.parametrize("n1, n2, max_iter", [(40, 40, 10), (30, 200, 10), (300, 50, 1000), (5, 3, 10)])
def test_sinkhorn_bit_identical_to_arrays(n1, n2, max_iter):
    # Many-to-many candidate sets, square or not (slack on either side, more than 128 dummies too), a
    # zero-weight group included: the kernel gives exactly the array formulation's values.
    rng = np.random.default_rng(n1 + n2)
    k = 6 * max(n1, n2)
    g1 = np.r_[np.arange(n1), rng.integers(0, n1, k - n1)]
    g2 = np.r_[np.arange(n2), rng.integers(0, n2, k - n2)][:k] if k >= n2 else rng.integers(0, n2, k)
    a = np.exp(30.0 * rng.random(k))
    a[g1 == 0] = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        want = _sinkhorn_arrays(a, g1, g2, 1e-3, max_iter)
    np.testing.assert_array_equal(sinkhorn(a, g1, g2, 1e-3, max_iter), want)


def test_pairwise_sum_is_numpys_sum():
    # The kernel's normalisations must sum as numpy does (pairwise, blockwise) to stay bit-identical.
    from ctxmatch_lib.filters.pgm._kernels import _pairwise_sum

    rng = np.random.default_rng(0)
    for n in [0, 1, 7, 8, 9, 127, 128, 129, 255, 256, 1000, 4099, 40000]:
        a = rng.exponential(size=n) * 10.0 ** rng.uniform(-20, 5, n)
        assert _pairwise_sum(a, 0, n) == a.sum(), n
