"""Vertex collapsing and Delaunay triangulations for DTM (Sec. 4): :func:`collapse_vertices` (DTM1 step 2),
:func:`triangulate` (``V ∪ B`` with the neighbourhoods ``A_v`` of step 3), :class:`IncrementalDelaunay`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from ._kernels import locate_kernel, triangle_neighbors_kernel, vertex_csr_kernel
from ._point_kernels import (
    doubled_areas_kernel,
    float32_exact_kernel,
    float32_row_keys_kernel,
    grid_nearest_kernel,
    integer_row_keys_kernel,
    key_rows_kernel,
    sorted_unique_rows_kernel,
)

__all__ = [
    "DelaunayMesh",
    "IncrementalDelaunay",
    "Triangulation",
    "collapse_vertices",
    "round_half_away",
    "unique_rows",
    "unique_ints",
    "triangulate",
    "delaunay_or_none",
    "delaunay_simplices",
    "points_in_triangles",
    "expand_ranges",
]


def round_half_away(x: np.ndarray) -> np.ndarray:
    """Round to the nearest integer, halves away from zero (MATLAB ``round``, the paper's ``⌈·⌋``)."""
    x = np.asarray(x, dtype=np.float64)
    return np.copysign(np.floor(np.abs(x) + 0.5), x)


def collapse_vertices(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Round ``(N, 2)`` points to integer pixels and merge duplicates (DTM1 step 2).

    Returns the distinct rounded points ``(V, 2)`` sorted by (x, y), and ``inverse`` ``(N,)``:
    ``vertices[inverse[n]]`` is the vertex point ``n`` collapsed into.

    Examples
    --------
    >>> v, inv = collapse_vertices(np.array([[1.2, 2.6], [0.0, 0.0], [0.8, 3.4]]))
    >>> v.tolist(), inv.tolist()
    ([[0.0, 0.0], [1.0, 3.0]], [1, 0, 1])
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) == 0:
        return np.empty((0, 2)), np.empty(0, np.int64)
    return unique_rows(round_half_away(points))


def unique_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(points, axis=0, return_inverse=True)`` for ``(N, 2)`` arrays: one sort of a 64-bit key
    per row when the values are integers or float32 values, else a lexsort."""
    key = None
    if len(points) > 1 and points.dtype == np.float64:
        points = np.ascontiguousarray(points)
        key, integer = integer_row_keys_kernel(points)
        if not integer:
            key, exact = float32_row_keys_kernel(points)
            key = key if exact else None
    if key is not None:
        order = np.argsort(key)  # equal rows are interchangeable here, so an unstable (SIMD) sort serves
        return sorted_unique_rows_kernel(points, key, order)
    new = np.ones(len(points), bool)
    order = np.lexsort((points[:, 1], points[:, 0]))
    srt = points[order]
    new[1:] = (srt[1:] != srt[:-1]).any(axis=1)
    inverse = np.empty(len(points), np.int64)
    inverse[order] = np.cumsum(new) - 1
    return srt[new], inverse


def unique_ints(x: np.ndarray) -> np.ndarray:
    """Sorted distinct values of a 1-D integer array (``np.unique`` without its hashing overhead)."""
    if len(x) > 64 and x.dtype == np.int64 and -2**31 <= x.min() and x.max() < 2**31:
        return unique_ints(x.astype(np.int32)).astype(np.int64)  # int32 sorts about twice as fast
    x = np.sort(x)
    if len(x) < 2:
        return x
    keep = np.ones(len(x), bool)
    keep[1:] = x[1:] != x[:-1]
    return x[keep]


def stable_argsort_small(keys: np.ndarray, n_keys: int) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` for integer keys in ``[0, n_keys)``, through int16 (radix sort)
    when they fit."""
    if n_keys <= 2**15:
        return np.argsort(keys.astype(np.int16), kind="stable")
    return np.argsort(keys, kind="stable")


@dataclass(frozen=True)
class DelaunayMesh:
    """A 2-D Delaunay triangulation (what DTM needs of ``scipy.spatial.Delaunay``): ``points`` ``(P, 2)``,
    ``simplices`` ``(T, 3)`` rows into them, and ``neighbors`` (scipy's convention, computed on first use)."""

    points: np.ndarray
    simplices: np.ndarray

    @cached_property
    def neighbors(self) -> np.ndarray:
        return triangle_neighbors_kernel(np.ascontiguousarray(self.simplices, np.int64), len(self.points))

    @property
    def convex_hull(self) -> np.ndarray:
        """Convex-hull edges, ndarray of shape (H, 2) (rows into ``points``)."""
        t, k = np.nonzero(self.neighbors < 0)
        return np.stack([self.simplices[t, (k + 1) % 3], self.simplices[t, (k + 2) % 3]], axis=1)

    @property
    def vertex_neighbor_vertices(self) -> tuple[np.ndarray, np.ndarray]:
        """CSR ``(indptr, indices)`` of the adjacent vertices of each point (increasing), as scipy's."""
        s = self.simplices
        a = np.concatenate([s[:, 0], s[:, 1], s[:, 2], s[:, 1], s[:, 2], s[:, 0]])
        b = np.concatenate([s[:, 1], s[:, 2], s[:, 0], s[:, 0], s[:, 1], s[:, 2]])
        n = len(self.points)
        key = unique_ints(a * n + b)  # each undirected edge appears in one or two triangles
        indptr = np.zeros(n + 1, np.int64)
        np.cumsum(np.bincount(key // n, minlength=n), out=indptr[1:])
        return indptr, key % n


def _float32_exact(points: np.ndarray) -> bool:
    """Whether ``points.astype(np.float32)`` holds the same values (compiled: one pass, no copies)."""
    return bool(float32_exact_kernel(np.ascontiguousarray(points, np.float64)))


class IncrementalDelaunay:
    """Delaunay triangulation of a point set that can grow by insertion (OpenCV ``Subdiv2D``, Qhull fallback).

    ``Subdiv2D`` (exact on float32-exact points) is used when its triangles use every point and cover the
    hull; otherwise Qhull. ``pad``: how far outside the bounding box of ``points`` later insertions may
    fall (farther: Qhull).
    """

    def __init__(self, points: np.ndarray, pad: float = 0.0):
        self.points = np.asarray(points, np.float64).reshape(-1, 2)
        self._sub = None
        if len(self.points) == 0 or not _float32_exact(self.points):
            return
        lo, hi = self.points.min(axis=0) - pad, self.points.max(axis=0) + pad
        ext = float((hi - lo).max()) + 1.0
        margin = 1024.0 * ext
        size = int(math.ceil(ext + 2.0 * margin)) + 2
        if size >= 2**30:
            return
        self._lo, self._hi = lo, hi
        self._sub = cv2.Subdiv2D((int(math.floor(lo[0] - margin)), int(math.floor(lo[1] - margin)), size, size))
        self._p32 = self.points.astype(np.float32) + np.float32(0.0)  # -0.0 -> 0.0: bit patterns identify points
        self._sub.insert(self._p32)

    def add(self, points: np.ndarray) -> None:
        """Insert more points (rows appended to :attr:`points`)."""
        points = np.asarray(points, np.float64).reshape(-1, 2)
        if len(points) == 0:
            return
        self.points = np.vstack([self.points, points])
        if self._sub is None:
            return
        if not _float32_exact(points) or (points < self._lo).any() or (points > self._hi).any():
            self._sub = None
            return
        p32 = points.astype(np.float32) + np.float32(0.0)
        self._p32 = np.vstack([self._p32, p32])
        self._sub.insert(p32)

    def simplices(self) -> np.ndarray:
        """Delaunay triangles, ``(T, 3)`` rows into :attr:`points` (none for fewer than three or collinear
        points)."""
        if len(self.points) < 3:
            return np.empty((0, 3), np.int64)
        if self._sub is not None:
            simplices = self._subdiv2d_simplices()
            if simplices is not None:
                return simplices
        try:
            return Delaunay(self.points).simplices.astype(np.int64)
        except (QhullError, ValueError):
            return np.empty((0, 3), np.int64)

    def _subdiv2d_simplices(self) -> np.ndarray | None:
        keys = np.ascontiguousarray(self._p32).view(np.int64).reshape(-1)
        tri = np.asarray(self._sub.getTriangleList(), np.float32).reshape(-1, 6)
        if len(tri) == 0:
            return None if len(np.unique(keys)) < len(keys) else np.empty((0, 3), np.int64)
        tk = np.ascontiguousarray(tri + np.float32(0.0)).view(np.int64).reshape(-1)
        # Every corner must be a point and every point a corner; duplicates go to Qhull.
        idx, status = key_rows_kernel(keys, tk)
        if status != 0:
            return None
        simplices = idx.reshape(-1, 3)
        area = doubled_areas_kernel(tri).sum()  # in float64, exact inputs: the float32 input coordinates
        hull = 2.0 * cv2.contourArea(cv2.convexHull(self._p32))
        if abs(area - hull) > 1e-9 * max(hull, 1.0):
            return None
        return simplices

    def mesh(self) -> DelaunayMesh | None:
        """The current triangulation as a :class:`DelaunayMesh`, ``None`` if it has no triangle."""
        simplices = self.simplices()
        return DelaunayMesh(self.points, simplices) if len(simplices) else None


def _subdiv2d_simplices(points: np.ndarray) -> np.ndarray | None:
    """Subdiv2D triangles of ``points`` or ``None`` when not usable (see :class:`IncrementalDelaunay`)."""
    inc = IncrementalDelaunay(points)
    return inc._subdiv2d_simplices() if inc._sub is not None else None


def delaunay_simplices(points: np.ndarray) -> np.ndarray:
    """Delaunay triangles of distinct ``(P, 2)`` points as ``(T, 3)`` rows into ``points`` (none for fewer
    than three or collinear points); see :class:`IncrementalDelaunay`."""
    return IncrementalDelaunay(points).simplices()


def delaunay_or_none(points: np.ndarray) -> DelaunayMesh | None:
    """Delaunay triangulation of ``points``, or ``None`` when they are fewer than three or all collinear."""
    return IncrementalDelaunay(points).mesh()


@dataclass(frozen=True)
class Triangulation:
    """A Delaunay triangulation of ``V ∪ B`` with the neighbourhoods of the ``V`` vertices.

    Attributes
    ----------
    points, n_vertices : ndarray of shape (P, 2), int
        Rows ``[:n_vertices]``: the collapsed keypoints ``V``; the rest: the boundary points ``B``.
    simplices, delaunay : ndarray of shape (T, 3), DelaunayMesh or None
        Triangles as rows into ``points``, and the mesh with its adjacency (empty / ``None`` if degenerate).
    indptr, indices : ndarray
        CSR ``A_v`` (step 3): the ``V`` vertices adjacent to ``v``, *including ``v`` itself*.
    """

    points: np.ndarray
    n_vertices: int
    simplices: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    delaunay: DelaunayMesh | None

    @property
    def boundary_points(self) -> np.ndarray:
        """The boundary set ``B``, ndarray of shape (P - n_vertices, 2)."""
        return self.points[self.n_vertices :]

    def find_simplex(self, xy: np.ndarray) -> np.ndarray:
        """Index of the triangle holding each point of ``xy`` (``(Q, 2)``), ``-1`` outside or degenerate.

        A visibility walk from the query's nearest vertex; points on an edge count as inside (either
        triangle); queries still walking after many steps are tested against every triangle.
        """
        xy = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        out = np.full(len(xy), -1, np.int64)
        if self.delaunay is None or len(xy) == 0 or len(self.simplices) == 0:
            return out
        simplices, p = self.simplices, np.ascontiguousarray(self.points, np.float64)
        _, nearest, tie = grid_nearest_kernel(xy, p)
        if tie:  # a query with two nearest vertices: the k-d tree's choice
            _, nearest = cKDTree(p, balanced_tree=False, compact_nodes=False).query(xy)
        out, unresolved = locate_kernel(p, np.ascontiguousarray(simplices, np.int64), self.delaunay.neighbors, xy,
                                        nearest.astype(np.int64), max(64, int(math.isqrt(len(simplices))) * 4))
        active = np.flatnonzero(unresolved)
        if len(active) == 0:
            return out
        corners = p[simplices]  # (T, 3, 2)
        a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
        n_tri = len(simplices)
        chunk = max(1, 65536 // n_tri)
        for start in range(0, len(active), chunk):
            q = active[start : start + chunk]
            inside = points_in_triangles(np.repeat(xy[q], n_tri, axis=0), np.tile(a, (len(q), 1)),
                                         np.tile(b, (len(q), 1)), np.tile(c, (len(q), 1))).reshape(len(q), -1)
            found = inside.any(axis=1)
            out[q[found]] = inside[found].argmax(axis=1)
        return out


def triangulate(vertices: np.ndarray, boundary: np.ndarray | None = None, *,
                simplices: np.ndarray | None = None) -> Triangulation:
    """Delaunay triangulation of ``V ∪ B`` and the neighbourhoods ``A_v`` of the ``V`` vertices (step 3).

    ``boundary`` points are triangulated but in no neighbourhood; ``simplices``: the triangles of
    ``V ∪ B`` when already known. Degenerate input gives no triangles and ``A_v = {v}``.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    boundary = np.empty((0, 2)) if boundary is None else np.asarray(boundary, np.float64).reshape(-1, 2)
    n = len(vertices)
    points = np.vstack([vertices, boundary]) if len(boundary) else vertices
    if simplices is None:
        tri = delaunay_or_none(points)
    else:
        tri = DelaunayMesh(points, np.asarray(simplices, np.int64).reshape(-1, 3)) if len(simplices) else None
    if tri is None:  # no triangles: A_v = {v}
        return Triangulation(points, n, np.empty((0, 3), np.int64), np.arange(n + 1, dtype=np.int64),
                             np.arange(n, dtype=np.int64), None)
    # Keypoint-keypoint edges both ways plus the self loops, sorted per vertex: CSR over V (compiled).
    indptr, indices = vertex_csr_kernel(np.ascontiguousarray(tri.simplices, np.int64), n)
    return Triangulation(points, n, tri.simplices, indptr, indices, tri)


def expand_ranges(starts: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The integer ranges ``[starts[r], starts[r] + lengths[r])``, range after range (``flat``), and the
    range ``r`` of each (``rows``).

    Examples
    --------
    >>> r, f = expand_ranges(np.array([5, 0]), np.array([2, 3]))
    >>> r.tolist(), f.tolist()
    ([0, 0, 1, 1, 1], [5, 6, 0, 1, 2])
    """
    starts = np.asarray(starts, np.int64)
    lengths = np.asarray(lengths, np.int64)
    total = int(lengths.sum())
    rows = np.repeat(np.arange(len(lengths), dtype=np.int64), lengths)
    if total == 0:
        return rows, np.empty(0, np.int64)
    offsets = np.cumsum(lengths) - lengths
    flat = np.arange(total, dtype=np.int64) - np.repeat(offsets - starts, lengths)
    return rows, flat


def points_in_triangles(xy: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Whether each point ``xy[k]`` lies in the closed triangle ``(a[k], b[k], c[k])`` (``(K, 2)`` arrays,
    either orientation; a zero-area triangle holds nothing)."""
    xy, a, b, c = (np.asarray(t, np.float64).reshape(-1, 2) for t in (xy, a, b, c))

    def cross(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    area = cross(a, b, c)
    d1, d2, d3 = cross(a, b, xy), cross(b, c, xy), cross(c, a, xy)
    # Tolerance relative to the triangle size, so that points on an edge count as inside.
    tol = 1e-12 * np.abs(area)
    sgn = np.sign(area)
    return (area != 0) & (d1 * sgn >= -tol) & (d2 * sgn >= -tol) & (d3 * sgn >= -tol)
