"""Boundary points ``B`` added to the DTM triangulations (Sec. 4, Fig. 2, footnotes 2-3, Appendix A).

:func:`dtm_boundary` builds ``B`` around the vertex set ``V`` of one image: DTM's alpha-shape construction
(``"alpha"``, Fig. 2), the alternatives of Appendix A (``"convex"``, ``"canvas"``, ``"corners"``) or the
author's Python port's frame and keypoints (``"keypoints"``, :func:`keypoint_boundary`).
:func:`alpha_shape` and :func:`matlab_boundary_alpha` emulate MATLAB's ``boundary``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import shapely

from .._numerics.validation import as_image_size, as_points
from ._kernels import alpha_shapes_kernel, circumradii_kernel, hull_edges_kernel, triangle_neighbors_kernel
from ._point_kernels import inside_ring_kernel
from ._samples import _fatten, _keep_clear, _nearest, _rings_from_edges, _sample_rings, _to_float32  # noqa: F401
from .triangulation import DelaunayMesh, IncrementalDelaunay, delaunay_or_none, round_half_away, unique_rows

__all__ = [
    "BOUNDARY_METHODS",
    "AlphaShape",
    "Boundary",
    "alpha_shape",
    "matlab_boundary_alpha",
    "boundary_step",
    "dtm_boundary",
    "boundary_and_triangulation",
    "boundaries_and_triangulations",
    "keypoint_boundary",
]

BOUNDARY_METHODS = ("alpha", "convex", "canvas", "corners", "keypoints")
_EMPTY2 = np.empty((0, 2))
_EMPTY_EDGES = np.empty((0, 2), np.int64)


@dataclass(frozen=True)
class AlphaShape:
    """The holes-filled alpha shape of a point set, as MATLAB ``alphaShape``/``boundary`` build it.

    Attributes
    ----------
    points, simplices, radii : ndarray of shape (N, 2), (T, 3), (T,)
        The input points, their Delaunay triangles and the triangles' circumradii.
    alpha : float
        The alpha radius used; triangles with ``radii <= alpha`` form the shape (``inf`` if degenerate).
    inside, edges : ndarray of shape (T,) bool, (E, 2)
        Triangles of the shape (holes filled) and its boundary edges (rows into ``points``).
    """

    points: np.ndarray
    simplices: np.ndarray
    radii: np.ndarray
    alpha: float
    inside: np.ndarray
    edges: np.ndarray


@dataclass(frozen=True)
class Boundary:
    """Boundary set ``B`` of one image and every intermediate of its construction (Fig. 2, App. A).

    Attributes
    ----------
    points : ndarray of shape (Q, 2)
        The final boundary set ``B`` (purple vertices in Fig. 2).
    method, s : str, float
        One of :data:`BOUNDARY_METHODS`; the step ``min(width, height) / 10`` (footnote 3).
    vertices, vertex_simplices, hull_edges : ndarray
        ``V``, its Delaunay triangles (blue in Fig. 2; may be empty) and hull edges (red), rows into ``V``.
    alpha, contour_alpha : float
        Alpha radii of the first and second shapes (``nan`` when not computed).
    shape_edges : ndarray of shape (E, 2)
        Boundary edges of the first shape (solid orange in Fig. 2), rows into ``vertices``.
    fattened : ndarray of shape (F, 2)
        ``B'`` (dashed orange): rows ``4e:4e+4`` are ``(v0 + s n, v1 + s n, v0 - s n, v1 - s n)`` of edge ``e``.
    contour : list of ndarray of shape (R, 2)
        Closed rings of the boundary of ``V ∪ B'`` (purple in Fig. 2) that ``points`` samples.
    """

    points: np.ndarray
    method: str
    s: float
    vertices: np.ndarray
    vertex_simplices: np.ndarray
    hull_edges: np.ndarray
    alpha: float
    shape_edges: np.ndarray
    fattened: np.ndarray
    contour: list
    contour_alpha: float


def boundary_step(image_size) -> float:
    """Fattening distance / segment length ``s = min(width, height) / 10`` (footnote 3)."""
    w, h = as_image_size(image_size, "image_size")
    return min(w, h) / 10.0


def _circumradii(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Circumradius of each triangle (:func:`~ctxmatch_lib.dtm._kernels.circumradii_kernel`)."""
    return circumradii_kernel(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(simplices, np.int64))


def matlab_boundary_alpha(radii: np.ndarray, simplices: np.ndarray, neighbors: np.ndarray,
                          n_points: int, shrink: float = 0.5) -> float:
    """Alpha radius that MATLAB ``boundary(P, shrink)`` picks for a Delaunay triangulation (docs/dtm.md).

    ``radii``: the ``(T,)`` circumradii of ``simplices`` with adjacency ``neighbors`` (scipy's conventions)
    over ``n_points`` points. Returns the alpha (``inf`` without triangles).
    """
    if not 0.0 <= shrink <= 1.0:
        raise ValueError(f"shrink must be in [0, 1], got {shrink}")
    if len(radii) == 0:
        return math.inf
    radii = np.ascontiguousarray(radii, np.float64)
    alphas = alpha_shapes_kernel(np.ascontiguousarray(simplices, np.int64), np.ascontiguousarray(neighbors, np.int64),
                                 radii, np.argsort(radii), np.array([0, len(radii)]), np.array([0, n_points]),
                                 float(shrink))[0]
    return float(alphas[0])


def alpha_shape(points: np.ndarray, shrink: float = 0.5, *, tri: DelaunayMesh | None = None) -> AlphaShape | None:
    """Alpha shape of the distinct ``points`` with MATLAB ``boundary``'s alpha for ``shrink``
    (:func:`matlab_boundary_alpha`), holes filled (``HoleThreshold`` = hull area); ``tri``: their Delaunay
    triangulation, when known. ``None`` for fewer than three or collinear points."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    tri = delaunay_or_none(points) if tri is None else tri
    if tri is None or len(tri.simplices) == 0:
        return None
    if not 0.0 <= shrink <= 1.0:
        raise ValueError(f"shrink must be in [0, 1], got {shrink}")
    return _alpha_shapes([points], [tri.simplices], shrink, tri.neighbors)[0][0]


def _alpha_shapes(points_list: list, simplices_list: list, shrink: float,
                  neighbors: np.ndarray | None = None) -> tuple[list, list]:
    """:func:`alpha_shape` of several triangulated point sets in one compiled pass; returns the shapes and
    each mesh's triangle adjacency (``neighbors``: the union's, when known)."""
    n_groups = len(points_list)
    p_off = np.array([0, *itertools.accumulate(len(p) for p in points_list)], np.int64)
    t_off = np.array([0, *itertools.accumulate(len(s) for s in simplices_list)], np.int64)
    points = np.vstack(points_list) if n_groups > 1 else points_list[0]
    simplices = np.vstack([np.asarray(s, np.int64) + o if o else np.asarray(s, np.int64)
                           for s, o in zip(simplices_list, p_off)])
    if neighbors is None:
        neighbors = triangle_neighbors_kernel(simplices, len(points))
    neighbors = np.ascontiguousarray(neighbors, np.int64)
    radii = circumradii_kernel(np.ascontiguousarray(points, np.float64), simplices)
    # numpy's sort is several times faster than numba's
    order = np.concatenate([np.argsort(radii[lo:hi]) + lo for lo, hi in zip(t_off[:-1], t_off[1:])])
    alphas, inside, edges, e_off = alpha_shapes_kernel(simplices, neighbors, radii, order, t_off, p_off, float(shrink))
    shapes, neighbors_list = [], []
    for g in range(n_groups):
        ts = slice(t_off[g], t_off[g + 1])
        nb = neighbors[ts]
        neighbors_list.append(np.where(nb >= 0, nb - t_off[g], -1) if t_off[g] else nb)
        ge = edges[e_off[g] : e_off[g + 1]]
        shapes.append(AlphaShape(points_list[g], simplices[ts] - p_off[g] if p_off[g] else simplices[ts], radii[ts],
                                 float(alphas[g]), inside[ts], ge - p_off[g] if p_off[g] else ge))
    return shapes, neighbors_list


def _outside_shape(b: np.ndarray, dist: np.ndarray, vertices: np.ndarray, shape: AlphaShape) -> np.ndarray:
    """Drop the boundary samples ``b`` inside the first alpha shape of ``V``; ``dist``: each sample's
    distance to its nearest vertex (beyond the largest circumradius means outside, untested)."""
    if len(b) == 0 or len(shape.edges) == 0:
        return b
    reach = float(shape.radii[shape.inside].max())
    near = np.flatnonzero(dist <= reach * (1 + 1e-9) + 1e-3)  # 1e-3 px: covers the float32 rounding of b
    if len(near) == 0:
        return b
    rings = _rings_from_edges(vertices, shape.edges)
    inside = np.zeros(len(b), bool)
    if len(rings) == 1:
        # One simple polygon: a crossing-number test, GEOS's answer when every orientation is certain.
        inside[near], certain = inside_ring_kernel(np.ascontiguousarray(rings[0], np.float64),
                                                   np.ascontiguousarray(b[near], np.float64))
        if certain:
            return b[~inside]
        region = shapely.Polygon(rings[0])
    else:
        region = shapely.union_all([shapely.Polygon(r) for r in rings])
    inside[near] = shapely.contains_xy(region, b[near, 0], b[near, 1])
    return b[~inside]


def _degenerate_boundary(vertices: np.ndarray, s: float) -> tuple[list, np.ndarray]:
    """Contour for 1 point or collinear points: the ring of their ``s``-buffer (no alpha shape exists)."""
    if len(vertices) == 1:
        geom = shapely.points(vertices[0])
    else:
        centred = vertices - vertices.mean(axis=0)
        direction = np.linalg.svd(centred, full_matrices=False)[2][0]
        proj = centred @ direction
        geom = shapely.linestrings(vertices[[np.argmin(proj), np.argmax(proj)]])
    poly = shapely.buffer(geom, s, quad_segs=8)
    ring = shapely.get_coordinates(shapely.get_exterior_ring(poly))
    return [ring], _sample_rings([ring], s)


def _image_border(image_size) -> np.ndarray:
    w, h = image_size
    # Pixel centres are integers, so the canvas edges lie half a pixel outside them.
    x0, y0, x1, y1 = -0.5, -0.5, w - 0.5, h - 0.5
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])


def _row_keys(points: np.ndarray) -> np.ndarray:
    """One int64 per row of integer-valued (x, y) points (|x|, |y| < 2**30), for set operations on rows."""
    xy = points.astype(np.int64) + (1 << 30)
    return (xy[:, 0] << 31) | xy[:, 1]


def keypoint_boundary(vertices, image_size, keypoints, *, collapsed: bool = False) -> Boundary:
    """Boundary set of the author's Python port of DTM (``boundary="keypoints"``, ``prepare_data_shaped``).

    ``B`` is the image frame sampled every ``ceil(sqrt(w h / |V|))`` px, rounded, plus the other keypoints
    (not in ``V``) on a Delaunay triangle with a frame vertex and no ``V`` vertex. ``keypoints``: all of the
    image's (``collapsed``: already rounded and distinct). ``.points``: frame points first, then the taken
    keypoints (also in ``.fattened``); ``.contour``: the frame ring.

    Examples
    --------
    >>> v = np.array([[100.0, 100.0], [300.0, 120.0], [200.0, 300.0]])
    >>> others = np.array([[20.0, 20.0], [200.0, 200.0]])
    >>> b = keypoint_boundary(v, (400, 400), others)
    >>> len(b.points), b.fattened.tolist()   # frame every 400 / ceil(400 / 231) = 200 px, and one keypoint
    (9, [[20.0, 20.0]])
    """
    image_size = as_image_size(image_size, "image_size")
    vertices = as_points(vertices, "vertices")
    w, h = image_size
    s = boundary_step(image_size)
    empty = dict(vertex_simplices=np.empty((0, 3), np.int64), hull_edges=_EMPTY_EDGES, alpha=math.nan,
                 shape_edges=_EMPTY_EDGES, contour_alpha=math.nan)
    border = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h], [0.0, 0.0]])
    if len(vertices) == 0:
        return Boundary(_EMPTY2, "keypoints", s, vertices, fattened=_EMPTY2, contour=[border], **empty)
    step = math.ceil(math.sqrt(w * h / len(vertices)))
    xs = np.arange(0.0, w + 1e-3, w / math.ceil(w / step))
    ys = np.arange(0.0, h + 1e-3, h / math.ceil(h / step))
    frame = np.vstack([np.c_[xs, np.zeros_like(xs)], np.c_[xs, np.full_like(xs, h)],
                       np.c_[np.zeros_like(ys), ys], np.c_[np.full_like(ys, w), ys]])
    frame = unique_rows(np.round(frame))[0]
    kp = np.asarray(keypoints, np.float64).reshape(-1, 2)[:, :2]
    others = kp if collapsed else unique_rows(round_half_away(kp))[0]
    # Priority where points coincide: vertices, then other keypoints, then frame points.
    v_keys = _row_keys(round_half_away(vertices))
    others = others[~np.isin(_row_keys(others), v_keys)]
    frame = frame[~np.isin(_row_keys(frame), np.concatenate([v_keys, _row_keys(others)]))]
    pts = np.vstack([vertices, others, frame])
    kind = np.repeat(np.array([0, 1, 2], np.int8), [len(vertices), len(others), len(frame)])
    mesh = delaunay_or_none(pts)
    taken = _EMPTY2
    if mesh is not None and len(others):
        k = kind[mesh.simplices]
        near_frame = (k != 0).all(axis=1) & (k == 2).any(axis=1)
        corner = mesh.simplices[near_frame][k[near_frame] == 1]
        taken = pts[np.unique(corner)] if len(corner) else _EMPTY2
    points = np.vstack([frame, taken])
    return Boundary(points, "keypoints", s, vertices, fattened=taken, contour=[border], **empty)


def dtm_boundary(vertices, image_size, method: str = "alpha", *, shrink: float = 0.5, keypoints=None) -> Boundary:
    """Boundary set ``B`` that DTM adds to the triangulation of the vertex set ``V`` (Sec. 4, Fig. 2).

    Parameters
    ----------
    vertices : array_like of shape (V, 2)
        Distinct vertex points ``V``, (x, y) pixels (collapsed keypoints,
        :func:`~ctxmatch_lib.dtm.collapse_vertices`).
    image_size : tuple of int
        ``(width, height)``; sets ``s = min(width, height) / 10`` (footnote 3) and the canvas.
    method : {"alpha", "convex", "canvas", "corners", "keypoints"}
        ``"alpha"``: DTM's (Fig. 2), the alpha-shape edges of ``V`` fattened by ``s`` (``B'``), then the
        alpha-shape contour of ``V ∪ B'`` sampled every ``s`` at most; ``"convex"``: the same with the hull
        (Fig. 11c-d); ``"canvas"``: the sampled image border (Fig. 11b); ``"corners"``: the image corners
        (Fig. 11a); ``"keypoints"``: :func:`keypoint_boundary`.
    shrink : float
        MATLAB ``boundary`` shrink factor for ``"alpha"`` (footnote 2).
    keypoints : array_like of shape (N, 2), optional
        All keypoints of the image; required by ``"keypoints"``, ignored otherwise.

    Returns
    -------
    Boundary
        ``.points`` is ``B``; the other fields keep every intermediate for plotting.

    Notes
    -----
    Samples closer than ``s`` to ``V`` are pushed out to ``s``, samples inside the first shape dropped,
    points rounded to float32; fewer than three or collinear vertices get the ``s``-buffer of ``V``
    (see docs/dtm.md, "The boundary").

    Examples
    --------
    >>> xy = np.stack(np.meshgrid(np.arange(100, 301, 20.0), np.arange(100, 301, 20.0)), -1).reshape(-1, 2)
    >>> b = dtm_boundary(xy, (640, 480))
    >>> b.s, len(b.shape_edges)
    (48.0, 40)
    """
    return boundary_and_triangulation(vertices, image_size, method, shrink=shrink, keypoints=keypoints)[0]


def boundary_and_triangulation(vertices, image_size, method: str = "alpha", *, shrink: float = 0.5,
                               keypoints=None) -> tuple[Boundary, np.ndarray | None]:
    """:func:`dtm_boundary` and the Delaunay triangles of ``V ∪ B`` (rows into ``vertices`` then ``B``):
    for ``"alpha"``/``"convex"``, ``B`` inserted into the triangulation of ``V``; else ``None``."""
    if method not in BOUNDARY_METHODS:
        raise ValueError(f"method must be one of {BOUNDARY_METHODS}, got {method!r}")
    image_size = as_image_size(image_size, "image_size")
    vertices = as_points(vertices, "vertices")
    if method == "keypoints":
        if keypoints is None:
            raise ValueError('boundary "keypoints" needs keypoints= (all keypoints of the image)')
        return keypoint_boundary(vertices, image_size, keypoints), None
    s = boundary_step(image_size)
    empty = dict(vertex_simplices=np.empty((0, 3), np.int64), hull_edges=_EMPTY_EDGES, alpha=math.nan,
                 shape_edges=_EMPTY_EDGES, fattened=_EMPTY2, contour_alpha=math.nan)
    if method in ("canvas", "corners"):
        border = _image_border(image_size)
        pts = border[:4] if method == "corners" else _to_float32(_sample_rings([border], s))
        return Boundary(pts, method, s, vertices, contour=[border], **empty), None
    if len(vertices) == 0:
        return Boundary(_EMPTY2, method, s, vertices, contour=[], **empty), None
    return _shape_boundary(vertices, method, shrink, s, empty)


def _shape_boundary(vertices, method, shrink, s, empty) -> tuple[Boundary, np.ndarray]:
    """``"alpha"``/``"convex"`` boundary of non-empty ``vertices`` at distance ``s``, and the triangles of
    ``V ∪ B``."""
    inc = IncrementalDelaunay(vertices, pad=2.0 * s)  # B lies within s of V's bounding box
    tri = inc.mesh()
    first = alpha_shape(vertices, 0.0 if method == "convex" else shrink, tri=tri)
    if first is None:
        contour, pts = _degenerate_boundary(vertices, s)
        pts = _keep_clear(pts, vertices, s)[0]
        inc.add(pts)
        return Boundary(pts, method, s, vertices, contour=contour, **empty), inc.simplices()
    hull_edges = tri.convex_hull.astype(np.int64)
    fattened = _fatten(vertices, first.edges, s)
    both = unique_rows(np.vstack([vertices, fattened]))[0]
    second = alpha_shape(both, 0.0 if method == "convex" else shrink)
    contour = _rings_from_edges(both, second.edges)
    pts = _outside_shape(*_keep_clear(_sample_rings(contour, s), vertices, s), vertices, first)
    inc.add(pts)
    return (Boundary(pts, method, s, vertices, first.simplices, hull_edges, first.alpha, first.edges, fattened,
                     contour, second.alpha), inc.simplices())


def boundaries_and_triangulations(vertices_list, image_sizes, method: str = "alpha", *,
                                  shrink: float = 0.5, keypoints_list=None) -> list:
    """:func:`boundary_and_triangulation` of several vertex sets (DTM: the two images), as a list of pairs;
    for ``"alpha"``/``"convex"`` the alpha shapes of all sets are computed in one pass per step."""
    if method not in BOUNDARY_METHODS:
        raise ValueError(f"method must be one of {BOUNDARY_METHODS}, got {method!r}")
    sizes = [as_image_size(size, "image_size") for size in image_sizes]
    vertices_list = [as_points(v, "vertices") for v in vertices_list]
    if len(vertices_list) != len(sizes):
        raise ValueError(f"vertices_list and image_sizes must have the same length, got {len(vertices_list)} "
                         f"and {len(sizes)}")

    def one_by_one():
        kps = keypoints_list if keypoints_list is not None else [None] * len(sizes)
        return [boundary_and_triangulation(v, size, method, shrink=shrink, keypoints=kp)
                for v, size, kp in zip(vertices_list, sizes, kps)]

    if method not in ("alpha", "convex") or any(len(v) < 3 for v in vertices_list):
        return one_by_one()
    if not 0.0 <= shrink <= 1.0:
        raise ValueError(f"shrink must be in [0, 1], got {shrink}")
    shrink = 0.0 if method == "convex" else shrink
    steps = [boundary_step(size) for size in sizes]
    incs = [IncrementalDelaunay(v, pad=2.0 * s) for v, s in zip(vertices_list, steps)]
    meshes = [inc.mesh() for inc in incs]
    if any(mesh is None for mesh in meshes):
        return one_by_one()  # collinear: the degenerate boundary
    firsts, neighbors = _alpha_shapes(vertices_list, [mesh.simplices for mesh in meshes], shrink)
    fattened = [_fatten(v, first.edges, s) for v, first, s in zip(vertices_list, firsts, steps)]
    boths = [unique_rows(np.vstack([v, f]))[0] for v, f in zip(vertices_list, fattened)]
    second_meshes = [delaunay_or_none(both) for both in boths]
    if any(mesh is None for mesh in second_meshes):
        return one_by_one()
    seconds, _ = _alpha_shapes(boths, [mesh.simplices for mesh in second_meshes], shrink)
    out = []
    for v, s, inc, first, nb, fat, both, second in zip(vertices_list, steps, incs, firsts, neighbors, fattened,
                                                         boths, seconds):
        hull_edges = hull_edges_kernel(np.ascontiguousarray(first.simplices, np.int64), nb)
        contour = _rings_from_edges(both, second.edges)
        pts = _outside_shape(*_keep_clear(_sample_rings(contour, s), v, s), v, first)
        inc.add(pts)
        simplices = inc.simplices()
        out.append((Boundary(pts, method, s, v, first.simplices, hull_edges, first.alpha, first.edges, fat, contour,
                             second.alpha), simplices))
    return out
