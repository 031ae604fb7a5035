"""Compiled (numba) graph walks of DTM: triangle adjacency, alpha shapes, point location, DTM1 steps 3-6,
DTM2 step 2, vertex neighbourhoods and hull edges. No ``fastmath``, so the same bits on any machine;
cached under ``$CTXMATCH_CACHE/numba`` unless ``NUMBA_CACHE_DIR`` is set.
"""

from __future__ import annotations

import math
from functools import partial

import numba
import numpy as np

from .._numerics.jit import user_cache
from ._point_kernels import _group_by

__all__ = [
    "alpha_shapes_kernel",
    "circumradii_kernel",
    "contract_expand_kernel",
    "hull_edges_kernel",
    "locate_kernel",
    "neighbourhood_kernel",
    "row_counts_kernel",
    "transfer_test_kernel",
    "triangle_neighbors_kernel",
    "vertex_csr_kernel",
]


with user_cache() as _cache:
    _jit = partial(numba.njit, cache=_cache, nogil=True)

    @_jit(inline="always")
    def _edge_ends(simplices, t, k):
        """The two vertices of edge ``k`` of triangle ``t`` (the edge opposite vertex ``k``)."""
        if k == 0:
            return simplices[t, 1], simplices[t, 2]
        if k == 1:
            return simplices[t, 2], simplices[t, 0]
        return simplices[t, 0], simplices[t, 1]

    @_jit
    def triangle_neighbors_kernel(simplices, n_points):
        """``neighbors[t, k]``: the triangle across the edge of ``t`` opposite vertex ``k``, ``-1`` on the hull;
        twin edges meet in an open-addressing hash table keyed by their vertex pair."""
        n_tri = simplices.shape[0]
        bits = 4
        while (1 << bits) < 3 * n_tri:
            bits += 1
        mask = (1 << bits) - 1
        shift = np.uint64(64 - bits)
        fib = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing: the top bits of key * 2^64 / phi
        keys = np.full(1 << bits, -1, np.int64)  # -1: empty slot
        rows = np.empty(1 << bits, np.int64)  # the waiting edge's row, -1 once its pair is closed
        out = np.full((n_tri, 3), -1, np.int64)
        for t in range(n_tri):
            for k in range(3):
                a, b = _edge_ends(simplices, t, k)
                key = min(a, b) * n_points + max(a, b)
                h = np.int64((np.uint64(key) * fib) >> shift)
                while True:
                    if keys[h] == -1:
                        keys[h] = key
                        rows[h] = 3 * t + k
                        break
                    if keys[h] == key and rows[h] >= 0:
                        e = rows[h]
                        out[t, k] = e // 3
                        out[e // 3, e % 3] = t
                        rows[h] = -1
                        break
                    h = (h + 1) & mask
        return out

    @_jit(inline="always")
    def _find(parent, x):
        """Root of ``x``'s set, compressing the path."""
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            up = parent[x]
            parent[x] = root
            x = up
        return root

    @_jit(inline="always")
    def _union(parent, size, a, b):
        """Merge the sets of ``a`` and ``b`` (by size); 1 if they were apart, else 0."""
        a = _find(parent, a)
        b = _find(parent, b)
        if a == b:
            return 0
        if size[a] < size[b]:
            a, b = b, a
        parent[b] = a
        size[a] += size[b]
        return 1

    @_jit
    def circumradii_kernel(points, simplices):
        """Circumradius ``sqrt(a² b² c²) / (2 |cross|)`` of each triangle, ``inf`` when degenerate."""
        n_tri = simplices.shape[0]
        radii = np.empty(n_tri)
        for t in range(n_tri):
            i, j, m = simplices[t, 0], simplices[t, 1], simplices[t, 2]
            ax, ay, bx, by, cx, cy = points[i, 0], points[i, 1], points[j, 0], points[j, 1], points[m, 0], points[m, 1]
            ux, uy, vx, vy, wx, wy = bx - cx, by - cy, cx - ax, cy - ay, ax - bx, ay - by
            abc2 = ux * ux + uy * uy
            abc2 = abc2 * (vx * vx + vy * vy)
            abc2 = abc2 * (wx * wx + wy * wy)
            area2 = abs(vy * wx - vx * wy)
            radii[t] = math.inf if area2 == 0 else math.sqrt(abc2) / (2.0 * area2)
        return radii

    @_jit(inline="always")
    def _mesh_alpha(g, simplices, neighbors, radii, order, t_off, p_off, shrink, rank, parent, size, spectrum,
                    first):
        """The alpha of mesh ``g`` (:func:`alpha_shapes_kernel`); the other arrays are scratch."""
        lo, hi = t_off[g], t_off[g + 1]
        # The alpha spectrum: distinct radii, ascending; rank[t] is the index of radii[t] in it.
        n_spec = 0
        for i in range(lo, hi):
            r = radii[order[i]]
            if n_spec == 0 or r != spectrum[n_spec - 1]:
                spectrum[n_spec] = r
                n_spec += 1
            rank[order[i]] = n_spec - 1
        # Smallest spectrum index at which every triangulated point is enclosed.
        for v in range(p_off[g], p_off[g + 1]):
            first[v] = n_spec
        for t in range(lo, hi):
            for k in range(3):
                v = simplices[t, k]
                if rank[t] < first[v]:
                    first[v] = rank[t]
        all_points = -1
        for v in range(p_off[g], p_off[g + 1]):
            if first[v] < n_spec and first[v] > all_points:
                all_points = first[v]
        # Regions (union-find) at all_points, then higher ranks added until one region is left: critical alpha.
        regions = 0
        for t in range(lo, hi):
            if rank[t] <= all_points:
                regions += 1
                for k in range(3):
                    u = neighbors[t, k]
                    if u >= 0 and u < t and rank[u] <= all_points:
                        if _union(parent, size, t, u):
                            regions -= 1
        critical = all_points if regions == 1 else n_spec - 1
        i = lo
        while i < hi and rank[order[i]] <= all_points:
            i += 1
        while regions > 1 and i < hi:
            r = rank[order[i]]
            while i < hi and rank[order[i]] == r:  # a tie joins through either of its triangles
                t = order[i]
                regions += 1
                for k in range(3):
                    u = neighbors[t, k]
                    if u >= 0 and rank[u] <= r:
                        if _union(parent, size, t, u):
                            regions -= 1
                i += 1
            if regions == 1:
                critical = r
        n = n_spec - critical
        return spectrum[critical + max(math.ceil((1.0 - shrink) * n), 1) - 1]

    @_jit(inline="always")
    def _fill_holes(inside, neighbors):
        """Fill holes in place: outside triangles not reachable through outside ones from the hull."""
        n_tri = inside.shape[0]
        exterior = np.zeros(n_tri, np.bool_)
        stack = np.empty(n_tri, np.int64)
        top = 0
        for t in range(n_tri):
            if not inside[t] and (neighbors[t, 0] < 0 or neighbors[t, 1] < 0 or neighbors[t, 2] < 0):
                exterior[t] = True
                stack[top] = t
                top += 1
        while top > 0:
            top -= 1
            t = stack[top]
            for k in range(3):
                u = neighbors[t, k]
                if u >= 0 and not inside[u] and not exterior[u]:
                    exterior[u] = True
                    stack[top] = u
                    top += 1
        for t in range(n_tri):
            inside[t] = not exterior[t]

    @_jit(inline="always")
    def _boundary_edges(simplices, neighbors, inside, t_off):
        """Edges of inside triangles with an outside or no neighbour, in ``(t, k)`` order, offsets per mesh."""
        n_tri = inside.shape[0]
        n_groups = t_off.shape[0] - 1
        n_edges = 0
        for t in range(n_tri):
            if inside[t]:
                for k in range(3):
                    u = neighbors[t, k]
                    if u < 0 or not inside[u]:
                        n_edges += 1
        edges = np.empty((n_edges, 2), np.int64)
        e_off = np.zeros(n_groups + 1, np.int64)
        e = 0
        for g in range(n_groups):
            for t in range(t_off[g], t_off[g + 1]):
                if inside[t]:
                    for k in range(3):
                        u = neighbors[t, k]
                        if u < 0 or not inside[u]:
                            edges[e, 0] = simplices[t, (k + 1) % 3]
                            edges[e, 1] = simplices[t, (k + 2) % 3]
                            e += 1
            e_off[g + 1] = e
        return edges, e_off

    @_jit
    def alpha_shapes_kernel(simplices, neighbors, radii, order, t_off, p_off, shrink):
        """Holes-filled alpha shapes (:func:`ctxmatch_lib.dtm.boundary.matlab_boundary_alpha`) of the meshes
        of a disjoint union: mesh ``g`` holds triangles ``t_off[g]:t_off[g + 1]`` (``order`` ranks them by
        circumradius) and points ``p_off[g]:p_off[g + 1]``. Returns the alphas, inside flags, boundary edges
        and their offsets per mesh."""
        n_tri = simplices.shape[0]
        n_groups = t_off.shape[0] - 1
        alphas = np.empty(n_groups)
        rank = np.empty(n_tri, np.int64)
        parent = np.arange(n_tri)
        size = np.ones(n_tri, np.int64)
        spectrum = np.empty(n_tri)
        first = np.empty(p_off[n_groups], np.int64)
        for g in range(n_groups):
            alphas[g] = _mesh_alpha(g, simplices, neighbors, radii, order, t_off, p_off, shrink, rank, parent, size,
                                    spectrum, first)
        inside = np.empty(n_tri, np.bool_)
        for g in range(n_groups):
            for t in range(t_off[g], t_off[g + 1]):
                inside[t] = radii[t] <= alphas[g]
        _fill_holes(inside, neighbors)
        edges, e_off = _boundary_edges(simplices, neighbors, inside, t_off)
        return alphas, inside, edges, e_off

    @_jit(inline="always")
    def _cross(px, py, qx, qy, rx, ry):
        """z of ``(q - p) x (r - p)``."""
        return (qx - px) * (ry - py) - (qy - py) * (rx - px)

    @_jit
    def locate_kernel(points, simplices, neighbors, xy, nearest, max_steps):
        """Visibility walk of :meth:`~ctxmatch_lib.dtm.triangulation.Triangulation.find_simplex`: from a
        triangle at ``nearest[q]``, cross the edge with the smallest ``d_k`` while some ``d_k < -1e-12 |area|``.
        Returns the triangles (``-1`` past the hull) and which queries exceeded ``max_steps``."""
        n_tri = simplices.shape[0]
        first = np.full(points.shape[0], -1, np.int64)
        for t in range(n_tri - 1, -1, -1):
            for k in range(3):
                first[simplices[t, k]] = t
        n = xy.shape[0]
        out = np.full(n, -1, np.int64)
        unresolved = np.zeros(n, np.bool_)
        d = np.empty(3)
        for j in range(n):
            qx, qy = xy[j, 0], xy[j, 1]
            t = first[nearest[j]]
            if t < 0:
                t = 0
            steps = 0
            while True:
                if steps == max_steps:
                    unresolved[j] = True
                    break
                steps += 1
                i0, i1, i2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
                ax, ay, bx, by, cx, cy = points[i0, 0], points[i0, 1], points[i1, 0], points[i1, 1], points[i2, 0], points[i2, 1]
                area = _cross(ax, ay, bx, by, cx, cy)
                sgn = 1.0 if area > 0 else (-1.0 if area < 0 else 0.0)
                tol = 1e-12 * abs(area)
                d[0] = _cross(bx, by, cx, cy, qx, qy) * sgn
                d[1] = _cross(cx, cy, ax, ay, qx, qy) * sgn
                d[2] = _cross(ax, ay, bx, by, qx, qy) * sgn
                k_best = -1
                for k in range(3):
                    if d[k] < -tol or area == 0:
                        if k_best < 0 or d[k] < d[k_best]:
                            k_best = k
                if k_best < 0:
                    out[j] = t
                    break
                nxt = neighbors[t, k_best]
                if nxt < 0:
                    break
                t = nxt
        return out, unresolved

    @_jit(inline="always")
    def _strictly_inside(x, y, ax, ay, bx, by, cx, cy, orientation):
        """Whether ``(x, y)`` lies strictly inside triangle ``abc`` turning the way of ``orientation`` (+1, -1;
        0 holds nothing)."""
        return ((_cross(ax, ay, bx, by, x, y) * orientation > 0) and (_cross(bx, by, cx, cy, x, y) * orientation > 0)
                and (_cross(cx, cy, ax, ay, x, y) * orientation > 0))

    @_jit
    def transfer_test_kernel(simplex, simplices, points, n_vertices, indptr, indices, q_src, q_dst, base_src,
                             base_dst, base_vertex):
        """DTM2 step 2 in one direction (the rule: :func:`ctxmatch_lib.dtm.core._transfer_test`), given the
        triangle ``simplex`` (``-1``: none) holding each ``q_src``."""
        n = q_src.shape[0]
        ok = np.zeros(n, np.bool_)
        start, at = _group_by(base_vertex, n_vertices)  # base matches collapsed onto each vertex
        for q in range(n):
            t = simplex[q]
            if t < 0:
                continue
            w0, w1, w2 = simplices[t, 0], simplices[t, 1], simplices[t, 2]
            ax, ay, bx, by = points[w0, 0], points[w0, 1], points[w1, 0], points[w1, 1]
            cx, cy = points[w2, 0], points[w2, 1]
            area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            orientation = 1.0 if area > 0 else (-1.0 if area < 0 else 0.0)
            n_kp = (w0 < n_vertices) + (w1 < n_vertices) + (w2 < n_vertices)
            x, y = q_dst[q, 0], q_dst[q, 1]
            if n_kp == 3:
                for i in range(start[w0], start[w0 + 1]):
                    ea = at[i]
                    for j in range(start[w1], start[w1 + 1]):
                        eb = at[j]
                        for k in range(start[w2], start[w2 + 1]):
                            ec = at[k]
                            if _strictly_inside(x, y, base_dst[ea, 0], base_dst[ea, 1], base_dst[eb, 0],
                                                base_dst[eb, 1], base_dst[ec, 0], base_dst[ec, 1], orientation):
                                ok[q] = True
                                break
                        if ok[q]:
                            break
                    if ok[q]:
                        break
            elif n_kp > 0:
                near = -1
                best = np.inf
                for v in (w0, w1, w2):
                    if v < n_vertices:
                        dx = points[v, 0] - q_src[q, 0]
                        dy = points[v, 1] - q_src[q, 1]
                        d2 = dx * dx + dy * dy
                        if d2 < best or near < 0:
                            best = d2
                            near = v
                for j in range(indptr[near], indptr[near + 1]):
                    u = indices[j]
                    if u == near:
                        continue
                    for i in range(start[u], start[u + 1]):
                        e = at[i]
                        mx = q_dst[q, 0] - base_dst[e, 0] + base_src[e, 0]
                        my = q_dst[q, 1] - base_dst[e, 1] + base_src[e, 1]
                        if _strictly_inside(mx, my, ax, ay, bx, by, cx, cy, orientation):
                            ok[q] = True
                            break
                    if ok[q]:
                        break
        return ok

    @_jit
    def neighbourhood_kernel(indptr1, indices1, vertex1, indptr2, indices2, vertex2):
        """DTM1 step 3 from image 1: every pair ``(m, o)`` with the vertex of ``o`` adjacent to (not equal to)
        that of ``m``, by increasing ``m``, and whether their image-2 vertices are adjacent too."""
        n = vertex1.shape[0]
        start, at = _group_by(vertex1, indptr1.shape[0] - 1)  # matches on each image-1 vertex, increasing
        total = 0
        for m in range(n):
            v = vertex1[m]
            for j in range(indptr1[v], indptr1[v + 1]):
                u = indices1[j]
                if u != v:
                    total += start[u + 1] - start[u]
        rows = np.empty(total, np.int64)
        others = np.empty(total, np.int64)
        both = np.zeros(total, np.bool_)
        k = 0
        for m in range(n):
            v = vertex1[m]
            a = vertex2[m]
            for j in range(indptr1[v], indptr1[v + 1]):
                u = indices1[j]
                if u == v:
                    continue
                for i in range(start[u], start[u + 1]):
                    o = at[i]
                    rows[k] = m
                    others[k] = o
                    b = vertex2[o]
                    if a != b:
                        for e in range(indptr2[a], indptr2[a + 1]):
                            if indices2[e] == b:
                                both[k] = True
                                break
                    k += 1
        return rows, others, both

    @_jit
    def hull_edges_kernel(simplices, neighbors):
        """The edges with no triangle across (``neighbors[t, k] < 0``), in ``(t, k)`` order."""
        n = 0
        for t in range(simplices.shape[0]):
            for k in range(3):
                if neighbors[t, k] < 0:
                    n += 1
        out = np.empty((n, 2), np.int64)
        e = 0
        for t in range(simplices.shape[0]):
            for k in range(3):
                if neighbors[t, k] < 0:
                    out[e, 0], out[e, 1] = _edge_ends(simplices, t, k)
                    e += 1
        return out

    @_jit
    def vertex_csr_kernel(simplices, n):
        """CSR ``(indptr, indices)`` of the vertices ``< n`` adjacent to each vertex ``v < n``, ``v`` included,
        increasing."""
        count = np.zeros(n + 1, np.int64)
        for t in range(simplices.shape[0]):
            for k in range(3):
                a, b = simplices[t, k], simplices[t, k + 1 if k < 2 else 0]
                if a < n and b < n:
                    count[a] += 1
                    count[b] += 1
        start = np.zeros(n + 1, np.int64)
        for v in range(n):
            start[v + 1] = start[v] + count[v]
        buf = np.empty(start[n], np.int64)
        fill = start[:-1].copy()
        for t in range(simplices.shape[0]):
            for k in range(3):
                a, b = simplices[t, k], simplices[t, k + 1 if k < 2 else 0]
                if a < n and b < n:
                    buf[fill[a]] = b
                    fill[a] += 1
                    buf[fill[b]] = a
                    fill[b] += 1
        # Each edge is listed once per triangle holding it: drop the repeats (stamp), add v, sort the few left.
        indptr = np.zeros(n + 1, np.int64)
        indices = np.empty(start[n] + n, np.int64)
        stamp = np.full(n, -1, np.int64)
        m = 0
        for v in range(n):
            lo = m
            indices[m] = v
            m += 1
            stamp[v] = v
            for i in range(start[v], start[v + 1]):
                u = buf[i]
                if stamp[u] != v:
                    stamp[u] = v
                    indices[m] = u
                    m += 1
            for i in range(lo + 1, m):  # insertion sort of the few neighbours
                x = indices[i]
                j = i - 1
                while j >= lo and indices[j] > x:
                    indices[j + 1] = indices[j]
                    j -= 1
                indices[j + 1] = x
            indptr[v + 1] = m
        return indptr, indices[:m].copy()

    @_jit
    def row_counts_kernel(rows, flag, n):
        """``np.bincount(rows[flag], minlength=n)``: per row, how many of its pairs are flagged."""
        out = np.zeros(n, np.int64)
        for j in range(rows.shape[0]):
            if flag[j]:
                out[rows[j]] += 1
        return out

    @_jit
    def _row_ptr(rows, n):
        """CSR pointers of pairs grouped by non-decreasing ``rows``: row ``m`` holds ``ptr[m]:ptr[m + 1]``."""
        ptr = np.zeros(n + 1, np.int64)
        for j in range(rows.shape[0]):
            ptr[rows[j] + 1] += 1
        for m in range(n):
            ptr[m + 1] += ptr[m]
        return ptr

    @_jit
    def contract_expand_kernel(rank, rows_a, others_a, both_a, rows_b, others_b, both_b, n):
        """DTM1 steps 5-6 on the pairs of :func:`neighbourhood_kernel`: in ``rank`` order, pick each match
        still alive and kill ``(M_A1 ∪ M_A2) \\ (M_A1 ∩ M_A2)``; keep the union of ``M_A1 ∩ M_A2`` over the
        picks. Returns the picks in order and the kept flags."""
        ptr_a = _row_ptr(rows_a, n)
        ptr_b = _row_ptr(rows_b, n)
        alive = np.ones(n, np.bool_)
        picked = np.empty(n, np.int64)
        n_picked = 0
        for i in range(n):
            m = rank[i]
            if alive[m]:
                picked[n_picked] = m
                n_picked += 1
                for j in range(ptr_a[m], ptr_a[m + 1]):
                    if not both_a[j]:
                        alive[others_a[j]] = False
                for j in range(ptr_b[m], ptr_b[m + 1]):
                    if not both_b[j]:
                        alive[others_b[j]] = False
        kept = np.zeros(n, np.bool_)
        for i in range(n_picked):
            m = picked[i]
            for j in range(ptr_a[m], ptr_a[m + 1]):
                if both_a[j]:
                    kept[others_a[j]] = True
        return picked[:n_picked].copy(), kept
