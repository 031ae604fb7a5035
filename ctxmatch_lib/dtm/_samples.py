"""Geometry helpers of :mod:`.boundary` (Sec. 4, Fig. 2): fattened edges, contour rings, their samples at
a fixed step, and the samples kept clear of the vertices."""

from __future__ import annotations

import numpy as np
import shapely
from scipy.spatial import cKDTree

from ._point_kernels import grid_nearest_kernel, push_out_kernel, sample_ring_kernel, single_ring_kernel
from .triangulation import unique_rows

_EMPTY2 = np.empty((0, 2))


def _to_float32(points: np.ndarray) -> np.ndarray:
    """Round constructed points to float32 (under 4e-5 px below 1000), the coordinates the triangulation
    (:func:`~ctxmatch_lib.dtm.triangulation.delaunay_simplices`) is exact and fastest on."""
    return np.asarray(points, np.float64).astype(np.float32).astype(np.float64)


def _fatten(points: np.ndarray, edges: np.ndarray, s: float) -> np.ndarray:
    """``B'``: the points at distance ``s`` on both sides of each edge, through both its vertices."""
    p0, p1 = points[edges[:, 0]], points[edges[:, 1]]
    d = p1 - p0
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    return _to_float32(np.stack([p0 + s * n, p1 + s * n, p0 - s * n, p1 - s * n], axis=1).reshape(-1, 2))


def _rings_from_edges(points: np.ndarray, edges: np.ndarray) -> list:
    """Closed rings (first point repeated) of the polygons bounded by ``edges``, as GEOS's
    ``polygonize`` gives them (their start and direction place the samples). One clockwise simple cycle is
    traced by :func:`~ctxmatch_lib.dtm._point_kernels.single_ring_kernel`; anything else goes to GEOS."""
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
    """Split every ring into ``n = max(ceil(L / s), 3)`` equal segments; return the segment vertices, with
    the arithmetic of GEOS's ``line_interpolate_point`` (:func:`._point_kernels.sample_ring_kernel`)."""
    out = [sample_ring_kernel(np.ascontiguousarray(ring, np.float64), float(s)) for ring in rings]
    out = [o for o in out if len(o)]
    return np.vstack(out) if out else _EMPTY2


def _nearest(b: np.ndarray, vertices: np.ndarray, need_index: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Distance to and index of the nearest vertex of each point of ``b``, as ``cKDTree.query`` gives them
    (a grid search; the k-d tree itself where an index is needed and two vertices tie)."""
    b = np.ascontiguousarray(b, np.float64)
    vertices = np.ascontiguousarray(vertices, np.float64)
    d, j, tie = grid_nearest_kernel(b, vertices)
    if not (need_index and tie):
        return d, j
    return cKDTree(vertices, balanced_tree=False, compact_nodes=False).query(b)  # unbalanced: faster to build


def _keep_clear(b: np.ndarray, vertices: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Push samples closer than ``s`` to ``V`` out to ``s``; drop those still closer than ``s / 2``
    (:func:`.boundary.dtm_boundary`). Returns the distinct float32 samples and their vertex distances."""
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
