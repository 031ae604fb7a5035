"""Compiled (numba) linear algebra of the EM filters (VFC, LLT) whose result does not depend on the BLAS kernel.

The EM loops of VFC and LLT iterate hundreds of times on small, ill-conditioned systems (Gaussian kernels of
a few control points), so the last bits of one iteration's products grow into different posteriors, and a
posterior near the threshold ``tau`` decides differently (issue 31: on the same candidate set, VFC kept one
match more under ``OPENBLAS_CORETYPE=Nehalem`` than under the default SkylakeX kernels, its posteriors 3.5e-5
apart after 188 iterations). OpenBLAS sums a product in an order that depends on the SIMD kernel it picks
for the CPU, and LAPACK's least squares truncates singular values at a cutoff that such differences cross.

Here every product is a plain loop that sums in a fixed order (row order, or four interleaved partial sums
for the weighted Gram matrices), without ``fastmath`` (no reassociation, no fused
multiply-add), and the small systems are solved by Gaussian elimination with partial pivoting (ties: the
lowest row): the same operations in the same order on any x86-64 CPU. The ``(K, n)`` products cost O(K n^2)
per iteration with n about 20, a few milliseconds at K = 30 000.

Compiled code is cached on disk as for the DTM kernels (``$CTXMATCH_CACHE/numba`` unless ``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from .._numba import user_cache

__all__ = ["weighted_gram", "weighted_gram_t", "matmul", "matmul_t", "dot", "solve", "solve_batched"]


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _weighted_gram(HT, w):
        # HT is H transposed (n, K). Each entry sums its K products in four interleaved partial sums (rows
        # k = 0, 1, 2, 3 mod 4), added in a fixed order at the end: the order is spelled out, so it is the
        # same on every CPU (no fastmath), and four independent chains run faster than one.
        n, K = HT.shape
        out = np.zeros((n, n))
        wi = np.empty(K)
        K4 = K - K % 4
        for i in range(n):
            for k in range(K):
                wi[k] = w[k] * HT[i, k]
            for j in range(i, n):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                a3 = 0.0
                for k in range(0, K4, 4):
                    a0 += wi[k] * HT[j, k]
                    a1 += wi[k + 1] * HT[j, k + 1]
                    a2 += wi[k + 2] * HT[j, k + 2]
                    a3 += wi[k + 3] * HT[j, k + 3]
                for k in range(K4, K):
                    a0 += wi[k] * HT[j, k]
                out[i, j] = (a0 + a1) + (a2 + a3)
                out[j, i] = out[i, j]
        return out

    @_jit
    def _matmul_t(AT, B):
        # (AT' B)' for AT (m, K) and B (m, n): entry (k, j) sums A_ki B_ij over i in increasing order,
        # updated across k side by side (vectorised); returned transposed, (n, K).
        m, K = AT.shape
        n = B.shape[1]
        out = np.zeros((n, K))
        for i in range(m):
            a = AT[i]
            for j in range(n):
                b = B[i, j]
                o = out[j]
                for k in range(K):
                    o[k] += a[k] * b
        return out

    @_jit
    def _dot(a, b):
        acc = 0.0
        for k in range(a.shape[0]):
            acc += a[k] * b[k]
        return acc

    @_jit
    def _solve(A, B):
        n = A.shape[0]
        M = A.copy()
        X = B.copy()
        for c in range(n):
            p = c
            best = abs(M[c, c])
            for r in range(c + 1, n):
                v = abs(M[r, c])
                if v > best:
                    best, p = v, r
            if best == 0.0 or not np.isfinite(best):
                return X, False
            if p != c:
                for j in range(n):
                    M[c, j], M[p, j] = M[p, j], M[c, j]
                for j in range(X.shape[1]):
                    X[c, j], X[p, j] = X[p, j], X[c, j]
            for r in range(c + 1, n):
                f = M[r, c] / M[c, c]
                if f != 0.0:
                    for j in range(c, n):
                        M[r, j] -= f * M[c, j]
                    for j in range(X.shape[1]):
                        X[r, j] -= f * X[c, j]
        for c in range(n - 1, -1, -1):
            for j in range(X.shape[1]):
                acc = X[c, j]
                for q in range(c + 1, n):
                    acc -= M[c, q] * X[q, j]
                X[c, j] = acc / M[c, c]
        return X, True


    @_jit
    def _solve_batched(A, B):
        X = np.empty_like(B)
        ok = np.empty(A.shape[0], np.bool_)
        for t in range(A.shape[0]):
            X[t], ok[t] = _solve(A[t], B[t])
        return X, ok


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def weighted_gram(H: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``H' diag(w) H`` of ``H`` (K, n) and ``w`` (K,): (n, n), symmetric, each entry summed over the rows in
    four interleaved partial sums (a fixed order)."""
    return _weighted_gram(np.ascontiguousarray(np.asarray(H, np.float64).T), _f64(w))


def weighted_gram_t(HT: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`weighted_gram` of ``HT.T`` given ``HT`` (n, K), C-contiguous float64 (no copy)."""
    return _weighted_gram(HT, w)


def matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A @ B`` of ``A`` (K, m) and ``B`` (m, n), each entry summed over ``m`` in order."""
    return matmul_t(np.ascontiguousarray(np.asarray(A, np.float64).T), B)


def matmul_t(AT: np.ndarray, B: np.ndarray) -> np.ndarray:
    """:func:`matmul` of ``AT.T`` given ``AT`` (m, K): the EM loops transpose their fixed matrix once."""
    return _matmul_t(_f64(AT), _f64(B)).T


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a @ b`` of two (K,) vectors, summed in order."""
    return float(_dot(_f64(a), _f64(b)))


def solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A^-1 B`` of a square ``A`` (n, n) and ``B`` (n, r) by Gaussian elimination with partial pivoting.

    An exactly singular (or non-finite) ``A`` falls back to LAPACK's least squares, whose answer may then depend
    on the BLAS kernel.
    """
    X, ok = _solve(_f64(A), _f64(B))
    if ok and np.isfinite(X).all():
        return X
    return np.linalg.lstsq(A, B, rcond=None)[0]


def solve_batched(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A[t]^-1 B[t]`` for a stack ``A`` (T, n, n) and ``B`` (T, n, r), each as :func:`solve` (the exactly
    singular ones by LAPACK's least squares)."""
    X, ok = _solve_batched(_f64(A), _f64(B))
    for t in np.flatnonzero(~ok | ~np.isfinite(X).all(axis=(1, 2))):
        X[t] = np.linalg.lstsq(A[t], B[t], rcond=None)[0]
    return X
