"""The boundary set's geometry helpers of :mod:`ctxmatch_lib.dtm.boundary` (private): the fattened edges,
the contour rings as GEOS gives them, their samples at a fixed step and the samples kept clear of the
vertices (Sec. 4, Fig. 2). Points are (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from ._point_kernels import grid_nearest_kernel, push_out_kernel, sample_ring_kernel, single_ring_kernel
from .triangulation import unique_rows

_EMPTY2 = np.empty((0, 2))


def _to_float32(points: np.ndarray) -> np.ndarray:
    """Round constructed points to the nearest float32 (under 4e-5 px for coordinates below 1000).

    The triangulation kernel (:func:`~ctxmatch_lib.dtm.triangulation.delaunay_simplices`) is exact, and
    fastest, on float32-representable coordinates; rounding here keeps the stored points identical to the
    triangulated ones.
    """
    return np.asarray(points, np.float64).astype(np.float32).astype(np.float64)


def _fatten(points: np.ndarray, edges: np.ndarray, s: float) -> np.ndarray:
    """``B'``: the points at distance ``s`` on both sides of each edge, through both its vertices."""
    p0, p1 = points[edges[:, 0]], points[edges[:, 1]]
    d = p1 - p0
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    return _to_float32(np.stack([p0 + s * n, p1 + s * n, p0 - s * n, p1 - s * n], axis=1).reshape(-1, 2))


def _rings_from_edges(points: np.ndarray, edges: np.ndarray) -> list:
    """Closed rings (as (R, 2) arrays, first point repeated) of the polygons bounded by ``edges``.

    The rings are GEOS's (``shapely.polygonize``): their start and direction set where the boundary samples
    fall (:func:`_sample_rings`). The common case, edges forming one simple cycle, is traced by a compiled
    walk (:func:`~ctxmatch_lib.dtm._point_kernels.single_ring_kernel`) that gives GEOS's ring for it (from
    ``edges[0, 1]`` through ``edges[0, 0]``, clockwise); a traced ring that turns counter-clockwise, and
    every other edge set, goes to GEOS.
    """
    if len(edges) == 0:
        return []
    ring = single_ring_kernel(np.ascontiguousarray(edges, np.int64), len(points))
    if len(ring):
        xy = points[ring]
        x, y = xy[:, 0], xy[:, 1]
        if float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1])) < 0:  # twice the signed area: clockwise
            return [xy]
    lines = shapely.linestrings(np.stack([points[edges[:, 0]], points[edges[:, 1]]], axis=1))
    polys = shapely.get_parts(shapely.polygonize(lines))
    return [shapely.get_coordinates(shapely.get_exterior_ring(p)) for p in polys]


def _sample_rings(rings: list, s: float) -> np.ndarray:
    """Split every ring into equal segments of length at most ``s``; return the segment vertices.

    The points are GEOS's ``line_interpolate_point`` at ``0, L / n, ..., (n - 1) L / n`` of the ring of
    length ``L`` (``n = max(ceil(L / s), 3)``), computed with its arithmetic in NumPy, bit for bit: segment
    lengths ``sqrt(dx² + dy²)`` summed in ring order, the point on the first segment whose running length
    exceeds the distance, at ``p0 + (p1 - p0) * frac`` (compiled,
    :func:`~ctxmatch_lib.dtm._point_kernels.sample_ring_kernel`).
    """
    out = [sample_ring_kernel(np.ascontiguousarray(ring, np.float64), float(s)) for ring in rings]
    out = [o for o in out if len(o)]
    return np.vstack(out) if out else _EMPTY2


def _nearest(b: np.ndarray, vertices: np.ndarray, need_index: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Distance to and index of the nearest vertex of each point of ``b``, as ``cKDTree.query`` gives them.

    A compiled grid search (:func:`~ctxmatch_lib.dtm._point_kernels.grid_nearest_kernel`, the distances of the
    exhaustive :func:`~ctxmatch_lib.dtm._point_kernels.nearest_kernel` bit for bit); the k-d tree whenever an index
    is needed and some point has two nearest vertices at exactly the same distance (a tie the tree breaks its
    own way)."""
    b = np.ascontiguousarray(b, np.float64)
    vertices = np.ascontiguousarray(vertices, np.float64)
    d, j, tie = grid_nearest_kernel(b, vertices)
    if not (need_index and tie):
        return d, j
    return cKDTree(vertices, balanced_tree=False, compact_nodes=False).query(b)  # unbalanced: faster to build


def _keep_clear(b: np.ndarray, vertices: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Push boundary samples closer than ``s`` to ``V`` radially out to distance ``s`` from their nearest
    vertex; drop the ones still closer than ``s / 2`` after that (see :func:`dtm_boundary`). Returns the
    distinct samples (rounded to float32) and each one's distance to its nearest vertex before rounding."""
    if len(b) == 0 or len(vertices) == 0:
        return _to_float32(b), np.full(len(b), np.inf)
    b = np.ascontiguousarray(b, np.float64)
    vertices = np.ascontiguousarray(vertices, np.float64)
    d, j = _nearest(b, vertices)
    if (d < s * (1 - 1e-9)).any():
        b, d = push_out_kernel(b, vertices, d, np.asarray(j, np.int64), float(s))  # compiled, same arithmetic
    pts, inverse = unique_rows(_to_float32(b))
    dist = np.empty(len(pts))
    dist[inverse] = d
    return pts, dist
