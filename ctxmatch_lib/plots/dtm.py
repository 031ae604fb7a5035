"""Overlays for DTM (Sec. 4) on an ``ax``: the boundary construction of Fig. 2 / Appendix A
(:func:`plot_boundary_steps`, :func:`plot_boundary_mesh`) and the DTM1/DTM2 steps of Fig. 3
(:func:`plot_dtm_iteration_flow`, :func:`plot_dtm_clusters`, :func:`plot_dtm_final`). Colours:
:data:`DTM_COLORS` and :data:`~ctxmatch_lib.plots.viz2d.MATCH_COLORS`."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.patches import Rectangle

from .palette import OKABE_ITO
from .viz2d import MATCH_COLORS, match_colors, plot_flow

__all__ = ["DTM_COLORS", "triangulation_edges", "plot_triangulation", "plot_canvas", "outer_fattening",
           "plot_boundary_steps", "plot_boundary_mesh", "plot_dtm_iteration_flow", "plot_dtm_clusters",
           "plot_dtm_final", "plot_dtm_mesh", "mesh_border_distance"]

#: Colours of Figs. 2-3 in Okabe–Ito: the paper's red hull / orange alpha shape become vermillion / sky blue,
#: which dichromats tell apart too.
DTM_COLORS = {
    "delaunay": OKABE_ITO["blue"],
    "keypoint_edge": OKABE_ITO["bluish_green"],
    "hull": OKABE_ITO["vermillion"],
    "alpha": OKABE_ITO["sky_blue"],
    "boundary": OKABE_ITO["reddish_purple"],
    "contraction": "#ffffff",  # white (Fig. 3: orange, the colour of wrong matches here)
    "expansion": "#009E73",    # bluish green (Fig. 3: yellow, the colour of dropped correct matches here)
    "mesh": "#a0a0a0",         # triangulations of the DTM-step figure: grey, blue is taken by correct matches
    "vertex": "black",
}


def triangulation_edges(simplices) -> np.ndarray:
    """The distinct undirected edges ``(E, 2)`` (sorted rows, smaller index first) of triangles ``(T, 3)``.

    Examples
    --------
    >>> triangulation_edges(np.array([[0, 1, 2], [1, 2, 3]])).tolist()
    [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    """
    s = np.asarray(simplices, np.int64).reshape(-1, 3)
    if len(s) == 0:
        return np.empty((0, 2), np.int64)
    e = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0)


def plot_triangulation(ax, points, simplices, n_vertices: int | None = None, *, color=None,
                       keypoint_color=None, lw: float = 0.6, alpha: float = 0.9, zorder: float = 1) -> None:
    """Draw the edges of a triangulation of ``points`` (``(P, 2)``); with ``keypoint_color``, edges joining two
    of the first ``n_vertices`` points (the keypoints ``V``, not ``B``) get that colour (Fig. 2 right)."""
    points = np.asarray(points, np.float64).reshape(-1, 2)
    edges = triangulation_edges(simplices)
    if len(edges) == 0:
        return
    color = DTM_COLORS["delaunay"] if color is None else color
    segs = points[edges]
    if keypoint_color is None or n_vertices is None:
        ax.add_collection(LineCollection(segs, colors=color, linewidths=lw, alpha=alpha, zorder=zorder))
        return
    kp = (edges < n_vertices).all(axis=1)
    ax.add_collection(LineCollection(segs[~kp], colors=color, linewidths=lw, alpha=alpha, zorder=zorder))
    ax.add_collection(LineCollection(segs[kp], colors=keypoint_color, linewidths=lw, alpha=alpha, zorder=zorder))


def plot_canvas(ax, image_size, *, color="0.35", lw: float = 1.0, fill: str | None = "white") -> None:
    """The image canvas ``(width, height)`` as a rectangle (pixel edges at -0.5 and size - 0.5), equal aspect,
    no ticks."""
    w, h = image_size
    ax.add_patch(Rectangle((-0.5, -0.5), w, h, fill=fill is not None, fc=fill or "none", ec=color, lw=lw,
                           zorder=0))
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _fit_view(ax, *arrays, margin: float = 0.04) -> None:
    pts = np.vstack([np.asarray(a, np.float64).reshape(-1, 2) for a in arrays if len(a)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = margin * (hi - lo).max()
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(hi[1] + pad, lo[1] - pad)  # y down, as images


def _shape_region(vertices, edges):
    """The union of the polygons bounded by ``edges`` (rows into ``vertices``), or ``None``."""
    import shapely

    if len(edges) == 0:
        return None
    lines = shapely.linestrings(np.stack([vertices[edges[:, 0]], vertices[edges[:, 1]]], axis=1))
    polys = shapely.get_parts(shapely.polygonize(lines))
    return shapely.union_all(polys) if len(polys) else None


def outer_fattening(boundary) -> np.ndarray:
    """The segments of ``B'`` drawn dashed in Fig. 2, ``(E, 2, 2)``: of the two copies of each shape edge
    shifted by ``±s`` (``Boundary.fattened``), those whose midpoint is outside the shape (both on a part thinner
    than ``s``); the inner copy never reaches the contour of ``V ∪ B'``."""
    import shapely

    if len(boundary.fattened) == 0:
        return np.empty((0, 2, 2))
    f = boundary.fattened.reshape(-1, 4, 2)
    copies = np.concatenate([f[:, [0, 1]], f[:, [2, 3]]])
    region = _shape_region(boundary.vertices, boundary.shape_edges)
    if region is None:
        return copies
    mid = copies.mean(axis=1)
    outside = ~shapely.contains_xy(region, mid[:, 0], mid[:, 1])
    return copies[outside]


def plot_boundary_steps(ax, boundary, *, shape_color=None, ps: float = 6, lw: float = 1.2) -> None:
    """The boundary construction of Fig. 2 (left) / Appendix A (a, b, c, e) for one ``Boundary``: Delaunay
    triangulation of ``V``, convex hull, shape edges (``shape_color``, default by method), their outer shift
    :func:`outer_fattening` dashed, the outer contour of ``V ∪ B'`` and the final set ``B`` (for ``"corners"`` /
    ``"canvas"`` just the border samples ``B``)."""
    import shapely

    v, c = boundary.vertices, DTM_COLORS
    if len(boundary.vertex_simplices):
        plot_triangulation(ax, v, boundary.vertex_simplices, color=c["delaunay"], lw=0.5, alpha=0.6)
    if len(boundary.hull_edges):
        ax.add_collection(LineCollection(v[boundary.hull_edges], colors=c["hull"], linewidths=lw, zorder=3))
    if shape_color is None:
        shape_color = c["hull"] if boundary.method == "convex" else c["alpha"]
    if len(boundary.shape_edges):
        ax.add_collection(LineCollection(v[boundary.shape_edges], colors=shape_color, linewidths=lw * 1.4,
                                         zorder=4))
    segs = outer_fattening(boundary)
    if len(segs):
        # Over the contour: the contour of V ∪ B' runs along these segments, and would hide them.
        ax.add_collection(LineCollection(segs, colors=shape_color, linewidths=lw * 0.9, linestyles=(0, (3, 2)),
                                         zorder=5.5))
    rings = [r for r in boundary.contour if len(r) >= 4]
    if rings:  # the outer boundary of the contour polygons (a hole's ring is not part of it)
        outline = shapely.union_all([shapely.Polygon(r) for r in rings])
        for poly in shapely.get_parts(outline):
            ring = shapely.get_coordinates(shapely.get_exterior_ring(poly))
            ax.plot(ring[:, 0], ring[:, 1], color=c["boundary"], lw=lw, zorder=5)
    ax.scatter(*v.T, s=ps, c=c["vertex"], linewidths=0, zorder=6)
    if len(boundary.points):
        ax.scatter(*boundary.points.T, s=ps * 2.5, c=c["boundary"], linewidths=0, zorder=7)
    _fit_view(ax, v, boundary.points, *(r for r in boundary.contour))


def plot_boundary_mesh(ax, boundary, *, ps: float = 6, lw: float = 0.7) -> None:
    """The final Delaunay triangulation of ``V ∪ B`` (Fig. 2 right, Appendix A b, d, f): edges joining two
    keypoint vertices green, edges touching ``B`` blue, ``B`` purple dots."""
    from ..dtm import triangulate

    tri = triangulate(boundary.vertices, boundary.points)
    plot_triangulation(ax, tri.points, tri.simplices, tri.n_vertices, color=DTM_COLORS["delaunay"],
                       keypoint_color=DTM_COLORS["keypoint_edge"], lw=lw)
    ax.scatter(*boundary.vertices.T, s=ps, c=DTM_COLORS["vertex"], linewidths=0, zorder=6)
    if len(boundary.points):
        ax.scatter(*boundary.points.T, s=ps * 2.5, c=DTM_COLORS["boundary"], linewidths=0, zorder=7)
    _fit_view(ax, tri.points)


def _plot_mesh(ax, tri, lw: float) -> None:
    """A triangulation drawn grey under the flows of Fig. 3."""
    plot_triangulation(ax, tri.points, tri.simplices, color=DTM_COLORS["mesh"], lw=lw, alpha=0.6)


def plot_dtm_iteration_flow(ax, iteration, p1, p2, labels, *, image: int = 1, lw: float = 0.9,
                            ps: float = 4, tri_lw: float = 0.4, dropped_lw: float = 0.5,
                            dropped_alpha: float = 0.35, max_dropped_lines: int | None = 300) -> bool:
    """Fig. 3 left column: triangulation ``T_1`` (grey) of a DTM1 ``iteration`` (from ``trace=True``) and the
    flows of its input matches ``M^{i-1}`` on image ``image``, coloured kept/removed × correct/wrong
    (:data:`MATCH_COLORS`, ``labels``). ``p1``, ``p2``: the keypoints ``(K, 2)`` of every input match. Above
    ``max_dropped_lines`` removed matches are dots (long lines would hide everything); returns whether.
    """
    _plot_mesh(ax, iteration.tri1 if image == 1 else iteration.tri2, tri_lw)
    active = iteration.active
    kept = np.isin(active, iteration.kept)
    src, dst = (p1, p2) if image == 1 else (p2, p1)
    gone, stay = active[~kept], active[kept]
    gone_colors = match_colors(labels[gone], np.zeros(len(gone), bool))
    as_dots = max_dropped_lines is not None and len(gone) > max_dropped_lines
    if as_dots:
        # Removed correct ones are few and pale yellow: larger, outlined, above the flows.
        good = labels[gone].astype(bool)
        ax.scatter(*src[gone[~good]].T, s=max(ps, 3.0), c=gone_colors[~good], linewidths=0, alpha=0.85, zorder=2)
        ax.scatter(*src[gone[good]].T, s=max(ps, 3.0) * 3.5, c=gone_colors[good], edgecolors="black",
                   linewidths=0.4, zorder=4)
    else:
        plot_flow(ax, src[gone], dst[gone], color=gone_colors, lw=dropped_lw, ps=ps * 0.5, alpha=dropped_alpha)
    plot_flow(ax, src[stay], dst[stay], color=match_colors(labels[stay]), lw=lw, ps=ps, zorder=3)
    return as_dots


def plot_dtm_clusters(ax, iteration, p1, p2, *, image: int = 2, lw: float = 0.9, ps: float = 14,
                      tri_lw: float = 0.4) -> None:
    """Fig. 3 right column: triangulation ``T_2`` (grey) of iteration ``i``, the contraction set ``T``
    (white dots) and each expansion cluster ``M_{A^1} ∩ M_{A^2}`` (bluish green: segments from the contraction
    match to its cluster members, members as dots), drawn at the keypoints of image ``image``."""
    pts = p2 if image == 2 else p1
    _plot_mesh(ax, iteration.tri2 if image == 2 else iteration.tri1, tri_lw)
    ptr, members, t = iteration.cluster_ptr, iteration.cluster_members, iteration.contraction
    centre = np.repeat(t, np.diff(ptr))
    ax.add_collection(LineCollection(np.stack([pts[centre], pts[members]], axis=1),
                                     colors=DTM_COLORS["expansion"], linewidths=lw, zorder=3))
    ax.scatter(*pts[members].T, s=ps * 0.4, c=DTM_COLORS["expansion"], linewidths=0, zorder=4)
    ax.scatter(*pts[t].T, s=ps, c=DTM_COLORS["contraction"], edgecolors="black", linewidths=0.4, zorder=5)


def plot_dtm_final(ax, result, p1, p2, labels, *, stage: int = 1, image: int = 1, lw: float = 0.9,
                   ps: float = 4, tri_lw: float = 0.4) -> None:
    """Fig. 3e-f as flows on image ``image``: the DTM1 output ``M^ī`` over the last DTM1 triangulation
    (``stage=1``), or the DTM2 output, re-added matches dashed, over the last DTM2 level's (``stage=2``).
    ``result``: a :class:`~ctxmatch_lib.dtm.DTMResult` with ``trace=True``."""
    tr = result.trace
    last = tr.iterations[-1] if stage == 1 or not tr.levels else tr.levels[-1]
    _plot_mesh(ax, last.tri1 if image == 1 else last.tri2, tri_lw)
    dtm1 = np.flatnonzero(result.removed_at == 0)
    src, dst = (p1, p2) if image == 1 else (p2, p1)
    plot_flow(ax, src[dtm1], dst[dtm1], color=match_colors(labels[dtm1]), lw=lw, ps=ps)
    if stage == 2:
        added = np.flatnonzero(result.readded_at > 0)
        plot_flow(ax, src[added], dst[added], color=match_colors(labels[added]), lw=lw * 1.2, ps=ps, zorder=3,
                  linestyle=(0, (2.5, 1.5)))


def plot_dtm_mesh(ax, result, *, image: int = 1, color="white", lw: float = 0.35, alpha: float = 0.55,
                  zorder: float = 1.5) -> int:
    """Draw the mesh over DTM's output ``M^ī`` on image ``image`` (edges of the last DTM1 iteration between two
    keypoints, not to ``B``) and return the number of edges. ``result``: a DTMResult with ``trace=True``."""
    if result.trace is None:
        raise ValueError("result has no trace: compute it with dtm(..., trace=True)")
    if not result.trace.iterations:
        return 0
    last = result.trace.iterations[-1]
    tri = last.tri1 if image == 1 else last.tri2
    edges = triangulation_edges(tri.simplices)
    edges = edges[(edges < tri.n_vertices).all(axis=1)]
    if len(edges):
        ax.add_collection(LineCollection(np.asarray(tri.points, np.float64)[edges], colors=color, linewidths=lw,
                                         alpha=alpha, zorder=zorder))
    return len(edges)


def mesh_border_distance(result, points, *, image: int = 1) -> np.ndarray:
    """Signed distance (pixels, negative outside) of ``points`` ``(K, 2)`` to the border of the region covered
    by :func:`plot_dtm_mesh`'s mesh on image ``image``: checks Sec. 5.3's remark that DTM's wrong matches sit
    near the triangulation border. ``result``: a DTMResult with ``trace=True``."""
    import shapely

    points = np.asarray(points, np.float64).reshape(-1, 2)
    if result.trace is None:
        raise ValueError("result has no trace: compute it with dtm(..., trace=True)")
    if not result.trace.iterations or len(points) == 0:
        return np.full(len(points), np.nan)
    last = result.trace.iterations[-1]
    tri = last.tri1 if image == 1 else last.tri2
    simp = np.asarray(tri.simplices, np.int64).reshape(-1, 3)
    simp = simp[(simp < tri.n_vertices).all(axis=1)]
    if len(simp) == 0:
        return np.full(len(points), np.nan)
    region = shapely.union_all(shapely.polygons(np.asarray(tri.points, np.float64)[simp]))
    pts = shapely.points(points)
    dist = shapely.distance(shapely.boundary(region), pts)
    return np.where(shapely.contains_xy(region.buffer(1e-9), points[:, 0], points[:, 1]), dist, -dist)


#: Legend entries of the Fig. 3 panels.
FLOW_LEGEND = {
    "kept, correct": MATCH_COLORS["correct"],
    "kept, wrong": MATCH_COLORS["wrong"],
    "removed, correct": MATCH_COLORS["correct_dropped"],
    "removed, wrong": MATCH_COLORS["wrong_dropped"],
    "re-added by DTM2, correct": (MATCH_COLORS["correct"], "--"),
    "re-added by DTM2, wrong": (MATCH_COLORS["wrong"], "--"),
}
