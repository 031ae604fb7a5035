"""Compiled (numba) linear algebra of the EM filters (VFC, LLT) whose result does not depend on the BLAS kernel.

The EM loops amplify last bits into a different ``p > tau``, so products sum in a fixed order (four
interleaved partial sums for the weighted Gram matrices) and small systems are solved by Gaussian
elimination with partial pivoting (ties: the lowest row). See docs/filters.md, "under any BLAS kernel".
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from .._numerics.jit import user_cache
from .._numerics.simd import load4 as _load4, mul4 as _mul4, muladd4 as _muladd4, store4 as _store4

__all__ = ["weighted_gram", "weighted_gram_t", "matmul", "matmul_t", "dot", "solve", "solve_batched", "solve_kernel"]


#: Rows of H per tile of a Gram matrix (a multiple of 4): the tile's columns stay in the L2 cache.
_TILE = 1024


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _load_row(acc, i, j):
        return _load4(acc[i, j], 0), _load4(acc[i, j + 1], 0), _load4(acc[i, j + 2], 0), _load4(acc[i, j + 3], 0)

    @_jit
    def _store_row(acc, i, j, p):
        _store4(acc[i, j], 0, p[0])
        _store4(acc[i, j + 1], 0, p[1])
        _store4(acc[i, j + 2], 0, p[2])
        _store4(acc[i, j + 3], 0, p[3])

    @_jit
    def _update_row(p, a, h):
        return _muladd4(p[0], a, h[0]), _muladd4(p[1], a, h[1]), _muladd4(p[2], a, h[2]), _muladd4(p[3], a, h[3])

    @_jit
    def _gram_block(w, HT, t0, i, j, acc, L):
        # acc[i + a, j + b] += sum_k (w_k H_k,i+a) H_k,j+b over the tile, increasing k: sixteen Vec4 in registers.
        wt = w[t0:]
        u0, u1, u2, u3 = HT[i, t0:], HT[i + 1, t0:], HT[i + 2, t0:], HT[i + 3, t0:]
        g0, g1, g2, g3 = HT[j, t0:], HT[j + 1, t0:], HT[j + 2, t0:], HT[j + 3, t0:]
        p0, p1 = _load_row(acc, i, j), _load_row(acc, i + 1, j)
        p2, p3 = _load_row(acc, i + 2, j), _load_row(acc, i + 3, j)
        for k in range(0, L, 4):
            wk = _load4(wt, k)
            h = _load4(g0, k), _load4(g1, k), _load4(g2, k), _load4(g3, k)
            p0 = _update_row(p0, _mul4(wk, _load4(u0, k)), h)
            p1 = _update_row(p1, _mul4(wk, _load4(u1, k)), h)
            p2 = _update_row(p2, _mul4(wk, _load4(u2, k)), h)
            p3 = _update_row(p3, _mul4(wk, _load4(u3, k)), h)
        _store_row(acc, i, j, p0)
        _store_row(acc, i + 1, j, p1)
        _store_row(acc, i + 2, j, p2)
        _store_row(acc, i + 3, j, p3)

    @_jit
    def _gram_strip(w, HT, t0, i, j, acc, L):
        # _gram_block for one column j; rows past the last repeat it (their sums land in acc's spare rows).
        n = HT.shape[0]
        wt, g = w[t0:], HT[j, t0:]
        u0, u1 = HT[i, t0:], HT[min(i + 1, n - 1), t0:]
        u2, u3 = HT[min(i + 2, n - 1), t0:], HT[min(i + 3, n - 1), t0:]
        p0, p1 = _load4(acc[i, j], 0), _load4(acc[i + 1, j], 0)
        p2, p3 = _load4(acc[i + 2, j], 0), _load4(acc[i + 3, j], 0)
        for k in range(0, L, 4):
            wk, h = _load4(wt, k), _load4(g, k)
            p0 = _muladd4(p0, _mul4(wk, _load4(u0, k)), h)
            p1 = _muladd4(p1, _mul4(wk, _load4(u1, k)), h)
            p2 = _muladd4(p2, _mul4(wk, _load4(u2, k)), h)
            p3 = _muladd4(p3, _mul4(wk, _load4(u3, k)), h)
        _store4(acc[i, j], 0, p0)
        _store4(acc[i + 1, j], 0, p1)
        _store4(acc[i + 2, j], 0, p2)
        _store4(acc[i + 3, j], 0, p3)

    @_jit
    def _weighted_gram(HT, w):
        # HT is H' (n, K). Entry (i, j) sums (w_k H_ki) H_kj in four partial sums (rows k mod 4, increasing
        # k; the last K mod 4 rows go to the first), added as (s0 + s1) + (s2 + s3). Tiles of _TILE rows go
        # through 4 x 4 blocks on and above the diagonal, then 4 x 1 strips for the last n mod 4 columns.
        n, K = HT.shape
        K4 = K - K % 4
        full = n - n % 4
        acc = np.zeros((n + 3, n, 4))  # the partial sums; 3 spare rows for the strips' last block
        for t0 in range(0, K4, _TILE):
            L = min(_TILE, K4 - t0)
            for i in range(0, full, 4):
                for j in range(i, full, 4):
                    _gram_block(w, HT, t0, i, j, acc, L)
            for j in range(full, n):
                for i in range(0, j + 1, 4):
                    _gram_strip(w, HT, t0, i, j, acc, L)
        out = np.empty((n, n))
        for i in range(n):
            for j in range(i, n):
                s0 = acc[i, j, 0]
                for k in range(K4, K):
                    s0 += (w[k] * HT[i, k]) * HT[j, k]
                out[i, j] = (s0 + acc[i, j, 1]) + (acc[i, j, 2] + acc[i, j, 3])
                out[j, i] = out[i, j]
        return out

    @_jit
    def _matmul_t(AT, B):
        # (AT' B)' (n, K) for AT (m, K), B (m, n): entry (k, j) sums A_ki B_ij over increasing i.
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
    def solve_kernel(A, B):
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
            X[t], ok[t] = solve_kernel(A[t], B[t])
        return X, ok


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def weighted_gram(H: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``H' diag(w) H`` (n, n) of ``H`` (K, n) and ``w`` (K,), summed in four interleaved partial sums."""
    return _weighted_gram(np.ascontiguousarray(np.asarray(H, np.float64).T), _f64(w))


def weighted_gram_t(HT: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`weighted_gram` of ``HT.T`` given ``HT`` (n, K) (no copy when C-contiguous float64)."""
    return _weighted_gram(_f64(HT), _f64(w))


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
    """``A^-1 B`` of ``A`` (n, n) and ``B`` (n, r) by Gaussian elimination with partial pivoting; an exactly
    singular (or non-finite) ``A`` by LAPACK's least squares, which may depend on the BLAS kernel."""
    X, ok = solve_kernel(_f64(A), _f64(B))
    if ok and np.isfinite(X).all():
        return X
    return np.linalg.lstsq(A, B, rcond=None)[0]


def solve_batched(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``A[t]^-1 B[t]`` for stacks ``A`` (T, n, n) and ``B`` (T, n, r), each as :func:`solve`."""
    X, ok = _solve_batched(_f64(A), _f64(B))
    for t in np.flatnonzero(~ok | ~np.isfinite(X).all(axis=(1, 2))):
        X[t] = np.linalg.lstsq(A[t], B[t], rcond=None)[0]
    return X
