"""Compiled look-ups beyond the sorted lists: f = Ω's greedy (:func:`greedy_dense`) and the second best
(:func:`next_in_lines`), through :func:`next_in_line` (16-bit codes propose, float64 distances decide).

numba's disk cache checks only this file: after editing ``_kernels`` or ``_numerics.simd``, touch it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._numerics.jit import user_cache
from .._numerics.simd import band16, prefetch
from ._kernels import TAKEN, _exact_sq, _lowest_bit, within_px

__all__ = ["next_in_line", "greedy_dense", "next_in_lines"]

#: Lines of codes asked for ahead of their look-up in :func:`next_in_lines` (a hint; no effect on results).
AHEAD = 2

with user_cache() as _cache:

    @njit(cache=_cache, nogil=True, inline="always")
    def _consider(A, line, B, k, d, j, strict, skip, pts, t_o2, best_d, best_k):
        """Entry ``k`` of the band of :func:`next_in_line`: its exact distance, if FGINN keeps it and it is
        after ``(d, j)``, against the best so far in (distance, index) order."""
        if t_o2 > 0 and within_px(pts, k, skip, t_o2):
            return best_d, best_k
        e = np.sqrt(_exact_sq(A, line, B, k))
        if e < d or (strict and e == d and k <= j):
            return best_d, best_k
        if e < best_d or (e == best_d and k < best_k):
            return e, k
        return best_d, best_k

    @njit(cache=_cache, nogil=True, inline="always")
    def _code_at_most(x, qoff, step):
        """The greatest code ``q`` (clipped to ``[0, TAKEN]``) with ``qoff + q step <= x``, rounded down by one
        more: every code below it decodes a whole step under ``x``."""
        c = np.floor((x - qoff) / step) - 1.0
        return np.int64(min(max(c, 0.0), float(TAKEN)))

    @njit(cache=_cache, nogil=True, inline="always")
    def _code_at_least(x, qoff, step):
        """The least code (clipped to ``[0, TAKEN]``) decoding above ``x``, rounded up by one more."""
        c = np.ceil((x - qoff) / step) + 1.0
        return np.int64(min(max(c, 0.0), float(TAKEN)))

    @njit(cache=_cache, nogil=True, inline="always")
    def _band_top(mu, top_best, E, qoff, step):
        """The last code that may come before the entry coded ``mu`` (decoded within ``2E``) or before the
        best so far (``top_best``)."""
        return max(_code_at_least(qoff + mu * step + 2.0 * E, qoff, step), top_best)

    @njit(cache=_cache, nogil=True)
    def _band_from(Q, r, pen, lo, top_best, E, qoff, step, band):
        """One pass over line ``r`` of ``Q``, sixteen codes at a time: the least code ``mu >= lo`` not taken
        out (``TAKEN``: none), and in ``band[:count]`` every entry coded in ``[lo, hi]``, ``hi`` the band top
        of the least code so far (it only falls, so the final band is all kept). Returns ``(mu, count)``."""
        m = Q.shape[1]
        m16 = m - m % 16
        mu = np.int64(TAKEN)
        hi = np.int64(TAKEN - 1)
        count = 0
        for k0 in range(0, m16, 16):
            mask = np.uint64(band16(Q, r, k0, pen, np.uint16(lo), np.uint16(hi)))
            while mask != np.uint64(0):
                mask, bit = _lowest_bit(mask)
                band[count] = k0 + bit
                count += 1
                x = np.int64(Q[r, k0 + bit])  # not taken out: pen is 0 here
                if x < mu:
                    mu = x
                    hi = min(_band_top(mu, top_best, E, qoff, step), TAKEN - 1)
        for k in range(m16, m):
            x = np.int64(Q[r, k] | pen[k])
            if x >= lo and x <= hi:
                band[count] = k
                count += 1
                if x < mu:
                    mu = x
                    hi = min(_band_top(mu, top_best, E, qoff, step), TAKEN - 1)
        return mu, count

    @njit(cache=_cache, nogil=True)
    def next_in_line(Q, r, A, line, B, E, d, j, strict, skip, pen, pts, t_o2, qoff, step, band):
        """The next entry of line ``line`` after ``(d, j)`` in (exact distance, index) order.

        ``Q[r]``: the line's codes. Candidates: ``pen[k] == 0``, ``k != skip``, not within ``sqrt(t_o2)`` px
        of ``skip`` (FGINN), after ``(d, j)`` (``strict``) or ``>= d``. ``band``: int64 scratch of
        ``Q.shape[1]``. Returns ``(distance, index)``, ``(inf, -1)`` for none.
        """
        held = np.uint16(0)
        if skip >= 0:
            held = pen[skip]
            pen[skip] = TAKEN
        lo = _code_at_most(d * d - E, qoff, step)  # codes below: certainly closer than d
        best_d, best_k = np.inf, -1
        while lo < TAKEN:
            top_best = _code_at_least(best_d * best_d + E, qoff, step) if best_k >= 0 else np.int64(0)
            mu, count = _band_from(Q, r, pen, lo, top_best, E, qoff, step, band)
            if mu >= TAKEN:
                break
            top = _band_top(mu, top_best, E, qoff, step)
            hi = min(top, TAKEN - 1)
            for c in range(count):  # the band's entries, in column order
                k = band[c]
                if (Q[r, k] | pen[k]) <= hi:
                    best_d, best_k = _consider(A, line, B, k, d, j, strict, skip, pts, t_o2, best_d, best_k)
            # Codes <= top have been looked at; unseen entries decode to at least qoff + (top + 1) step.
            lo = top + 1
            if best_k >= 0 and qoff + lo * step - E > best_d * best_d * (1.0 + 1e-12):
                break
        if skip >= 0:
            pen[skip] = held
        return best_d, best_k

    @njit(cache=_cache, nogil=True, inline="always")
    def _prefetch_line(Q, r):
        """Prefetch line ``r`` of ``Q`` (a hint: no effect on any result)."""
        for k in range(0, Q.shape[1], 32):  # 32 codes: one 64-byte cache line
            prefetch(Q, r, k)

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
    def greedy_dense(Q, A, B, lidx, lval, E_rows, f_prime, qoff, step):
        """Step 2 over all of D (f = Ω): a heap of each row's next entry in (distance, column) order, from
        its sorted list, then from :func:`next_in_line` on its row of codes ``Q``."""
        n, m = Q.shape
        T = lidx.shape[1]
        rc = np.zeros(n, np.int64)
        cc = np.zeros(m, np.int64)
        pen = np.zeros(m, np.uint16)  # TAKEN: a saturated column
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
        band = np.empty(m, np.int64)
        while size > 0 and free_cols > 0:
            d, i, j, size = _hpop(hv, hi, hj, size)
            if cc[j] < f_prime:
                out_i[K], out_j[K], out_d[K] = i, j, d
                K += 1
                rc[i] += 1
                cc[j] += 1
                if cc[j] == f_prime:
                    pen[j] = TAKEN
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
            # Skip j itself: (d, j) is an entry of the row, and its code would otherwise enter the band.
            e, k = next_in_line(Q, i, A, i, B, E_rows[i], d, j, True, j, pen, dummy, 0.0, qoff, step, band)
            if k >= 0:
                size = _hpush(hv, hi, hj, size, e, i, k)
        return out_i[:K], out_j[:K], out_d[:K]

    @njit(cache=_cache, nogil=True)
    def next_in_lines(Q, rows, A, which, B, E_lines, d, j, strict, skip, pts, t_o2, qoff, step):
        """:func:`next_in_line` for lines ``which[r]`` of ``A`` (codes ``Q[rows[r]]``), prefetching
        :data:`AHEAD` lines ahead. Returns the exact distances and indices (``inf``, ``-1``: none)."""
        L = len(which)
        out_d = np.empty(L)
        out_k = np.empty(L, np.int64)
        pen = np.zeros(Q.shape[1], np.uint16)
        band = np.empty(Q.shape[1], np.int64)
        for r in range(min(AHEAD, L)):
            _prefetch_line(Q, rows[r])
        for r in range(L):
            if r + AHEAD < L:
                _prefetch_line(Q, rows[r + AHEAD])
            i = which[r]
            e, k = next_in_line(Q, rows[r], A, i, B, E_lines[i], d[r], j[r], strict[r], skip[r], pen, pts,
                                t_o2, qoff, step, band)
            out_d[r] = e
            out_k[r] = k
        return out_d, out_k
