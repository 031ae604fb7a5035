"""Compiled (numba) steps of LLT: reconstruction weights and EM residuals, with the bits of the numpy they replace.

numba's cache checks this file's timestamp only: an edit of :mod:`._em_kernels` or
:mod:`ctxmatch_lib._numerics.simd` needs this file touched (or the cache cleared).
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from ..._numerics.jit import user_cache
from ..._numerics.simd import load4 as _load4, muladd4 as _muladd4, store4 as _store4
from .._em_kernels import solve_kernel

__all__ = ["offset_norms", "lle_solve", "em_residuals"]

with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _offset_norms(x, nb):
        n, kk = nb.shape
        out = np.empty((n, kk))
        for i in range(n):
            for a in range(kk):
                z0 = x[nb[i, a], 0] - x[i, 0]
                z1 = x[nb[i, a], 1] - x[i, 1]
                out[i, a] = z0 * z0 + z1 * z1
        return out

    @_jit
    def _lle_solve(x, nb, t):
        n, kk = nb.shape
        z = np.empty((kk, 2))
        gram = np.empty((kk, kk))
        ones = np.ones((kk, 1))
        w = np.empty((n, kk))
        ok = np.empty(n, np.bool_)
        for i in range(n):
            for a in range(kk):
                z[a, 0] = x[nb[i, a], 0] - x[i, 0]
                z[a, 1] = x[nb[i, a], 1] - x[i, 1]
            for a in range(kk):
                for b in range(kk):
                    g = z[a, 0] * z[b, 0] + z[a, 1] * z[b, 1]
                    g += t[i] * (1.0 if a == b else 0.0)
                    gram[a, b] = g
            X, ok[i] = solve_kernel(gram, ones)
            for a in range(kk):
                w[i, a] = X[a, 0]
                ok[i] = ok[i] and np.isfinite(X[a, 0])
        return w, ok

    @_jit
    def _em_residuals(GT, C, target, BX):
        # Four entries of F = matmul_t(GT, C) per column of C in a Vec4 (U_p C, (BU)_p C and the next point's),
        # summed over the m rows of GT in order from 0.0; the last two entries (odd n) in scalars.
        m, n2 = GT.shape
        r2 = np.empty(n2 // 2)
        local = np.empty(n2 // 2)
        c0 = np.empty((m, 4))  # C[i, 0] and C[i, 1] in every lane
        c1 = np.empty((m, 4))
        for i in range(m):
            c0[i, :] = C[i, 0]
            c1[i, :] = C[i, 1]
        zero = np.zeros(4)
        f0 = np.empty(4)
        f1 = np.empty(4)
        for k in range(0, n2, 4):
            if k + 4 <= n2:
                s0 = _load4(zero, 0)
                s1 = s0
                for i in range(m):
                    a = _load4(GT[i], k)
                    s0 = _muladd4(s0, a, _load4(c0[i], 0))
                    s1 = _muladd4(s1, a, _load4(c1[i], 0))
                _store4(f0, 0, s0)
                _store4(f1, 0, s1)
            else:
                for q in range(2):
                    f0[q] = 0.0
                    f1[q] = 0.0
                    for i in range(m):
                        f0[q] += GT[i, k + q] * C[i, 0]
                        f1[q] += GT[i, k + q] * C[i, 1]
            for q in range(0, min(4, n2 - k), 2):
                p = (k + q) // 2
                res0 = target[p, 0] - f0[q]
                res1 = target[p, 1] - f1[q]
                loc0 = BX[p, 0] + f0[q + 1]
                loc1 = BX[p, 1] + f1[q + 1]
                r2[p] = res0 * res0 + res1 * res1
                local[p] = loc0 * loc0 + loc1 * loc1
        return r2, local


def offset_norms(x: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """Squared lengths ``|x[nb[i, a]] - x[i]|^2`` (n, kk) of points ``x`` (n, 2) to their neighbours ``nb``
    (n, kk): the diagonals of :func:`lle_solve`'s local Gram matrices, bit for bit."""
    return _offset_norms(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(nb, np.int64))


def lle_solve(x: np.ndarray, nb: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unnormalised locally linear reconstruction weights ``(G_i + t_i I)^-1 1`` of every point ``i``.

    ``G_i``: Gram matrix of the offsets ``x[nb[i, a]] - x[i]``. Returns ``w`` (n, kk) and ``ok`` (n,),
    False where the system is singular or a weight non-finite (to be solved by least squares).
    """
    return _lle_solve(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(nb, np.int64),
                      np.ascontiguousarray(t, np.float64))


def em_residuals(GT: np.ndarray, C: np.ndarray, target: np.ndarray, BX: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared residuals (n,) of the fit and of the local constraint after an M-step of LLT.

    ``GT`` (m, 2n): ``[U, BU]`` reshaped to (2n, m), transposed; ``C`` (m, 2); ``target`` = ``y - x`` and
    ``BX`` = ``(I - W) x`` (n, 2). With ``F = matmul_t(GT, C).reshape(n, 2, 2)``: the squared row norms
    of ``target - F[:, 0]`` and ``BX + F[:, 1]``.
    """
    f64 = partial(np.ascontiguousarray, dtype=np.float64)
    return _em_residuals(f64(GT), f64(C), f64(target), f64(BX))
