"""Compiled (numba) point-set helpers of DTM: row keys, de-duplication and look-up of points
(:mod:`.triangulation`), nearest-vertex searches, and the boundary's ring tracing and sampling
(:mod:`._samples`). Same rules as :mod:`._kernels` (no ``fastmath``, cached on disk)."""

from __future__ import annotations

import math
from functools import partial

import numba
import numpy as np

from .._numerics.jit import user_cache

__all__ = [
    "doubled_areas_kernel",
    "float32_exact_kernel",
    "float32_row_keys_kernel",
    "grid_nearest_kernel",
    "inside_ring_kernel",
    "integer_row_keys_kernel",
    "key_rows_kernel",
    "nearest_kernel",
    "push_out_kernel",
    "sample_ring_kernel",
    "single_ring_kernel",
    "sorted_unique_rows_kernel",
]


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit
    def _group_by(keys, n_keys):
        """Counting sort: group ``k`` (positions of ``keys == k``, increasing) is ``order[start[k]:start[k + 1]]``."""
        start = np.zeros(n_keys + 1, np.int64)
        for i in range(keys.shape[0]):
            start[keys[i] + 1] += 1
        for k in range(n_keys):
            start[k + 1] += start[k]
        fill = start[:-1].copy()
        order = np.empty(keys.shape[0], np.int64)
        for i in range(keys.shape[0]):
            order[fill[keys[i]]] = i
            fill[keys[i]] += 1
        return start, order

    @_jit
    def single_ring_kernel(edges, n_points):
        """``edges`` as one closed ring of point indices from ``edges[0, 1]`` through ``edges[0, 0]`` (first
        repeated at the end) when they form one simple cycle, else empty (:func:`._samples._rings_from_edges`)."""
        n_edges = edges.shape[0]
        fail = np.empty(0, np.int64)
        if n_edges < 3:
            return fail
        degree = np.zeros(n_points, np.int64)
        inc = np.full((n_points, 2), -1, np.int64)  # the two edges at each endpoint
        for e in range(n_edges):
            for side in range(2):
                p = edges[e, side]
                if degree[p] == 2:
                    return fail
                inc[p, degree[p]] = e
                degree[p] += 1
        for e in range(n_edges):
            if degree[edges[e, 0]] != 2 or degree[edges[e, 1]] != 2 or edges[e, 0] == edges[e, 1]:
                return fail
        ring = np.empty(n_edges + 1, np.int64)
        ring[0] = edges[0, 1]
        ring[1] = edges[0, 0]
        prev_edge = 0
        for k in range(2, n_edges + 1):
            v = ring[k - 1]
            e = inc[v, 0] if inc[v, 0] != prev_edge else inc[v, 1]
            ring[k] = edges[e, 0] if edges[e, 1] == v else edges[e, 1]
            prev_edge = e
            if ring[k] == ring[0] and k < n_edges:
                return fail  # the cycle through edges[0] misses some edges: several rings
        if ring[n_edges] != ring[0]:
            return fail
        return ring

    @_jit(inline="always")
    def _closer(qx, qy, points, p, best, arg, again):
        """One step of both nearest-point searches: point ``p`` replaces ``(best, arg)`` when closer; at
        exactly ``best`` it raises the tie flag ``again``."""
        dx = qx - points[p, 0]
        dy = qy - points[p, 1]
        d2 = dx * dx + dy * dy
        if d2 < best:
            return d2, p, False
        if d2 == best:
            return best, arg, True
        return best, arg, again

    @_jit
    def nearest_kernel(queries, points):
        """Nearest of ``points`` to each query, exhaustively: distance (as ``cKDTree.query``), index, and
        whether any query has two nearest points at exactly the same distance."""
        n = queries.shape[0]
        dist = np.empty(n)
        index = np.empty(n, np.int64)
        tie = False
        for q in range(n):
            qx, qy = queries[q, 0], queries[q, 1]
            best = np.inf
            arg = -1
            again = False
            for i in range(points.shape[0]):
                best, arg, again = _closer(qx, qy, points, i, best, arg, again)
            tie = tie or again
            dist[q] = math.sqrt(best)
            index[q] = arg
        return dist, index, tie

    @_jit
    def grid_nearest_kernel(queries, points):
        """:func:`nearest_kernel` through a uniform grid (about two points per cell), bit for bit alike: each
        query visits rings of cells until the rest lie farther than its nearest point (with a margin)."""
        n, m = points.shape[0], queries.shape[0]
        dist = np.full(m, np.inf)
        index = np.full(m, -1, np.int64)
        tie = False
        if n == 0:
            return dist, index, tie
        x0, x1, y0, y1 = points[0, 0], points[0, 0], points[0, 1], points[0, 1]
        for i in range(n):
            x0, x1 = min(x0, points[i, 0]), max(x1, points[i, 0])
            y0, y1 = min(y0, points[i, 1]), max(y1, points[i, 1])
        w, h = x1 - x0, y1 - y0
        cell = max(math.sqrt(2.0 * w * h / n), max(w, h) / n)
        if not cell > 0:
            cell = 1.0
        nx, ny = min(int(w / cell) + 1, 4096), min(int(h / cell) + 1, 4096)
        cell = max(cell, w / nx * (1 + 1e-12), h / ny * (1 + 1e-12))  # after capping: nx, ny cells cover the box
        key = np.empty(n, np.int64)
        for i in range(n):
            cx = min(max(int((points[i, 0] - x0) / cell), 0), nx - 1)
            cy = min(max(int((points[i, 1] - y0) / cell), 0), ny - 1)
            key[i] = cy * nx + cx
        start, at = _group_by(key, nx * ny)
        margin = 1e-9 * cell
        for q in range(m):
            qx, qy = queries[q, 0], queries[q, 1]
            fx, fy = (qx - x0) / cell, (qy - y0) / cell
            cx = 0 if fx < 0 else min(int(fx), nx - 1)
            cy = 0 if fy < 0 else min(int(fy), ny - 1)
            best = np.inf
            arg = -1
            again = False
            r = 0
            while True:
                if r > 0:
                    # Lower bound on the distance to cells outside the rings < r.
                    lb = np.inf
                    if cx - r >= 0:
                        lb = min(lb, qx - (x0 + (cx - r + 1) * cell))
                    if cx + r < nx:
                        lb = min(lb, x0 + (cx + r) * cell - qx)
                    if cy - r >= 0:
                        lb = min(lb, qy - (y0 + (cy - r + 1) * cell))
                    if cy + r < ny:
                        lb = min(lb, y0 + (cy + r) * cell - qy)
                    if lb == np.inf:
                        break  # the box covers the grid
                    lb -= margin
                    if lb > 0 and lb * lb > best * (1.0 + 1e-9):
                        break
                for j in range(max(cy - r, 0), min(cy + r, ny - 1) + 1):
                    edge_row = j == cy - r or j == cy + r
                    step = 1 if edge_row else 2 * r
                    i = cx - r
                    while i <= cx + r:
                        if 0 <= i < nx:
                            c = j * nx + i
                            for k in range(start[c], start[c + 1]):
                                best, arg, again = _closer(qx, qy, points, at[k], best, arg, again)
                        if r == 0:
                            break
                        i += step
                r += 1
            tie = tie or again
            dist[q] = math.sqrt(best)
            index[q] = arg
        return dist, index, tie

    @_jit
    def push_out_kernel(b, vertices, d, j, s):
        """The move of :func:`._samples._keep_clear`: samples closer than ``s`` to their nearest vertex moved
        radially to ``v + (b - v) * (s / d)``; those at least ``s / 2`` away are kept, with their distances."""
        moved = b.copy()
        for i in range(b.shape[0]):
            if d[i] < s * (1 - 1e-9) and d[i] > 1e-9 * s:
                f = s / d[i]
                for c in range(2):
                    moved[i, c] = vertices[j[i], c] + (b[i, c] - vertices[j[i], c]) * f
        d2 = grid_nearest_kernel(moved, vertices)[0]
        n = 0
        for i in range(b.shape[0]):
            if d2[i] >= 0.5 * s:
                n += 1
        out = np.empty((n, 2))
        dist = np.empty(n)
        k = 0
        for i in range(b.shape[0]):
            if d2[i] >= 0.5 * s:
                out[k, 0], out[k, 1], dist[k] = moved[i, 0], moved[i, 1], d2[i]
                k += 1
        return out, dist

    @_jit
    def inside_ring_kernel(ring, xy):
        """Crossing-number test of each point of ``xy`` against the closed ``ring``, and whether every answer
        is certain: each orientation must exceed a rounding-error bound (Shewchuk's, widened a hundredfold);
        a certain answer is the exact one, hence GEOS's."""
        n_edges = ring.shape[0] - 1
        inside = np.zeros(xy.shape[0], np.bool_)
        for q in range(xy.shape[0]):
            px, py = xy[q, 0], xy[q, 1]
            odd = False
            for e in range(n_edges):
                ax, ay, bx, by = ring[e, 0], ring[e, 1], ring[e + 1, 0], ring[e + 1, 1]
                t1 = (bx - ax) * (py - ay)
                t2 = (by - ay) * (px - ax)
                det = t1 - t2
                if abs(det) <= 1e-13 * (abs(t1) + abs(t2)) or det == 0:
                    return inside, False
                if (ay > py) != (by > py):  # the edge crosses the horizontal line through the point
                    # it crosses right of the point when the point lies left of the upward edge
                    if (det > 0) == (by > ay):
                        odd = not odd
            inside[q] = odd
        return inside, True

    @_jit
    def doubled_areas_kernel(tri):
        """Twice the area of each float32 triangle ``(x0, y0, x1, y1, x2, y2)``, computed in float64."""
        out = np.empty(tri.shape[0])
        for t in range(tri.shape[0]):
            x0, y0 = np.float64(tri[t, 0]), np.float64(tri[t, 1])
            x1, y1 = np.float64(tri[t, 2]), np.float64(tri[t, 3])
            x2, y2 = np.float64(tri[t, 4]), np.float64(tri[t, 5])
            out[t] = abs((x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0))
        return out

    @_jit
    def integer_row_keys_kernel(points):
        """``((x << 31) + y, True)`` per row when every value is an integer in ``(-2**30, 2**30)``, else
        ``(_, False)``."""
        n = points.shape[0]
        key = np.empty(n, np.int64)
        for i in range(n):
            x, y = points[i, 0], points[i, 1]
            if not (-2.0**30 < x < 2.0**30 and -2.0**30 < y < 2.0**30):
                return key, False
            xi, yi = np.int64(x), np.int64(y)
            if np.float64(xi) != x or np.float64(yi) != y:
                return key, False
            key[i] = (xi << 31) + yi
        return key, True

    @_jit
    def float32_row_keys_kernel(points):
        """``(key, True)``, one uint64 per row in lexicographic row order (monotone float32 bit patterns, ``x``
        high), when every value is a float32 value in ``(-2**30, 2**30)``, else ``(_, False)``."""
        n = points.shape[0]
        p32 = np.empty((n, 2), np.float32)
        for i in range(n):
            for c in range(2):
                x = points[i, c]
                if not (-2.0**30 < x < 2.0**30):
                    return np.empty(0, np.uint64), False
                f = np.float32(x)
                if np.float64(f) != x:
                    return np.empty(0, np.uint64), False
                p32[i, c] = f + np.float32(0.0)
        bits = p32.view(np.uint32)
        key = np.empty(n, np.uint64)
        for i in range(n):
            m = np.empty(2, np.uint64)
            for c in range(2):
                b = np.uint64(bits[i, c])
                m[c] = (~b & np.uint64(0xFFFFFFFF)) if b >> np.uint64(31) else (b | np.uint64(1 << 31))
            key[i] = (m[0] << np.uint64(32)) | m[1]
        return key, True

    @_jit
    def sorted_unique_rows_kernel(points, key, order):
        """The first row of each run of equal ``key[order]``, and each row's run."""
        n = order.shape[0]
        inverse = np.empty(n, np.int64)
        first = np.empty(n, np.int64)
        m = -1
        for i in range(n):
            if i == 0 or key[order[i]] != key[order[i - 1]]:
                m += 1
                first[m] = order[i]
            inverse[order[i]] = m
        out = np.empty((m + 1, 2))
        for j in range(m + 1):
            out[j, 0] = points[first[j], 0]
            out[j, 1] = points[first[j], 1]
        return out, inverse

    @_jit
    def float32_exact_kernel(points):
        """Whether every value of ``points`` is a float32 value (NaN never is)."""
        flat = points.reshape(-1)
        for i in range(flat.shape[0]):
            if np.float64(np.float32(flat[i])) != flat[i]:
                return False
        return True

    @_jit(error_model="numpy")
    def sample_ring_kernel(ring, s):
        """The samples of one closed ring at ``0, L / n, ..., (n - 1) L / n`` of its length ``L``,
        ``n = max(ceil(L / s - 1e-9), 3)`` (:func:`._samples._sample_rings`); none for zero length."""
        n_seg = ring.shape[0] - 1
        seg = np.empty(max(n_seg, 0))
        cum = np.empty(max(n_seg, 0))
        total = 0.0
        for i in range(n_seg):
            dx = ring[i + 1, 0] - ring[i, 0]
            dy = ring[i + 1, 1] - ring[i, 1]
            seg[i] = math.sqrt(dx * dx + dy * dy)
            total += seg[i]
            cum[i] = total
        length = cum[n_seg - 1] if n_seg > 0 else 0.0
        if not length > 0:
            return np.empty((0, 2))
        n = max(int(math.ceil(length / s - 1e-9)), 3)
        step = length / n
        out = np.empty((n, 2))
        for j in range(n):
            t = j * step
            lo, hi = 0, n_seg  # searchsorted(cum, t, side="right"): the first i with cum[i] > t
            while lo < hi:
                mid = (lo + hi) // 2
                if cum[mid] <= t:
                    lo = mid + 1
                else:
                    hi = mid
            i = min(lo, n_seg - 1)
            frac = (t - (cum[i - 1] if i > 0 else 0.0)) / seg[i]
            for c in range(2):
                p0, p1 = ring[i, c], ring[i + 1, c]
                out[j, c] = p0 if frac <= 0 else (p1 if frac >= 1 else (p1 - p0) * frac + p0)
        return out

    @_jit
    def key_rows_kernel(keys, queries):
        """Row of each query among the int64 ``keys`` (open-addressing hash table). ``status``: 0 when queries
        and keys match up, 1 on duplicate keys, 2 when a query is no key, 3 when a key is no query's."""
        n = keys.shape[0]
        bits = 4
        while (1 << bits) < 4 * n:
            bits += 1
        mask = (1 << bits) - 1
        shift = np.uint64(64 - bits)
        fib = np.uint64(0x9E3779B97F4A7C15)
        table = np.full(1 << bits, -1, np.int64)
        rows = np.empty(queries.shape[0], np.int64)
        for i in range(n):
            h = np.int64((np.uint64(keys[i]) * fib) >> shift)
            while table[h] >= 0:
                if keys[table[h]] == keys[i]:
                    return rows, 1
                h = (h + 1) & mask
            table[h] = i
        seen = np.zeros(n, np.bool_)
        for q in range(queries.shape[0]):
            h = np.int64((np.uint64(queries[q]) * fib) >> shift)
            while True:
                r = table[h]
                if r < 0:
                    return rows, 2
                if keys[r] == queries[q]:
                    break
                h = (h + 1) & mask
            rows[q] = r
            seen[r] = True
        for i in range(n):
            if not seen[i]:
                return rows, 3
        return rows, 0
