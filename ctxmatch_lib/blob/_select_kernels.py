"""Compiled kernels of blob matching's steps 1-2 on the sorted lists: the pre-filter F∪ / F∩, the order by
(value, row, column) and the greedy many-to-many selection."""

from __future__ import annotations

import numpy as np
from numba import njit

from .._numerics.jit import user_cache

__all__ = ["prefilter_lists", "break_ties", "greedy_sorted"]


with user_cache() as _cache:

    @njit(cache=_cache, nogil=True)
    def prefilter_lists(ridx, rval, cidx, cval, fr, fc, cup):
        """Step 1: the entries of F∪ (Eq. 11, ``cup``) or F∩ (Eq. 10) as rows, columns and values, unordered;
        an entry of both lists comes once."""
        n, m = ridx.shape[0], cidx.shape[0]
        size = n * fr + (m * fc if cup else 0)
        rows, cols, vals = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size)
        k = 0
        for i in range(n):
            for t in range(fr):
                j = ridx[i, t]
                if not cup:
                    u = 0
                    while u < fc and cidx[j, u] != i:
                        u += 1
                    if u == fc:  # not among its column's f best
                        continue
                rows[k], cols[k], vals[k] = i, j, rval[i, t]
                k += 1
        if cup:
            for j in range(m):
                for u in range(fc):
                    i = cidx[j, u]
                    t = 0
                    while t < fr and ridx[i, t] != j:
                        t += 1
                    if t < fr:  # already in as its row's
                        continue
                    rows[k], cols[k], vals[k] = i, j, cval[j, u]
                    k += 1
        return rows[:k], cols[:k], vals[:k]

    @njit(cache=_cache, nogil=True)
    def break_ties(order, vals, first, second):
        """``order`` (an argsort of ``vals``) with every run of equal values reordered by (``first``,
        ``second``): the order of ``np.lexsort((second, first, vals))`` when those pairs are distinct."""
        N = len(order)
        s = 0
        while s < N:
            v = vals[order[s]]
            e = s + 1
            while e < N and vals[order[e]] == v:
                e += 1
            if e - s > 16:
                run = order[s:e].copy()
                key = np.empty(e - s, np.int64)
                top = 0
                for p in range(e - s):
                    top = max(top, second[run[p]] + 1)
                for p in range(e - s):
                    key[p] = first[run[p]] * top + second[run[p]]
                sub = np.argsort(key)
                for p in range(e - s):
                    order[s + p] = run[sub[p]]
            else:
                for p in range(s + 1, e):
                    x = order[p]
                    q = p - 1
                    while q >= s and (first[order[q]] > first[x]
                                      or (first[order[q]] == first[x] and second[order[q]] > second[x])):
                        order[q + 1] = order[q]
                        q -= 1
                    order[q + 1] = x
            s = e
        return order

    @njit(cache=_cache, nogil=True)
    def greedy_sorted(rows, cols, n, m, f_prime):
        """Step 2 on entries already sorted: accept while row and column counts stay <= f'."""
        rc = np.zeros(n, np.int64)
        cc = np.zeros(m, np.int64)
        acc = np.empty(len(rows), np.int64)
        k = 0
        for e in range(len(rows)):
            i, j = rows[e], cols[e]
            if rc[i] < f_prime and cc[j] < f_prime:
                rc[i] += 1
                cc[j] += 1
                acc[k] = e
                k += 1
        return acc[:k]
