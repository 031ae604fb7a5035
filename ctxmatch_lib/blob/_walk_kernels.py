"""Compiled look-ups of blob matching beyond the sorted lists: whole lines of the approximate matrix.

f = Ω's greedy (:func:`greedy_dense`) walks a row past its sorted list, and a ratio's second best
(:func:`next_in_lines`) may lie past it. Both take the next entry of a line in (exact distance, index) order
with :func:`next_in_line`: the float32 approximate squared distances (within the certified bound ``E`` of
:mod:`._kernels`) propose, sixteen at a time, and float64 exact distances decide.

numba's disk cache checks the timestamp of a kernel's own file only: after an edit of ``_kernels._exact_sq``
or of ``ctxmatch_lib._simd``, touch this file (or clear ``$CTXMATCH_CACHE/numba``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._numba import user_cache
from .._simd import band16, least16, min16, splat16
from ._kernels import _exact_sq

__all__ = ["next_in_line", "greedy_dense", "next_in_lines"]

with user_cache() as _cache:

    @njit(cache=_cache, nogil=True, inline="always")
    def _f32_at_least(x):
        """The least float32 ``>= x`` (a float64): for every float32 ``y``, ``y >= it`` iff ``y >= x``."""
        y = np.float32(x)
        return np.nextafter(y, np.float32(np.inf)) if np.float64(y) < x else y

    @njit(cache=_cache, nogil=True, inline="always")
    def _f32_at_most(x):
        """The greatest float32 ``<= x`` (a float64): for every float32 ``y``, ``y <= it`` iff ``y <= x``."""
        y = np.float32(x)
        return np.nextafter(y, np.float32(-np.inf)) if np.float64(y) > x else y

    @njit(cache=_cache, nogil=True)
    def _least_from(Dap, r, pen, lo):
        """The least ``Dap[r, k] + pen[k]`` that is ``>= lo`` (``inf`` if none), in float32: sixteen running
        minima in one register (a minimum does not depend on the order it is taken in)."""
        m = Dap.shape[1]
        m16 = m - m % 16
        acc = splat16(np.float32(np.inf))
        for k in range(0, m16, 16):
            acc = least16(acc, Dap, r, k, pen, lo)
        best = min16(acc)
        for k in range(m16, m):
            a = Dap[r, k] + pen[k]
            if a >= lo and a < best:
                best = a
        return best

    @njit(cache=_cache, nogil=True, inline="always")
    def _consider(A, line, B, k, d, j, strict, skip, pts, t_o2, best_d, best_k):
        """Entry ``k`` of the band of :func:`next_in_line`: its exact distance, if FGINN keeps it and it is
        after ``(d, j)``, against the best so far in (distance, index) order."""
        if t_o2 > 0:
            dx = pts[k, 0] - pts[skip, 0]
            dy = pts[k, 1] - pts[skip, 1]
            if dx * dx + dy * dy < t_o2:
                return best_d, best_k
        e = np.sqrt(_exact_sq(A, line, B, k))
        if e < d or (strict and e == d and k <= j):
            return best_d, best_k
        if e < best_d or (e == best_d and k < best_k):
            return e, k
        return best_d, best_k

    @njit(cache=_cache, nogil=True)
    def next_in_line(Dap, r, A, line, B, E, d, j, strict, skip, pen, pts, t_o2):
        """The next entry of line ``line`` after ``(d, j)`` in (exact distance, index) order.

        ``Dap[r]`` is the line's approximate squared distances (float32, within ``E`` of the exact ones).
        Candidates: ``pen[k] == 0`` (float32 ``inf`` takes entry ``k`` out; saturated columns of the greedy),
        ``k != skip``, not within ``sqrt(t_o2)`` pixels of ``skip`` (FGINN, when ``t_o2 > 0``) and exact
        distance ``> d`` or ``== d`` with ``k > j`` (``strict``) / ``>= d`` (not ``strict``, any ``k``).
        Exact distances are computed only for entries whose approximation cannot rule them out: the band
        ``[lo, top]`` above the least approximation not yet seen. The float64 bounds are compared with the
        float32 entries through the nearest float32 inside them, which decides each entry as the float64
        comparison would, sixteen at a time. Returns ``(distance, index)``, ``(inf, -1)`` when none
        qualifies. ``pen[skip]`` is set to ``inf`` during the call and restored.
        """
        m = Dap.shape[1]
        m16 = m - m % 16
        held = np.float32(0)
        if skip >= 0:
            held = pen[skip]
            pen[skip] = np.inf
        lo = d * d - 2.0 * E  # below: certainly closer than d
        best_d, best_k = np.inf, -1
        while True:
            lo32 = _f32_at_least(lo)
            mu = _least_from(Dap, r, pen, lo32)
            if mu == np.inf:
                break
            top = np.float64(mu) + 2.0 * E
            if best_k >= 0:
                top = max(top, best_d * best_d + 2.0 * E)
            top32 = _f32_at_most(top)
            for k0 in range(0, m16, 16):  # the band is narrow: most blocks of 16 have no entry in it
                mask = band16(Dap, r, k0, pen, lo32, top32)
                if mask == 0:
                    continue
                for q in range(16):
                    if (mask >> q) & 1:
                        best_d, best_k = _consider(A, line, B, k0 + q, d, j, strict, skip, pts, t_o2, best_d,
                                                   best_k)
            for k in range(m16, m):
                a = Dap[r, k] + pen[k]
                if a >= lo32 and a <= top32:
                    best_d, best_k = _consider(A, line, B, k, d, j, strict, skip, pts, t_o2, best_d, best_k)
            # Entries with approx <= top have been looked at.
            lo = np.nextafter(top, np.inf)
            # Unseen entries have approx > top, so exact > top - E: certified once that exceeds best_d².
            if best_k >= 0 and top - E > best_d * best_d * (1.0 + 1e-12):
                break
        if skip >= 0:
            pen[skip] = held
        return best_d, best_k

    @njit(cache=_cache, nogil=True)
    def _hpush(hv, hi, hj, size, v, i, j):
        p = size
        while p > 0:
            q = (p - 1) >> 1
            if hv[q] > v or (hv[q] == v and (hi[q] > i or (hi[q] == i and hj[q] > j))):
                hv[p], hi[p], hj[p] = hv[q], hi[q], hj[q]
                p = q
            else:
                break
        hv[p], hi[p], hj[p] = v, i, j
        return size + 1

    @njit(cache=_cache, nogil=True)
    def _hpop(hv, hi, hj, size):
        v, i, j = hv[0], hi[0], hj[0]
        size -= 1
        lv, li, lj = hv[size], hi[size], hj[size]
        p = 0
        while True:
            c = 2 * p + 1
            if c >= size:
                break
            if c + 1 < size and (hv[c + 1] < hv[c] or (hv[c + 1] == hv[c] and (
                    hi[c + 1] < hi[c] or (hi[c + 1] == hi[c] and hj[c + 1] < hj[c])))):
                c += 1
            if hv[c] < lv or (hv[c] == lv and (hi[c] < li or (hi[c] == li and hj[c] < lj))):
                hv[p], hi[p], hj[p] = hv[c], hi[c], hj[c]
                p = c
            else:
                break
        if size > 0:
            hv[p], hi[p], hj[p] = lv, li, lj
        return v, i, j, size

    @njit(cache=_cache, nogil=True)
    def greedy_dense(Dap, A, B, lidx, lval, E_rows, f_prime):
        """Step 2 over all of D (f = Ω): a heap holds each row's next entry in (distance, column) order.

        Rows walk their exact sorted lists first, then continue with :func:`next_in_line` on the
        approximate dense matrix (exact distances where the approximation cannot decide).
        """
        n, m = Dap.shape
        T = lidx.shape[1]
        rc = np.zeros(n, np.int64)
        cc = np.zeros(m, np.int64)
        pen = np.zeros(m, np.float32)  # inf: a saturated column
        ptr = np.zeros(n, np.int64)
        hv = np.empty(n)
        hi = np.empty(n, np.int64)
        hj = np.empty(n, np.int64)
        size = 0
        for i in range(n):
            size = _hpush(hv, hi, hj, size, lval[i, 0], i, lidx[i, 0])
        out_i = np.empty(n * f_prime, np.int64)
        out_j = np.empty(n * f_prime, np.int64)
        out_d = np.empty(n * f_prime)
        K = 0
        free_cols = m
        dummy = np.zeros((1, 2))
        while size > 0 and free_cols > 0:
            d, i, j, size = _hpop(hv, hi, hj, size)
            if cc[j] < f_prime:
                out_i[K], out_j[K], out_d[K] = i, j, d
                K += 1
                rc[i] += 1
                cc[j] += 1
                if cc[j] == f_prime:
                    pen[j] = np.inf
                    free_cols -= 1
            if rc[i] >= f_prime:
                continue
            p = ptr[i] + 1
            pushed = False
            while p < T:
                jj = lidx[i, p]
                if cc[jj] < f_prime:
                    ptr[i] = p
                    size = _hpush(hv, hi, hj, size, lval[i, p], i, jj)
                    pushed = True
                    break
                p += 1
            if pushed:
                continue
            if ptr[i] < T:
                ptr[i] = T
                d, j = lval[i, T - 1], lidx[i, T - 1]
            if T == m:
                continue
            e, k = next_in_line(Dap, i, A, i, B, E_rows[i], d, j, True, -1, pen, dummy, 0.0)
            if k >= 0:
                size = _hpush(hv, hi, hj, size, e, i, k)
        return out_i[:K], out_j[:K], out_d[:K]

    @njit(cache=_cache, nogil=True)
    def next_in_lines(Dap, rows, A, which, B, E_lines, d, j, strict, skip, pts, t_o2):
        """:func:`next_in_line` for several lines: line ``which[r]`` of ``A`` against ``B``, its approximate
        squared distances in ``Dap[rows[r]]``, the entry after ``(d[r], j[r])`` (``strict[r]``) other than
        ``skip[r]`` and, when ``t_o2 > 0``, not within ``sqrt(t_o2)`` pixels of it (FGINN). Returns the
        exact distances and indices, ``inf`` and ``-1`` where none qualifies."""
        L = len(which)
        out_d = np.empty(L)
        out_k = np.empty(L, np.int64)
        pen = np.zeros(Dap.shape[1], np.float32)
        for r in range(L):
            i = which[r]
            e, k = next_in_line(Dap, rows[r], A, i, B, E_lines[i], d[r], j[r], strict[r], skip[r], pen, pts,
                                t_o2)
            out_d[r] = e
            out_k[r] = k
        return out_d, out_k
