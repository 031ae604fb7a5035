"""Compiled (numba) kernels of AdaLAM (:mod:`.adalam`): the confidence-based inlier count of the local maps
(:func:`best_confident_maps`) and the seed test (:func:`beaten_by_neighbours`). Same expressions and
summation order as the array form, no fast-math: bit-identical (``tests/test_filters_kernels.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..._numerics.jit import user_cache

__all__ = ["beaten_by_neighbours", "best_confident_maps", "half_keys"]

_KEY_2M14 = (127 - 14) << 10  # float32 bit pattern of 2^-14, shifted right by 13
_INF_KEY = 31744  # one past the key of 65504, the largest finite half-precision value


with user_cache() as _cache:
    _jit = numba.njit(cache=_cache, nogil=True, error_model="numpy")  # count / 0 is inf, as in the reference

    @_jit
    def half_keys(y, keys):  # pragma: no cover - compiled
        """Int64 keys of float32 ``y >= 0`` into ``keys``, nondecreasing, equal iff equal as float16.

        Rounding as the reference's float16 cast; each NaN gets a key of its own."""
        bits = y.view(np.int32)
        for k in range(len(y)):
            v = y[k]
            if v != v:
                keys[k] = -1 - k
            elif v >= 65520.0:
                keys[k] = _INF_KEY
            elif v < 2.0 ** -14:
                keys[k] = int(np.rint(np.float64(v) * 2.0 ** 24))
            else:
                b = np.int64(bits[k])
                keys[k] = ((b + 0xFFF + ((b >> 13) & 1)) >> 13) - _KEY_2M14 + 1024

    @_jit
    def _count(sv, w, y, keys, min_conf):  # pragma: no cover - compiled
        """Inlier count and confidence of the sorted residuals ``sv`` (``w``, ``y``, ``keys``: scratch)."""
        n = len(sv)
        # Votes: runs of equal half-precision squared residuals (float32 squares, as the reference) share one;
        # exact fits have none.
        for k in range(n):
            y[k] = np.float32(sv[k] * sv[k])
        half_keys(y[:n], keys)
        votes = 0.0
        i = 0
        while i < n:
            j = i + 1
            while j < n and keys[j] == keys[i]:
                j += 1
            for k in range(i, j):
                x = sv[k]
                w[k] = 0.0 if x * x <= 1e-8 else 1.0 / (j - i)
                votes += w[k]
            i = j
        if votes == 0.0:  # nothing but exact fits: no evidence
            return 0, 0.0
        cum = 0.0
        good = 0.0
        for k in range(n):
            cum += w[k]
            x = sv[k]
            if x * x * min_conf <= cum / votes or x * x <= 1e-8:
                good += w[k]
        c = int(math.floor(good + 1e-9))
        if c == 0:
            return 0, 0.0
        x = sv[c - 1]
        return c, c / (votes * x * x)

    @_jit
    def _split(res, min_conf, sv, y, keys, marks, stamp):  # pragma: no cover - compiled
        """Countable residuals (``r^2 * min_conf <= 1`` or exact) sorted to the front of ``sv``, then the rest.

        Returns ``(p, runs)``: how many are countable, distinct keys of the rest (marked ``stamp`` in ``marks``)."""
        n = len(res)
        p, q = 0, n
        for i in range(n):
            x = res[i]
            if x * x * min_conf <= 1.0 or x * x <= 1e-8:
                sv[p] = x
                p += 1
            else:
                q -= 1
                sv[q] = x
        sv[:p].sort()
        for k in range(p, n):
            y[k] = np.float32(sv[k] * sv[k])
        half_keys(y[p:n], keys[p:n])
        runs = 0
        for k in range(p, n):
            if keys[k] < 0:
                runs += 1
            elif marks[keys[k]] != stamp:
                marks[keys[k]] = stamp
                runs += 1
        return p, runs

    @_jit
    def _count_bound(sv, runs, w, y, keys, marks, stamp, min_conf):  # pragma: no cover - compiled
        """Upper bound of :func:`_count` from the countable sorted ``sv`` and the ``runs`` of :func:`_split`.

        It underestimates the total votes and overstates the votes so far; ``1e-9`` covers rounding."""
        p = len(sv)
        for k in range(p):
            y[k] = np.float32(sv[k] * sv[k])
        half_keys(y[:p], keys[:p])
        head = 0.0  # votes of the runs before the last
        last = 0.0
        i = 0
        while i < p:
            j = i + 1
            while j < p and keys[j] == keys[i]:
                j += 1
            head += last
            last = 0.0
            for k in range(i, j):
                w[k] = 0.0 if sv[k] * sv[k] <= 1e-8 else 1.0 / (j - i)
                last += w[k]
            i = j
        shared = p > 0 and marks[keys[p - 1]] == stamp
        low = (head + (runs - 1 if shared else runs + last)) * (1.0 - 1e-9)
        if low <= 0.0:
            return len(w)
        cum = 0.0
        good = 0.0
        for k in range(p):
            cum += w[k]
            x = sv[k]
            if x * x * min_conf <= cum / low * (1.0 + 1e-9):
                good += w[k]
        return int(math.floor(good * (1.0 + 1e-9) + 1e-6))

    @_jit
    def best_confident_maps(A, U, V, ns, usable, distinct, min_conf):  # pragma: no cover - compiled
        """The best map of every neighbourhood under the confidence-based inlier count.

        ``A`` (B, T, 2, 2) maps, ``usable`` (B, T) (others: residual 2); ``U``, ``V`` (B, M, 2) members, the
        first ``ns[b]`` rows. Returns ``count, conf`` (B,) of the best map (the first of the largest count; 0
        without inlier), ``order`` (B, M) the stable sort of its residuals (then the absent rows), and
        ``near, near_distinct`` (B, T): residuals up to ``2^-12`` per map, of all and of ``distinct`` members."""
        B, T = A.shape[0], A.shape[1]
        M = U.shape[1]
        order = np.empty((B, M), np.int64)
        count = np.zeros(B, np.int64)
        conf = np.zeros(B)
        near = np.zeros((B, T), np.int64)
        near_distinct = np.zeros((B, T), np.int64)
        res = np.empty(M)
        best_res = np.empty(M)
        w = np.empty(M)
        sv = np.empty(M)
        y = np.empty(M, np.float32)
        keys = np.empty(M, np.int64)
        marks = np.zeros(_INF_KEY + 1, np.int64)
        stamp = 0
        for b in range(B):
            n = ns[b]
            best_c = -1
            for t in range(T):
                a00, a01, a10, a11 = A[b, t, 0, 0], A[b, t, 0, 1], A[b, t, 1, 0], A[b, t, 1, 1]
                bound = 0
                for i in range(n):
                    if usable[b, t]:
                        rx = a00 * U[b, i, 0] + a01 * U[b, i, 1] - V[b, i, 0]
                        ry = a10 * U[b, i, 0] + a11 * U[b, i, 1] - V[b, i, 1]
                        res[i] = math.sqrt(rx * rx + ry * ry)
                    else:
                        res[i] = 2.0  # no map: outside the unit discs
                    x = res[i]
                    if x <= 2.0 ** -12:
                        near[b, t] += 1
                        if distinct[b, i]:
                            near_distinct[b, t] += 1
                    if x * x > 1e-8 and x * x * min_conf <= 1.0:  # may count (cum / votes <= 1)
                        bound += 1
                if bound <= best_c:  # cannot beat the best so far (ties keep the first)
                    continue
                c, cf = 0, 0.0
                if bound > 0:
                    stamp += 1
                    p, runs = _split(res[:n], min_conf, sv, y, keys, marks, stamp)
                    if _count_bound(sv[:p], runs, w, y, keys, marks, stamp, min_conf) > best_c:
                        sv[p:n].sort()  # sv[:n]: the residuals sorted
                        c, cf = _count(sv[:n], w, y, keys, min_conf)
                if c > best_c:
                    best_c = c
                    count[b], conf[b] = c, cf
                    best_res[:n] = res[:n]
            o = np.argsort(best_res[:n], kind="mergesort")
            for i in range(n):
                order[b, i] = o[i]
            for i in range(n, M):
                order[b, i] = i
        return count, conf, order, near, near_distinct

    @_jit
    def beaten_by_neighbours(s, inv, pairs, n_loc):  # pragma: no cover - compiled
        """``(K,)`` bool: score ``s`` above the best at the match's location ``inv`` or one paired in ``pairs``."""
        best = np.full(n_loc, np.inf)
        for i in range(len(s)):
            if s[i] < best[inv[i]]:
                best[inv[i]] = s[i]
        low = best.copy()
        for k in range(len(pairs)):
            p, q = pairs[k, 0], pairs[k, 1]
            if best[q] < low[p]:
                low[p] = best[q]
            if best[p] < low[q]:
                low[q] = best[p]
        beaten = np.empty(len(s), np.bool_)
        for i in range(len(s)):
            beaten[i] = s[i] > low[inv[i]]
        return beaten
