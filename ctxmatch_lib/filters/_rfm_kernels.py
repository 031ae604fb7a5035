"""Compiled (numba) neighbour counts of RFM-SCAN in its motion space, on a uniform grid.

The motion-space points are rows ``[x, y, v]`` (six coordinates in [0, 1], the float32 values of
:class:`ctxmatch_lib.filters.rfm_scan._MotionSpace` held as float64), and the distance is Eq. (3) of Jiang
et al. (TIP 2020), ``d = |dx| + |dy| + (1 + gamma exp(-min(|dx|, |dy|))) |dv|``. A match within ``r`` of a
query has ``|dx| <= r`` and, its motion weight being at least ``c(r) = 1 + gamma exp(-r / 2)`` (the smaller
of two norms summing to at most ``r`` is at most ``r / 2``), ``|dv| <= r / c(r)``: the grid has cells of
those sizes over ``(x, v)`` and a query visits the cells of that box.

The kernels never decide alone. They compute Eq. (3) in float64 and count the members *surely* within the
threshold (``t <= eps (1 - MARGIN)``) and those *possibly* within it (``t <= eps (1 + MARGIN)``); the
filter's own float32 distances differ from these by a few float32 roundings, relative (every term of Eq. (3)
is non-negative), far below ``MARGIN``. A count that the two do not settle is left to the exact float32 test
of the caller.

Compiled code is cached on disk as for the other kernels (``$CTXMATCH_CACHE/numba`` unless
``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

from functools import partial

import numba
import numpy as np

from .._numba import user_cache

__all__ = ["MARGIN", "MotionGrid", "count_within"]

#: Relative margin between the float64 distances of the kernels and the caller's float32 ones.
MARGIN = 1e-4

#: The grid's coordinates: the keypoint in image 1 and the motion vector.
_DIMS = (0, 1, 4, 5)


def _box_radii(radius: float, gamma: float) -> np.ndarray:
    """Half-widths of the box of ``(x, v)`` around a query holding every point within ``radius``."""
    c = 1.0 + gamma * np.exp(-radius / 2.0)
    return np.array([radius, radius, radius / c, radius / c])


class MotionGrid:
    """Members of a motion space sorted by the cells of a uniform grid over ``(x, v)``.

    Parameters
    ----------
    feats : ndarray of shape (n, 6)
        Motion-space points (float64).
    members : ndarray of shape (m,)
        Indices of the points in the grid.
    radius : float
        The largest query radius (true distance) the grid serves; the cells are at least the box of
        that radius (larger when that would make more than ``cells_per_member`` cells per member).
    gamma : float
        Eq. (3)'s gamma (the float32 value the caller's distances use).
    """

    def __init__(self, feats: np.ndarray, members: np.ndarray, radius: float, gamma: float,
                 cells_per_member: float = 4.0) -> None:
        pts = feats[members][:, _DIMS]
        self.origin = pts.min(0) if len(pts) else np.zeros(4)
        extent = pts.max(0) - self.origin if len(pts) else np.zeros(4)
        size = np.maximum(_box_radii(radius * (1 + 2 * MARGIN), gamma), 1e-12)
        budget = max(cells_per_member * len(pts), 1.0)
        while True:
            shape = np.floor(extent / size).astype(np.int64) + 1
            if np.prod(shape.astype(np.float64)) <= budget:
                break
            size = size * max(1.05, (np.prod(shape.astype(np.float64)) / budget) ** 0.25)
        self.size, self.shape = size, shape
        cell = np.minimum(np.floor((pts - self.origin) / size).astype(np.int64), shape - 1)
        key = ((cell[:, 0] * shape[1] + cell[:, 1]) * shape[2] + cell[:, 2]) * shape[3] + cell[:, 3]
        order = np.argsort(key, kind="stable")
        self.members = members[order]
        self.feats = np.ascontiguousarray(feats[self.members])
        self.starts = np.searchsorted(key[order], np.arange(int(np.prod(shape)) + 1)).astype(np.int64)


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _count_within(qf, qscale, stop, on_possible, gf, gscale, starts, origin, size, shape, eps, gamma,
                      margin, sure, possible):
        # For each query q: the members j with t = d(q, j) * gscale * qscale[q] <= eps (1 -/+ margin), counted
        # into sure[q] / possible[q], until sure[q] (possible[q] with on_possible) reaches stop[q].
        lo_t = eps * (1.0 - margin)
        hi_t = eps * (1.0 + margin)
        box = np.empty(4)
        lo = np.empty(4, np.int64)
        hi = np.empty(4, np.int64)
        for q in range(qf.shape[0]):
            if stop[q] <= 0:
                continue
            s = gscale * qscale[q]
            lo_d = lo_t / s
            hi_d = hi_t / s
            c_min = 1.0 + gamma * np.exp(-hi_d / 2.0)
            box[0] = hi_d
            box[1] = hi_d
            box[2] = hi_d / c_min
            box[3] = hi_d / c_min
            empty = False
            for a in range(4):
                col = a if a < 2 else a + 2
                lo[a] = max(np.int64(np.floor((qf[q, col] - box[a] - origin[a]) / size[a])), 0)
                hi[a] = min(np.int64(np.floor((qf[q, col] + box[a] - origin[a]) / size[a])), shape[a] - 1)
                if lo[a] > hi[a]:
                    empty = True
            if empty:
                continue
            ns = sure[q]
            npos = possible[q]
            target = stop[q]
            if (ns if not on_possible else npos) >= target:
                continue
            done = False
            x0, x1, y0, y1, v0, v1 = qf[q, 0], qf[q, 1], qf[q, 2], qf[q, 3], qf[q, 4], qf[q, 5]
            for i0 in range(lo[0], hi[0] + 1):
                if done:
                    break
                for i1 in range(lo[1], hi[1] + 1):
                    if done:
                        break
                    for i2 in range(lo[2], hi[2] + 1):
                        if done:
                            break
                        base = ((i0 * shape[1] + i1) * shape[2] + i2) * shape[3]
                        for j in range(starts[base + lo[3]], starts[base + hi[3] + 1]):
                            a = x0 - gf[j, 0]
                            b = x1 - gf[j, 1]
                            d1 = np.sqrt(a * a + b * b)
                            if d1 > hi_d:
                                continue
                            a = y0 - gf[j, 2]
                            b = y1 - gf[j, 3]
                            d2 = np.sqrt(a * a + b * b)
                            if d1 + d2 > hi_d:
                                continue
                            a = v0 - gf[j, 4]
                            b = v1 - gf[j, 5]
                            dv = np.sqrt(a * a + b * b)
                            if d1 + d2 + c_min * dv > hi_d:
                                continue
                            d = d1 + d2 + (1.0 + gamma * np.exp(-min(d1, d2))) * dv
                            if d <= hi_d:
                                npos += 1
                                if d <= lo_d:
                                    ns += 1
                                if (ns if not on_possible else npos) >= target:
                                    done = True
                                    break
            sure[q] = ns
            possible[q] = npos


def count_within(grid: MotionGrid, qf: np.ndarray, qscale: np.ndarray, stop: np.ndarray, eps: float,
                 gamma: float, gscale: float = 1.0, sure: np.ndarray | None = None,
                 possible: np.ndarray | None = None, on_possible: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Members of ``grid`` surely / possibly within ``eps`` of each query, the distance scaled.

    Parameters
    ----------
    grid : MotionGrid
        Built for a radius of at least ``eps / (gscale * qscale)`` of every query.
    qf : ndarray of shape (q, 6)
        The queries' motion-space points (float64).
    qscale : ndarray of shape (q,)
        Per-query factor of the distance (with ``gscale``, the group's).
    stop : ndarray of shape (q,)
        A query stops counting once its sure count (possible count with ``on_possible``) reaches it; 0 or
        less: not counted.
    eps : float
        The threshold of the scaled distance ``d * gscale * qscale``.
    gamma : float
        Eq. (3)'s gamma.
    sure, possible : ndarray of shape (q,), optional
        Counts to add to (int64, updated in place); zeros when left out.

    Returns
    -------
    sure, possible : ndarray of shape (q,)
        Members with scaled distance at most ``eps (1 - MARGIN)`` and at most ``eps (1 + MARGIN)``, the
        counts stopped early as said (cumulated over calls when passed in).
    """
    n = len(qf)
    sure = np.zeros(n, np.int64) if sure is None else sure
    possible = np.zeros(n, np.int64) if possible is None else possible
    if n and len(grid.members):
        _count_within(np.ascontiguousarray(qf, np.float64), np.ascontiguousarray(qscale, np.float64),
                      np.ascontiguousarray(stop, np.int64), bool(on_possible), grid.feats, float(gscale),
                      grid.starts, grid.origin, grid.size, grid.shape, float(eps), float(gamma), MARGIN,
                      sure, possible)
    return sure, possible
