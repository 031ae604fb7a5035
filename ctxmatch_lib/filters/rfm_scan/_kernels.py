"""Compiled (numba) neighbour counts of RFM-SCAN in its motion space, on a uniform grid.

Points are rows ``[x, y, v]`` (:class:`.rfm_scan._MotionSpace`'s float32 values as float64), distances
Eq. (3) of Jiang et al. (TIP 2020). A match within ``r`` has ``|dx| <= r`` and ``|dv| <= r / c(r)``,
``c(r) = 1 + gamma exp(-r / 2)``, which sets the grid cells over ``(x, v)``. Members are counted *surely*
(``d <= eps (1 - MARGIN)``) and *possibly* (``d <= eps (1 + MARGIN)``) within ``eps``, in float64; the
caller decides the open cases on its exact float32 distances.
"""

from __future__ import annotations

import math
from functools import partial

import numba
import numpy as np

from ..._numerics.fixedmath import exp
from ..._numerics.jit import user_cache

__all__ = ["MARGIN", "MotionGrid", "count_within", "upper_kth"]

#: Relative margin between the float64 distances of the kernels and the caller's float32 ones.
MARGIN = 1e-4

#: The grid's coordinates: the keypoint in image 1 and the motion vector.
_DIMS = (0, 1, 4, 5)


def _box_radii(radius: float, gamma: float) -> np.ndarray:
    """Half-widths of the box of ``(x, v)`` around a query holding every point within ``radius``."""
    c = 1.0 + gamma * float(exp(-radius / 2.0))
    return np.array([radius, radius, radius / c, radius / c])


class MotionGrid:
    """The points ``members`` of ``feats`` (n, 6) sorted by the cells of a uniform grid over ``(x, v)``.

    Cells are half the box of ``radius`` (at most ``cells_per_member`` per member); any radius can be queried."""

    def __init__(self, feats: np.ndarray, members: np.ndarray, radius: float, gamma: float,
                 cells_per_member: float = 4.0) -> None:
        members = np.asarray(members, np.int64)
        pts = np.ascontiguousarray(feats[members][:, _DIMS])
        self.origin = pts.min(0) if len(pts) else np.zeros(4)
        extent = pts.max(0) - self.origin if len(pts) else np.zeros(4)
        size = np.maximum(0.5 * _box_radii(radius * (1 + 2 * MARGIN), gamma), 1e-12)
        budget = max(cells_per_member * len(pts), 1.0)
        while True:
            shape = np.floor(extent / size).astype(np.int64) + 1
            if np.prod(shape.astype(np.float64)) <= budget:
                break
            size = size * max(1.05, float(np.prod(shape.astype(np.float64)) / budget) ** 0.25)
        self.size, self.shape = size, shape
        order, self.starts = _sort_by_cell(pts, self.origin, size, shape)
        self.members = members[order]
        self.feats = np.ascontiguousarray(feats[self.members], np.float64)


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _sort_by_cell(pts, origin, size, shape):
        # Counting sort of the points by cell (row-major over the four grid coordinates; ties: input order).
        n = pts.shape[0]
        ncell = shape[0] * shape[1] * shape[2] * shape[3]
        key = np.empty(n, np.int64)
        starts = np.zeros(ncell + 1, np.int64)
        for i in range(n):
            k = 0
            for a in range(4):
                c = min(np.int64(np.floor((pts[i, a] - origin[a]) / size[a])), shape[a] - 1)
                k = k * shape[a] + max(c, 0)
            key[i] = k
            starts[k + 1] += 1
        for c in range(ncell):
            starts[c + 1] += starts[c]
        fill = starts[:-1].copy()
        order = np.empty(n, np.int64)
        for i in range(n):
            order[fill[key[i]]] = i
            fill[key[i]] += 1
        return order, starts

    @_jit
    def _kth_rows(f, rows, cand, cscale, k, gamma, out):
        # out[r] = the k-th smallest d(rows[r], cand[r, c]) * cscale[r, c] over c (float64 Eq. (3)).
        m = cand.shape[1]
        buf = np.empty(m)
        for r in range(rows.shape[0]):
            i = rows[r]
            top = 0.0
            for c in range(m):
                j = cand[r, c]
                a = f[i, 0] - f[j, 0]
                b = f[i, 1] - f[j, 1]
                d1 = np.sqrt(a * a + b * b)
                a = f[i, 2] - f[j, 2]
                b = f[i, 3] - f[j, 3]
                d2 = np.sqrt(a * a + b * b)
                a = f[i, 4] - f[j, 4]
                b = f[i, 5] - f[j, 5]
                dv = np.sqrt(a * a + b * b)
                buf[c] = (d1 + d2 + (1.0 + gamma * math.exp(-min(d1, d2))) * dv) * cscale[r, c]
                top = max(top, buf[c])
            if k == m:  # the k-th smallest of k: the largest
                out[r] = top
            else:
                buf.sort()
                out[r] = buf[k - 1]

    @_jit
    def _count_within(qf, qscale, stop, on_possible, gf, gscale, starts, origin, size, shape, eps, gamma,
                      margin, sure, possible):
        # For each query q: the members j with t = d(q, j) * gscale * qscale[q] <= eps (1 -/+ margin), counted
        # into sure[q] / possible[q], until sure[q] (possible[q] with on_possible) reaches stop[q]; the cells
        # visited as in the module docstring.
        lo_t = eps * (1.0 - margin)
        hi_t = eps * (1.0 + margin)
        for q in range(qf.shape[0]):
            ns = sure[q]
            npos = possible[q]
            target = stop[q]
            if target <= 0 or (ns if not on_possible else npos) >= target:
                continue
            s = gscale * qscale[q]
            lo_d = lo_t / s
            hi_d = hi_t / s
            box = hi_d * (1.0 + 1e-9) + 1e-12  # the cell geometry's rounding
            c_min = 1.0 + gamma * math.exp(-hi_d / 2.0)
            x0, x1, y0, y1, v0, v1 = qf[q, 0], qf[q, 1], qf[q, 2], qf[q, 3], qf[q, 4], qf[q, 5]
            a0 = max(np.int64(np.floor((x0 - box - origin[0]) / size[0])), 0)
            b0 = min(np.int64(np.floor((x0 + box - origin[0]) / size[0])), shape[0] - 1)
            a1 = max(np.int64(np.floor((x1 - box - origin[1]) / size[1])), 0)
            b1 = min(np.int64(np.floor((x1 + box - origin[1]) / size[1])), shape[1] - 1)
            done = False
            for i0 in range(a0, b0 + 1):
                if done:
                    break
                e0 = origin[0] + i0 * size[0]
                g0 = max(e0 - x0, x0 - (e0 + size[0]), 0.0)
                for i1 in range(a1, b1 + 1):
                    if done:
                        break
                    e1 = origin[1] + i1 * size[1]
                    g1 = max(e1 - x1, x1 - (e1 + size[1]), 0.0)
                    lx = np.sqrt(g0 * g0 + g1 * g1)
                    if lx > box:
                        continue
                    vb = (box - lx) / c_min + 1e-12
                    a2 = max(np.int64(np.floor((v0 - vb - origin[2]) / size[2])), 0)
                    b2 = min(np.int64(np.floor((v0 + vb - origin[2]) / size[2])), shape[2] - 1)
                    a3 = max(np.int64(np.floor((v1 - vb - origin[3]) / size[3])), 0)
                    b3 = min(np.int64(np.floor((v1 + vb - origin[3]) / size[3])), shape[3] - 1)
                    if a3 > b3:
                        continue
                    for i2 in range(a2, b2 + 1):
                        if done:
                            break
                        base = ((i0 * shape[1] + i1) * shape[2] + i2) * shape[3]
                        for j in range(starts[base + a3], starts[base + b3 + 1]):
                            a = v0 - gf[j, 4]
                            b = v1 - gf[j, 5]
                            dv = np.sqrt(a * a + b * b)
                            if c_min * dv > hi_d:
                                continue
                            a = x0 - gf[j, 0]
                            b = x1 - gf[j, 1]
                            d1 = np.sqrt(a * a + b * b)
                            if d1 + c_min * dv > hi_d:
                                continue
                            a = y0 - gf[j, 2]
                            b = y1 - gf[j, 3]
                            d2 = np.sqrt(a * a + b * b)
                            if d1 + d2 + c_min * dv > hi_d:
                                continue
                            d = d1 + d2 + (1.0 + gamma * math.exp(-min(d1, d2))) * dv
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
    """``(sure, possible)`` counts of ``grid`` members with ``d * gscale * qscale`` within ``eps (1 -/+ MARGIN)``.

    ``qf`` (q, 6): queries, each stopping once its sure (``on_possible``: possible) count reaches ``stop``
    (0: never). Given ``sure``/``possible`` are added to; ``grid``'s radius must be ``>= eps / (gscale qscale)``.
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


def upper_kth(feats: np.ndarray, rows: np.ndarray, cand: np.ndarray, cscale: np.ndarray, k: int,
              gamma: float) -> np.ndarray:
    """``(r,)`` float32 upper bounds of the ``k``-th smallest ``d * cscale`` of ``rows`` to ``cand`` (r, m)."""
    out = np.empty(len(rows))
    if len(rows):
        _kth_rows(np.ascontiguousarray(feats, np.float64), np.ascontiguousarray(rows, np.int64),
                  np.ascontiguousarray(cand, np.int64), np.ascontiguousarray(cscale, np.float64), int(k),
                  float(gamma), out)
    return (out * (1.0 + MARGIN)).astype(np.float32)
