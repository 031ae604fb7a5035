"""Vertex collapsing, Delaunay triangulations and neighbourhoods for DTM (Sec. 4 of the paper).

Points are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.

The helpers here are the geometric kernel shared by DTM1 and DTM2:

- :func:`collapse_vertices` rounds keypoints and merges the ones that round to the same pixel
  (DTM1 step 2, "vertex collapsing by rounding-off");
- :func:`triangulate` builds the Delaunay triangulation of the vertex set ``V`` plus a boundary set ``B``
  and exposes the neighbourhoods ``A_v`` restricted to ``V`` (DTM1 step 3) as CSR arrays;
- :func:`points_in_triangles` is the vectorised point-in-triangle test of DTM2 step 2;
- :func:`expand_ranges` is the CSR "gather" used to enumerate neighbourhoods without Python loops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

__all__ = [
    "Triangulation",
    "collapse_vertices",
    "round_half_away",
    "triangulate",
    "points_in_triangles",
    "expand_ranges",
]


def round_half_away(x: np.ndarray) -> np.ndarray:
    """Round to the nearest integer, halves away from zero (MATLAB ``round``, the paper's ``⌈·⌋``)."""
    x = np.asarray(x, dtype=np.float64)
    return np.copysign(np.floor(np.abs(x) + 0.5), x)


def collapse_vertices(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Round points to integer pixels and merge duplicates (DTM1 step 2).

    Parameters
    ----------
    points : ndarray of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.

    Returns
    -------
    vertices : ndarray of shape (V, 2)
        The distinct rounded points, sorted lexicographically by (x, y), so that the vertex order does not
        depend on the order of ``points``.
    inverse : ndarray of shape (N,)
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
    rounded = round_half_away(points)
    vertices, inverse = np.unique(rounded, axis=0, return_inverse=True)
    return vertices, inverse.reshape(-1).astype(np.int64)


@dataclass(frozen=True)
class Triangulation:
    """A Delaunay triangulation of ``V ∪ B`` with the neighbourhoods of the ``V`` vertices.

    Attributes
    ----------
    points : ndarray of shape (P, 2)
        Triangulation vertices, (x, y) pixels: rows ``[:n_vertices]`` are the collapsed keypoints ``V``,
        the remaining rows the boundary points ``B`` (never matches).
    n_vertices : int
        ``|V|``.
    simplices : ndarray of shape (T, 3)
        Triangles as row indices into ``points`` (empty when fewer than three points are in general
        position).
    indptr, indices : ndarray
        CSR neighbourhoods over ``V``: ``indices[indptr[v]:indptr[v + 1]]`` are the ``V`` vertices adjacent
        to ``v``, *including ``v`` itself* (``A_v`` of DTM1 step 3; boundary vertices dropped).
    delaunay : scipy.spatial.Delaunay or None
        The scipy object, kept for point location (``find_simplex``); ``None`` when degenerate.
    """

    points: np.ndarray
    n_vertices: int
    simplices: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    delaunay: Delaunay | None

    @property
    def boundary_points(self) -> np.ndarray:
        """The boundary set ``B``, ndarray of shape (P - n_vertices, 2)."""
        return self.points[self.n_vertices :]

    def find_simplex(self, xy: np.ndarray) -> np.ndarray:
        """Index of the triangle holding each point of ``xy`` (``(Q, 2)``), ``-1`` outside or degenerate.

        Points are looked up among the triangles around their nearest vertex, which almost always hold
        them (a point on a shared edge gets the lowest-index triangle); the rest go to Qhull's exhaustive
        search. Qhull's own walk is not used: on the near-degenerate triangles that rounded coordinates
        produce it can fall back to the exhaustive search for every point (hundreds of ms per call).
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(xy), -1, np.int64)
        if self.delaunay is None or len(xy) == 0 or len(self.simplices) == 0:
            return out
        simplices, p = self.simplices, self.points
        _, nearest = cKDTree(p).query(xy)
        ptr, tri_of = _vertex_triangles(simplices, len(p))
        rows, pos = expand_ranges(ptr[nearest], np.diff(ptr)[nearest])
        cand = tri_of[pos]
        hit = points_in_triangles(xy[rows], p[simplices[cand, 0]], p[simplices[cand, 1]], p[simplices[cand, 2]])
        # rows are grouped by query with increasing triangles inside a group: keep the first hit
        rows_hit, first = np.unique(rows[hit], return_index=True)
        out[rows_hit] = cand[hit][first]
        miss = np.flatnonzero(out < 0)
        if len(miss):
            out[miss] = self.delaunay.find_simplex(xy[miss], bruteforce=True)
        return out


def _vertex_triangles(simplices: np.ndarray, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR map vertex -> incident triangles (increasing)."""
    flat = simplices.reshape(-1)
    order = np.argsort(flat, kind="stable")
    ptr = np.zeros(n_points + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n_points), out=ptr[1:])
    return ptr, order // 3


def delaunay_or_none(points: np.ndarray) -> Delaunay | None:
    """scipy Delaunay of ``points``, or ``None`` when they are fewer than three or all collinear."""
    if len(points) < 3:
        return None
    try:
        return Delaunay(points)
    except (QhullError, ValueError):
        return None


def triangulate(vertices: np.ndarray, boundary: np.ndarray | None = None) -> Triangulation:
    """Delaunay triangulation of ``V ∪ B`` and the neighbourhoods ``A_v`` of the ``V`` vertices.

    Parameters
    ----------
    vertices : ndarray of shape (V, 2)
        Distinct vertex points (x, y) pixels, e.g. from :func:`collapse_vertices`.
    boundary : ndarray of shape (Q, 2), optional
        Boundary points ``B`` (Sec. 4, Fig. 2). They take part in the triangulation but are excluded from
        the neighbourhoods, because they carry no match.

    Returns
    -------
    Triangulation
        With ``A_v`` as CSR arrays (DTM1 step 3). Degenerate input (fewer than three points in general
        position) gives no triangles and ``A_v = {v}``.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 2)
    boundary = np.empty((0, 2)) if boundary is None else np.asarray(boundary, np.float64).reshape(-1, 2)
    n = len(vertices)
    points = np.vstack([vertices, boundary]) if len(boundary) else vertices
    tri = delaunay_or_none(points)
    if tri is None:
        simplices = np.empty((0, 3), np.int64)
        indptr = np.arange(n + 1, dtype=np.int64)
        indices = np.arange(n, dtype=np.int64)
        return Triangulation(points, n, simplices, indptr, indices, None)
    nb_ptr, nb_idx = tri.vertex_neighbor_vertices
    # Neighbour lists of the V rows only, keypoint neighbours only, plus v itself.
    nb_ptr = nb_ptr[: n + 1].astype(np.int64)
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(nb_ptr))
    cols = nb_idx[: nb_ptr[-1]].astype(np.int64)
    keep = cols < n
    rows = np.concatenate([rows[keep], np.arange(n, dtype=np.int64)])
    cols = np.concatenate([cols[keep], np.arange(n, dtype=np.int64)])
    order = np.argsort(rows, kind="stable")
    indices = cols[order]
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n), out=indptr[1:])
    return Triangulation(points, n, tri.simplices.astype(np.int64), indptr, indices, tri)


def expand_ranges(starts: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Enumerate the integer ranges ``[starts[r], starts[r] + lengths[r])`` in one vectorised pass.

    Returns
    -------
    rows : ndarray of shape (L,)
        For each produced index, the range ``r`` it comes from.
    flat : ndarray of shape (L,)
        The produced indices, range after range.

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
    """Whether each point ``xy[k]`` lies in the closed triangle ``(a[k], b[k], c[k])``.

    All arguments are ``(K, 2)`` (x, y) arrays; either vertex orientation works. Degenerate (zero-area)
    triangles contain nothing.
    """
    xy, a, b, c = (np.asarray(t, np.float64).reshape(-1, 2) for t in (xy, a, b, c))

    def cross(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    area = cross(a, b, c)
    d1, d2, d3 = cross(a, b, xy), cross(b, c, xy), cross(c, a, xy)
    # Tolerance relative to the triangle size, so that points on an edge count as inside.
    tol = 1e-12 * np.abs(area)
    sgn = np.sign(area)
    return (area != 0) & (d1 * sgn >= -tol) & (d2 * sgn >= -tol) & (d3 * sgn >= -tol)
