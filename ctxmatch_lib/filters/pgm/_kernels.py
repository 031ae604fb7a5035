"""Compiled (numba) kernels of PGM (see :mod:`.pgm`): pairwise affinities, votes, Sinkhorn normalisation.

Same operations in the same order as the array form (sums in numpy's order, no fast-math), so the results
are bit-identical (``tests/test_filters_pgm.py``)."""

from __future__ import annotations

import math

import numba
import numpy as np

from ..._numerics.jit import user_cache

__all__ = ["pair_affinity", "sinkhorn", "votes"]


with user_cache() as _cache:

    _jit = numba.njit(cache=_cache, nogil=True, error_model="numpy")

    @_jit
    def _one(x, y, t, p, q, cut, with_t):  # pragma: no cover - compiled
        """Affinity of the candidates ``p`` and ``q`` (see :func:`pair_affinity`)."""
        dx0, dx1 = x[q, 0] - x[p, 0], x[q, 1] - x[p, 1]
        dy0, dy1 = y[q, 0] - y[p, 0], y[q, 1] - y[p, 1]
        if with_t:
            ua, va = dy0 - t[p, 0] * dx0 - t[p, 1] * dx1, dy1 - t[p, 2] * dx0 - t[p, 3] * dx1
            ub, vb = dy0 - t[q, 0] * dx0 - t[q, 1] * dx1, dy1 - t[q, 2] * dx0 - t[q, 3] * dx1
            # |(u, v)| >= max(|u|, |v|), in floating point too: a pair whose bound reaches the cut-off (most
            # pairs) has affinity exactly 0 without the two hypot calls.
            if 0.5 * (max(abs(ua), abs(va)) + max(abs(ub), abs(vb))) >= cut:
                return 0.0
            d = 0.5 * (math.hypot(ua, va) + math.hypot(ub, vb))
            if not math.isfinite(d):
                d = np.inf
        else:
            l1, l2 = math.hypot(dx0, dx1), math.hypot(dy0, dy1)
            d = 2.0 * abs(l1 - l2) / (l1 + l2) if l1 + l2 > 0 else 0.0
        return max(1.0 - d / cut, 0.0)

    @_jit
    def _pair_affinity_kernel(x, y, t, a, b, cut, with_t):  # pragma: no cover - compiled
        w = np.empty(len(a))
        for i in range(len(a)):
            w[i] = _one(x, y, t, a[i], b[i], cut, with_t)
        return w

    @_jit
    def _votes_kernel(x, y, t, m, nb, score, cut, with_t):  # pragma: no cover - compiled
        vote = np.zeros(len(nb))
        for p in range(len(nb)):
            acc = 0.0
            prev = -1
            for j in range(nb.shape[1]):
                q = nb[p, j]
                if q == prev:  # a neighbour in both images votes once
                    continue
                prev = q
                if m[p, 0] == m[q, 0] or m[p, 1] == m[q, 1]:  # no vote for a conflicting candidate
                    continue
                acc += _one(x, y, t, p, q, cut, with_t) * score[q]
            vote[p] = acc
        return vote


    @_jit
    def _block_sum(a, lo, n):  # pragma: no cover - compiled
        """numpy's sum of a block of at most 128 values (eight interleaved accumulators from 8 on)."""
        if n < 8:
            res = 0.0
            for i in range(lo, lo + n):
                res += a[i]
            return res
        r = a[lo:lo + 8].copy()
        i = 8
        while i < n - (n % 8):
            for j in range(8):
                r[j] += a[lo + i + j]
            i += 8
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            res += a[lo + i]
            i += 1
        return res

    @_jit
    def _pairwise_sum(a, lo, n):  # pragma: no cover - compiled
        """``a[lo:lo + n].sum()`` bit for bit as numpy's pairwise sum; iterative, as numba caches no recursion."""
        if n <= 128:
            return _block_sum(a, lo, n)
        st_lo, st_n, st_ph = np.empty(128, np.int64), np.empty(128, np.int64), np.empty(128, np.int64)
        vals = np.empty(128)
        sp, vsp = 0, 0
        st_lo[0], st_n[0], st_ph[0] = lo, n, 0
        while sp >= 0:
            lo_, n_, ph = st_lo[sp], st_n[sp], st_ph[sp]
            if n_ <= 128:
                vals[vsp] = _block_sum(a, lo_, n_)
                vsp += 1
                sp -= 1
                continue
            half = n_ // 2
            half -= half % 8
            if ph == 0:  # the left half first
                st_ph[sp] = 1
                sp += 1
                st_lo[sp], st_n[sp], st_ph[sp] = lo_, half, 0
            elif ph == 1:  # then the right half
                st_ph[sp] = 2
                sp += 1
                st_lo[sp], st_n[sp], st_ph[sp] = lo_ + half, n_ - half, 0
            else:  # both done: left + right
                vals[vsp - 2] = vals[vsp - 2] + vals[vsp - 1]
                vsp -= 1
                sp -= 1
        return vals[0]

    @_jit
    def _sinkhorn_kernel(a, g1, g2, n1, n2, tol, max_iter):  # pragma: no cover - compiled
        k = len(a)
        extra = float(n2 - n1)
        dummy = np.ones(n2)
        row = np.empty(n1)
        col = np.empty(n2)
        b = np.empty(k)
        tmp = np.empty(k)  # gathered divisors: the divisions then run in vectorisable loops
        for _ in range(max_iter):
            row[:] = 0.0
            for i in range(k):
                row[g1[i]] += a[i]
            for i in range(k):
                tmp[i] = row[g1[i]]
            for i in range(k):
                a[i] = a[i] / tmp[i]
            if n2 > n1:
                total = _pairwise_sum(dummy, 0, n2)
                for j in range(n2):
                    dummy[j] = dummy[j] / total
            col[:] = 0.0
            for i in range(k):
                col[g2[i]] += a[i]
            for j in range(n2):
                col[j] = col[j] + extra * dummy[j]
            for i in range(k):
                tmp[i] = col[g2[i]]
            for i in range(k):
                b[i] = a[i] / tmp[i]
            change = 0.0
            nan = False  # np.max of the changes is NaN if any is: not converged
            for i in range(k):
                e = abs(b[i] - a[i])
                nan |= e != e
                change = e if e > change else change
            for j in range(n2):
                dummy[j] = dummy[j] / col[j]
            a, b = b, a
            if not nan and change < tol:
                break
        return a


def pair_affinity(x: np.ndarray, y: np.ndarray, T: np.ndarray | None, a: np.ndarray, b: np.ndarray,
                  tau: float, rho: float) -> np.ndarray:
    """Pairwise affinity in [0, 1] of the candidates ``a[i]`` and ``b[i]``; ``x``, ``y`` (n, 2) pixels.

    With local affine maps ``T`` (n, 2, 2): ``max(1 - d / tau, 0)``, ``d`` the mutual projection error;
    with ``T=None``: ``max(1 - d / rho, 0)``, ``d = |l1 - l2| / ((l1 + l2) / 2)``."""
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(y, np.float64)
    a = np.ascontiguousarray(a, np.int64)
    b = np.ascontiguousarray(b, np.int64)
    if T is None:
        return _pair_affinity_kernel(x, y, np.zeros((0, 4)), a, b, float(rho), False)
    t = np.ascontiguousarray(np.asarray(T, np.float64).reshape(-1, 4))
    return _pair_affinity_kernel(x, y, t, a, b, float(tau), True)


def votes(x: np.ndarray, y: np.ndarray, T: np.ndarray | None, m: np.ndarray, nb: np.ndarray, score: np.ndarray,
          tau: float, rho: float) -> np.ndarray:
    """Vote ``sum_q pair_affinity(p, q) * score[q]`` of every candidate ``p`` over its neighbours ``nb[p]``.

    ``nb`` (n, j): rows sorted ascending, a repeated index counted once; neighbours sharing a keypoint
    (``m`` (n, 2)) are skipped. Summed in row order, as ``np.bincount`` over the same pairs."""
    x = np.ascontiguousarray(x, np.float64)
    y = np.ascontiguousarray(y, np.float64)
    m = np.ascontiguousarray(m, np.int64)
    nb = np.ascontiguousarray(nb, np.int64)
    score = np.ascontiguousarray(score, np.float64)
    if T is None:
        return _votes_kernel(x, y, np.zeros((0, 4)), m, nb, score, float(rho), False)
    t = np.ascontiguousarray(np.asarray(T, np.float64).reshape(-1, 4))
    return _votes_kernel(x, y, t, m, nb, score, float(tau), True)


def sinkhorn(a: np.ndarray, g1: np.ndarray, g2: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
    """Sinkhorn normalisation with slack of ``a`` (K,) over dense 0-based groups ``g1``, ``g2`` (see
    :func:`ctxmatch_lib.filters.pgm._sinkhorn`)."""
    g1 = np.ascontiguousarray(g1, np.int64)
    g2 = np.ascontiguousarray(g2, np.int64)
    n1, n2 = int(g1.max()) + 1, int(g2.max()) + 1
    if n1 > n2:  # transpose the problem so that the dummies are rows
        g1, g2, n1, n2 = g2, g1, n2, n1
    a = np.array(a, np.float64)  # a copy: the kernel normalises in place
    return _sinkhorn_kernel(a, g1, g2, n1, n2, float(tol), int(max_iter))
