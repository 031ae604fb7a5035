"""Compiled (numba) steps of LLT that numpy ran through large temporaries: the local Gram matrices of the
locally linear reconstruction, and the residuals of one EM iteration.

Each kernel performs the operations of the numpy expression it replaces, element by element and in the same
order (one IEEE multiply or add at a time, no ``fastmath``: no reassociation, no fused multiply-add), so its
results are the same bits; the sums that numpy orders by its own rules (``np.trace``, ``ndarray.sum``) stay
in numpy. Compiled code is cached on disk as for the other kernels (``$CTXMATCH_CACHE/numba`` unless
``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from .._numba import user_cache

__all__ = ["local_grams", "add_to_diagonal", "em_residuals"]

#: Rows of ``[U, BU]`` per tile of :func:`em_residuals` (two 16 kB output tiles stay in the L1 cache).
_TILE = 2048

with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _local_grams(x, nb):
        n, kk = nb.shape
        z = np.empty((kk, 2))
        gram = np.empty((n, kk, kk))
        for i in range(n):
            for a in range(kk):
                z[a, 0] = x[nb[i, a], 0] - x[i, 0]
                z[a, 1] = x[nb[i, a], 1] - x[i, 1]
            for a in range(kk):
                for b in range(kk):
                    gram[i, a, b] = z[a, 0] * z[b, 0] + z[a, 1] * z[b, 1]
        return gram

    @_jit
    def _add_to_diagonal(gram, t):
        n, kk, _ = gram.shape
        for i in range(n):
            for a in range(kk):
                for b in range(kk):
                    gram[i, a, b] += t[i] * (1.0 if a == b else 0.0)

    @_jit
    def _em_residuals(GT, C, target, BX):
        m, n2 = GT.shape
        r2 = np.empty(n2 // 2)
        local = np.empty(n2 // 2)
        f0 = np.empty(_TILE)
        f1 = np.empty(_TILE)
        for t0 in range(0, n2, _TILE):
            L = min(_TILE, n2 - t0)
            f0[:L] = 0.0
            f1[:L] = 0.0
            for i in range(m):
                a = GT[i, t0:t0 + L]
                b0 = C[i, 0]
                b1 = C[i, 1]
                for k in range(L):
                    f0[k] += a[k] * b0
                    f1[k] += a[k] * b1
            for k in range(0, L, 2):  # rows 2p (U_p C) and 2p + 1 ((BU)_p C) of point p
                p = (t0 + k) // 2
                r0 = target[p, 0] - f0[k]
                r1 = target[p, 1] - f1[k]
                l0 = BX[p, 0] + f0[k + 1]
                l1 = BX[p, 1] + f1[k + 1]
                r2[p] = r0 * r0 + r1 * r1
                local[p] = l0 * l0 + l1 * l1
        return r2, local


def local_grams(x: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """Gram matrices of every point's neighbour offsets: ``gram[i, a, b] = z_ia . z_ib`` with
    ``z_ia = x[nb[i, a]] - x[i]``, shape (n, kk, kk).

    The bits of numpy's ``z[:, :, None, 0] * z[:, None, :, 0] + z[:, :, None, 1] * z[:, None, :, 1]`` without
    its four (n, kk, kk) temporaries.

    Parameters
    ----------
    x : ndarray of shape (n, 2)
        The points.
    nb : ndarray of shape (n, kk), int
        Neighbour indices into ``x``.
    """
    return _local_grams(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(nb, np.int64))


def add_to_diagonal(gram: np.ndarray, t: np.ndarray) -> None:
    """``gram += t[:, None, None] * np.eye(kk)`` in place, as numpy does it (``t_i * 0.0`` added off the
    diagonal too), on a C-contiguous float64 ``gram`` (n, kk, kk) and ``t`` (n,)."""
    _add_to_diagonal(gram, np.ascontiguousarray(t, np.float64))


def em_residuals(GT: np.ndarray, C: np.ndarray, target: np.ndarray, BX: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared residuals of the fit and of the local constraint after an M-step of LLT.

    With ``F = matmul_t(GT, C).reshape(n, 2, 2)`` (:func:`ctxmatch_lib.filters._em_kernels.matmul_t`: each
    entry summed over the ``m`` rows in order), ``res = target - F[:, 0]`` and ``loc = BX + F[:, 1]``, returns
    ``r2 = einsum("ij,ij->i", res, res)`` and ``local = einsum("ij,ij->i", loc, loc)``: the same operations in
    the same order, one pass over ``GT`` instead of one per column of ``C``, and no (n, 2) temporaries.

    Parameters
    ----------
    GT : ndarray of shape (m, 2n)
        ``[U, BU]`` reshaped to (2n, m) and transposed, C-contiguous float64: column ``2p`` is ``U_p``,
        column ``2p + 1`` is ``(BU)_p``.
    C : ndarray of shape (m, 2)
        Kernel coefficients.
    target, BX : ndarray of shape (n, 2)
        ``y - x`` and ``(I - W) x``.

    Returns
    -------
    r2, local : ndarray of shape (n,)
    """
    f64 = partial(np.ascontiguousarray, dtype=np.float64)
    return _em_residuals(f64(GT), f64(C), f64(target), f64(BX))
