"""Compiled (numba) loop behind :func:`ctxmatch_lib.metrics.ranked_area`: each correct candidate's term
``P_k * (N_k - N_{k-1})`` at its stable rank, bit-identical to :func:`ctxmatch_lib.metrics._area_terms_numpy`."""

from __future__ import annotations

import numpy as np
from numba import njit

from .jit import user_cache

__all__ = ["area_terms"]

with user_cache() as _cache:

    @njit(cache=_cache, nogil=True)
    def _area_terms(rows, cols, lab, scores, order, terms):
        # ``order`` sorts the scores (any algorithm): without ties (-0.0 == +0.0 included) it is the stable
        # order; with ties (rare) the merge sort's is taken.
        k = len(lab)
        for t in range(1, k):
            if scores[order[t]] == scores[order[t - 1]]:
                order = np.argsort(scores, kind="mergesort")
                break
        top_r, top_c = 0, 0
        for i in range(k):
            if lab[i]:
                top_r = max(top_r, rows[i])
                top_c = max(top_c, cols[i])
        seen_r = np.zeros(top_r + 1, np.bool_)
        seen_c = np.zeros(top_c + 1, np.bool_)
        n_r, n_c, n_prev, j = 0, 0, 0, 0
        for t in range(k):
            i = order[t]
            if not lab[i]:
                continue
            j += 1
            if not seen_r[rows[i]]:
                seen_r[rows[i]] = True
                n_r += 1
            if not seen_c[cols[i]]:
                seen_c[cols[i]] = True
                n_c += 1
            n = max(n_prev, min(n_r, n_c))
            terms[t] = j / (t + 1) * np.float64(n - n_prev)
            n_prev = n


def area_terms(rows: np.ndarray, cols: np.ndarray, lab: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """The terms of :func:`ctxmatch_lib.metrics.ranked_area` at their ranks (+0.0 at the wrong candidates'),
    for int64 ``rows``, ``cols``, bool ``lab`` and NaN-free float64 ``scores`` of one length."""
    scores = np.ascontiguousarray(scores, np.float64)
    lab = np.ascontiguousarray(lab, np.bool_)
    terms = np.zeros(len(lab))
    _area_terms(np.ascontiguousarray(rows, np.int64), np.ascontiguousarray(cols, np.int64), lab, scores,
                np.argsort(scores), terms)
    return terms
