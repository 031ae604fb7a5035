"""Boundary points ``B`` added to the DTM triangulations (Sec. 4, Fig. 2, footnotes 2-3, Appendix A).

Points are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel; image
sizes are ``(width, height)``.

DTM's own boundary (``method="alpha"``, Fig. 2):

1. the alpha-shape boundary edges of the vertex set ``V``, as MATLAB's ``boundary(x, y)`` with its default
   shrink factor 0.5 returns them (footnote 2; :func:`matlab_boundary_alpha` says how alpha is picked);
2. for each boundary edge, the four points at distance ``s = min(width, height) / 10`` (footnote 3) on the
   perpendiculars to the edge through its two vertices form ``B'``;
3. the alpha-shape boundary of ``V ∪ B'`` is split into segments of length at most ``s``; the segment
   vertices are ``B``.

The alternatives that Appendix A (Fig. 11) compares are ``"corners"`` (the four image corners),
``"canvas"`` (the image border split into segments of length ``s``) and ``"convex"`` (steps 1-3 with the
convex hull, i.e. shrink factor 0, instead of the alpha shape).

``"keypoints"`` is the construction of the author's public Python port of DTM (github fb82/DTM,
``prepare_data_shaped``), which has no alpha shape: the image frame split into segments of about the mean
vertex spacing, plus the image's other keypoints (those not among the vertices) that share a Delaunay
triangle free of vertices with a frame point (:func:`keypoint_boundary`).
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
    points : ndarray of shape (N, 2)
        The input points.
    simplices : ndarray of shape (T, 3)
        Their Delaunay triangles (rows into ``points``).
    radii : ndarray of shape (T,)
        Circumradius of each triangle.
    alpha : float
        The alpha radius used; triangles with ``radii <= alpha`` form the shape (``inf`` if degenerate).
    inside : ndarray of shape (T,) bool
        Triangles of the shape, holes filled.
    edges : ndarray of shape (E, 2)
        Boundary edges of the shape (rows into ``points``).
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
        The final boundary set ``B`` (purple vertices in Fig. 2), (x, y) pixels.
    method : str
        One of :data:`BOUNDARY_METHODS`.
    s : float
        Fattening distance and segment length ``min(width, height) / 10`` (footnote 3).
    vertices : ndarray of shape (V, 2)
        The vertex set ``V`` the boundary was built for.
    vertex_simplices : ndarray of shape (T, 3)
        Delaunay triangles of ``V`` alone (blue in Fig. 2; empty if ``V`` is degenerate or the method
        does not triangulate ``V``).
    hull_edges : ndarray of shape (H, 2)
        Convex-hull edges of ``V`` (red in Fig. 2), rows into ``vertices``.
    alpha : float
        Alpha radius of the first shape (``inf`` for ``"convex"``, ``nan`` when not computed).
    shape_edges : ndarray of shape (E, 2)
        Boundary edges of the first shape (solid orange in Fig. 2; the hull for ``"convex"``), rows into
        ``vertices``.
    fattened : ndarray of shape (F, 2)
        ``B'``: the four points at distance ``s`` on the perpendiculars of each shape edge (dashed
        orange in Fig. 2 joins them edge by edge: rows ``4e:4e+4`` belong to ``shape_edges[e]`` and are
        ``(v0 + s n, v1 + s n, v0 - s n, v1 - s n)``).
    contour : list of ndarray of shape (R, 2)
        Closed rings (first point repeated at the end) of the second shape, i.e. the boundary of
        ``V ∪ B'`` (purple contour in Fig. 2) that ``points`` samples; for ``"canvas"``/``"corners"`` the
        image border.
    contour_alpha : float
        Alpha radius of the second shape (``nan`` when not computed).
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
    """Circumradius ``abc / (4 area)`` of each triangle, ``inf`` for a degenerate one, computed as
    ``sqrt(a² b² c²) / (2 |cross|)`` (one square root per triangle)."""
    return circumradii_kernel(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(simplices, np.int64))


def matlab_boundary_alpha(radii: np.ndarray, simplices: np.ndarray, neighbors: np.ndarray,
                          n_points: int, shrink: float = 0.5) -> float:
    """Alpha radius that MATLAB ``boundary(P, shrink)`` picks for a Delaunay triangulation.

    MATLAB builds ``alphaShape(P, Inf)``, takes its *alpha spectrum* (the distinct alpha values at which the
    shape changes: for a 2-D regularised alpha shape, the distinct triangle circumradii) and its critical
    alpha ``a_c = criticalAlpha('one-region')`` (the smallest alpha whose shape encloses every point in a
    single region), keeps the spectrum values ``>= a_c`` in increasing order, ``a_c = v_1 < ... < v_n``,
    and uses ``v_k`` with ``k = max(ceil((1 - shrink) n), 1)``. So ``shrink = 0`` gives ``v_n`` (the convex
    hull), ``shrink = 1`` the tightest single region ``a_c``, and the default 0.5 the median of the range.

    Here a triangle belongs to the shape when its circumradius is ``<= alpha``; regions are sets of
    triangles connected through shared edges; a point is enclosed when one of its triangles is in the shape
    (points that Qhull leaves out of every triangle are ignored). ``a_c`` is found exactly with a union-find
    over the triangles: the regions of the shape that first encloses every point, then the remaining
    triangles added in increasing circumradius until one region is left (compiled,
    :func:`~ctxmatch_lib.dtm._kernels.alpha_shapes_kernel`).

    Parameters
    ----------
    radii : ndarray of shape (T,)
        Triangle circumradii.
    simplices, neighbors : ndarray of shape (T, 3)
        Triangles and their adjacency (``scipy.spatial.Delaunay`` conventions; ``-1``: no neighbour).
    n_points : int
        Number of triangulated points.
    shrink : float
        MATLAB's shrink factor ``S`` in ``[0, 1]``.

    Returns
    -------
    float
        The alpha radius (``inf`` if there are no triangles).
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
    """Holes-filled alpha shape of ``points`` with MATLAB ``boundary``'s choice of alpha.

    Parameters
    ----------
    points : ndarray of shape (N, 2)
        Distinct (x, y) points.
    shrink : float
        MATLAB shrink factor: 0 convex hull, 1 tightest single region, 0.5 MATLAB's default.
    tri : DelaunayMesh, optional
        Precomputed Delaunay triangulation of ``points`` (:func:`~ctxmatch_lib.dtm.triangulation.delaunay_or_none`).

    Returns
    -------
    AlphaShape or None
        ``None`` when the points are fewer than three or collinear (no triangle). Holes are filled, as
        MATLAB ``boundary`` does by setting ``HoleThreshold`` to the hull area.
    """
    points = np.asarray(points, np.float64).reshape(-1, 2)
    tri = delaunay_or_none(points) if tri is None else tri
    if tri is None or len(tri.simplices) == 0:
        return None
    if not 0.0 <= shrink <= 1.0:
        raise ValueError(f"shrink must be in [0, 1], got {shrink}")
    return _alpha_shapes([points], [tri.simplices], shrink, tri.neighbors)[0][0]


def _alpha_shapes(points_list: list, simplices_list: list, shrink: float,
                  neighbors: np.ndarray | None = None) -> tuple[list, list]:
    """:func:`alpha_shape` of several triangulated point sets (each with triangles) in one compiled pass.

    The meshes are concatenated into one disjoint mesh (vertex and triangle indices offset) and
    :func:`~ctxmatch_lib.dtm._kernels.alpha_shapes_kernel` runs once for all of them, with the alpha spectrum
    ranked per mesh, so each shape is exactly the one :func:`alpha_shape` gives alone.
    ``neighbors`` is the concatenated triangle adjacency when already known. Returns the shapes and the
    triangle adjacency of each mesh.
    """
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
    """Drop the boundary samples that fall inside the first alpha shape of ``V`` (see :func:`dtm_boundary`).

    ``dist`` is each sample's distance to its nearest vertex. Every point of a triangle lies within its
    circumradius of one of the triangle's vertices, so a sample farther than the largest circumradius of the
    shape's triangles (holes filled included) from every vertex is outside it; only the others are tested
    against the shape's polygons (on dense sets, none)."""
    if len(b) == 0 or len(shape.edges) == 0:
        return b
    reach = float(shape.radii[shape.inside].max())
    near = np.flatnonzero(dist <= reach * (1 + 1e-9) + 1e-3)  # 1e-3 px: covers the float32 rounding of b
    if len(near) == 0:
        return b
    rings = _rings_from_edges(vertices, shape.edges)
    inside = np.zeros(len(b), bool)
    if len(rings) == 1:
        # One ring is one simple polygon (edges of a triangulation, every vertex on two of them): a compiled
        # crossing-number test, used when every orientation in it is certain (then it is GEOS's answer).
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
    """Boundary set of the author's Python port of DTM (``boundary="keypoints"``).

    The paper builds ``B`` from an alpha shape of ``V`` (Fig. 2); the author's public port (github
    fb82/DTM, ``prepare_data_shaped``) instead uses the image itself:

    1. the image frame ``[0, width] x [0, height]`` split into equal segments of about
       ``l = ceil(sqrt(width * height / |V|))`` pixels (the mean spacing of ``|V|`` points spread over the
       image), the segment vertices rounded to integers;
    2. the image's other keypoints ``O`` (rounded, not among ``V``) that are vertices of a Delaunay
       triangle of ``V ∪ O ∪ frame`` having a frame vertex and no ``V`` vertex: the detections just inside
       the frame that no candidate match uses.

    ``B`` is the frame points plus those keypoints. Where ``V`` is concentrated in part of the image, the
    unmatched keypoints around it pull the boundary close to ``V``, much as the alpha shape does.

    Parameters
    ----------
    vertices : array_like of shape (V, 2)
        Distinct vertex points ``V``, (x, y) pixels with the origin at the centre of the top-left pixel.
    image_size : tuple of int
        ``(width, height)``.
    keypoints : array_like of shape (N, 2)
        All keypoints detected in the image, (x, y) pixels (those collapsing onto ``V`` are ignored).
    collapsed : bool
        ``keypoints`` are already rounded and distinct (:func:`~ctxmatch_lib.dtm.collapse_vertices`).

    Returns
    -------
    Boundary
        ``.points`` is ``B`` (frame points first); ``.contour`` is the frame ring; ``.fattened`` holds the
        keypoints taken into ``B``.

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
        Distinct vertex points ``V``, (x, y) pixels with the origin at the centre of the top-left pixel
        (typically collapsed keypoints, :func:`~ctxmatch_lib.dtm.collapse_vertices`).
    image_size : tuple of int
        ``(width, height)`` of the image; sets ``s = min(width, height) / 10`` (footnote 3) and the canvas
        for ``"canvas"``/``"corners"``.
    method : {"alpha", "convex", "canvas", "corners", "keypoints"}
        ``"alpha"`` is DTM's boundary (Fig. 2): alpha-shape edges of ``V`` (MATLAB ``boundary`` with shrink
        factor ``shrink``), fattened by ``s`` into ``B'``, alpha-shape contour of ``V ∪ B'`` split into
        segments of length at most ``s``. ``"convex"`` does the same with the convex hull (Appendix A,
        Fig. 11c-d). ``"canvas"`` splits the image border into segments of length at most ``s``
        (Fig. 11b); ``"corners"`` uses the four image corners (Fig. 11a). ``"keypoints"`` is the author's
        Python port's frame-and-unmatched-keypoints boundary (:func:`keypoint_boundary`).
    shrink : float
        MATLAB shrink factor for ``"alpha"`` (default 0.5, MATLAB's default, as in footnote 2).
    keypoints : array_like of shape (N, 2), optional
        All keypoints of the image; required by ``"keypoints"``, ignored otherwise.

    Returns
    -------
    Boundary
        ``.points`` is ``B``; the other fields keep every intermediate for plotting.

    Notes
    -----
    Two details the paper leaves open are fixed as follows.

    - The contour of ``V ∪ B'`` cuts the convex corners of ``B'`` with chords, which pass closer than ``s``
      to the corner vertex (``s cos(θ/2)`` for a turn of ``θ``: ``0.71 s`` at a right angle). Samples that
      fall closer than ``s`` to ``V`` are pushed radially out to distance ``s`` from their nearest vertex
      (any still closer than ``s/2``, which needs a very thin spike, are dropped), so ``B`` keeps the
      clearance ``s`` that the construction aims for.
    - When ``V`` is sparse (vertices further apart than about ``2 s``), the alpha shape of ``V ∪ B'`` can
      cut into the shape of ``V`` it should surround, and its samples then fall between the vertices and
      cut their Delaunay edges (a set of four matches in agreement could lose every neighbourhood).
      Samples inside the first shape are dropped: ``B`` bounds the shape of ``V`` from outside, as Fig. 2
      intends. On dense sets no sample lies there and nothing changes.
    - Constructed points (``B'`` and ``B``) are rounded to float32 (under 4e-5 px at image scale), so that
      the fast triangulation kernel works on exactly the stored coordinates
      (:func:`~ctxmatch_lib.dtm.triangulation.delaunay_simplices`).
    - When ``V`` has fewer than three points or is collinear the alpha shape is empty; the contour is then
      the boundary of the ``s``-buffer of ``V`` (a circle, or a stadium around the segment), sampled the
      same way. An empty ``V`` gives an empty ``B`` for ``"alpha"`` and ``"convex"``.

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
    """:func:`dtm_boundary` and the Delaunay triangles of ``V ∪ B`` (rows into ``vertices`` then ``B``).

    For ``"alpha"`` and ``"convex"`` the boundary points are inserted into the triangulation of ``V`` that
    the first shape needed, which saves a full triangulation of ``V ∪ B``; the triangles are ``None`` when
    not computed here (then :func:`~ctxmatch_lib.dtm.triangulation.triangulate` builds them).
    """
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
    """:func:`boundary_and_triangulation` of several vertex sets (DTM: the two images), as a list of pairs.

    For ``"alpha"`` and ``"convex"`` the alpha shapes of all the sets are computed together, one vectorised
    pass per construction step instead of one per set; the results are exactly those of
    :func:`boundary_and_triangulation` on each set, which degenerate sets and the other methods fall back to.
    """
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
