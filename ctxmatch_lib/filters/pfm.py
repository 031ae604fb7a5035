"""PFM: Progressive Feature Matching, incremental graph construction and optimization (Lee, Lim, Suh, TIP 2020).

:func:`pfm_filter` grows a Delaunay graph of the matches (round 0: the best-scored ``seed_fraction``; each
round doubles the candidates, each new one linked to its enclosing triangle) and relabels it each round.
Step 1: local affine maps (:func:`local_affines`). Step 2: edge consistency ``c_ij = exp(-(r_ij^2 + r_ji^2)
/ (2 sigma^2))``, ``r_ij`` the relative transfer error. Step 3: labels minimising ``sum_i t_i l_i - lam
sum_(ij) c_ij l_i l_j``, ``t_i = t + beta (rank_i - 1/2)``, by an exact minimum s-t cut (Boykov and
Kolmogorov). Step 4: the progressive graph. Constants the paper leaves open: ``docs/filters.md``.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from .._numerics.blas import one_blas_thread
from .._numerics.fixedmath import exp
from ._common import MatchSet, inverse_2x2, knn_without_self, match_filter

__all__ = ["pfm_filter", "local_affines"]

_CAP_SCALE = 10_000  # max-flow capacities are integers: energies are multiplied by this and rounded
#: Without keypoint shapes, the share of candidates with no local map above which PFM warns.
NO_MAP_WARN = 0.9


def local_affines(x: np.ndarray, y: np.ndarray, A1=None, A2=None, k: int = 8) -> np.ndarray:
    """Local affine map image 1 -> image 2 of every match, ``(K, 2, 2)``, NaN where undefined.

    ``A2 A1^-1`` from the shapes, else least squares on the edges to the neighbours shared by the ``k``
    nearest in both images (at least two, not collinear)."""
    n = len(x)
    if A1 is not None and A2 is not None:
        out = A2 @ inverse_2x2(A1)
        out[~np.isfinite(out).all(axis=(1, 2))] = np.nan
        return out
    out = np.full((n, 2, 2), np.nan)
    nx, ny = (knn_without_self(p, np.arange(n), k) for p in (x, y))
    if nx.shape[1] < 2:
        return out
    shared = (nx[:, :, None] == ny[:, None, :]).any(-1)  # (n, k): neighbour in image 1 also near in image 2
    dx = (x[nx] - x[:, None, :]) * shared[..., None]
    dy = (y[nx] - y[:, None, :]) * shared[..., None]
    sxx = np.einsum("nka,nkb->nab", dx, dx)
    syx = np.einsum("nka,nkb->nab", dy, dx)
    det = sxx[:, 0, 0] * sxx[:, 1, 1] - sxx[:, 0, 1] ** 2
    scale = np.trace(sxx, axis1=1, axis2=2)
    ok = (shared.sum(1) >= 2) & (det > 1e-9 * np.maximum(scale, 1e-12) ** 2)
    out[ok] = syx[ok] @ inverse_2x2(sxx[ok])
    return out


def _edge_consistency(x, y, A, i, j, sigma: float) -> np.ndarray:
    """``c_ij`` of step 2 for the edges ``(i[e], j[e])``."""

    def rel_error(a, b):
        obs = y[b] - y[a]
        pred = np.einsum("eab,eb->ea", A[a], x[b] - x[a])
        err = np.sqrt(((obs - pred) ** 2).sum(1))
        norm = 0.5 * (np.sqrt((obs**2).sum(1)) + np.sqrt((pred**2).sum(1)))
        return err / np.maximum(norm, 1.0)  # 1 px floor: coincident keypoints

    r1, r2 = rel_error(i, j), rel_error(j, i)
    d1, d2 = np.isfinite(r1), np.isfinite(r2)
    s = np.where(d1, r1**2, 0.0) + np.where(d2, r2**2, 0.0)
    s = np.where(d1 & d2, s, 2.0 * s)  # one direction only: count it for both
    return np.where(d1 | d2, exp(-s / (2.0 * sigma**2)), 0.0)  # _fixedmath's: CPU-independent


def _point_groups(x: np.ndarray, members: np.ndarray):
    """Unique image-1 keypoints of ``members`` and the point of each member."""
    pts, inv = np.unique(x[members], axis=0, return_inverse=True)
    return pts, inv.ravel()


def _point_edges(pts: np.ndarray) -> np.ndarray:
    """Edges (p, q), p < q, of the Delaunay triangulation of ``pts`` (k-NN graph if it is degenerate)."""
    if len(pts) < 2:
        return np.empty((0, 2), np.int64)
    try:
        if len(pts) < 3:
            raise QhullError("too few points")
        tri = Delaunay(pts)
        s = tri.simplices
        e = np.vstack([s[:, [0, 1]], s[:, [1, 2]], s[:, [0, 2]]])
    except QhullError:  # collinear keypoints: the 2 nearest on each side
        nb = knn_without_self(pts, np.arange(len(pts)), 4)
        e = np.c_[np.repeat(np.arange(len(pts)), nb.shape[1]), nb.ravel()]
    e = np.sort(e, axis=1)
    return np.unique(e[e[:, 0] != e[:, 1]], axis=0)


def _matches_at(points: np.ndarray, point_of: np.ndarray, members: np.ndarray):
    """``(e, match)``: every match of each point ``points[e]``, ``members[i]`` being at point ``point_of[i]``;
    points in turn, the matches of a point in the order of ``members``."""
    order = np.argsort(point_of, kind="stable")
    counts = np.bincount(point_of)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    reps = counts[points]
    e = np.repeat(np.arange(len(points)), reps)
    within = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
    return e, members[order[starts[points[e]] + within]]


def _graph_edges(x: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Match edges of the Delaunay graph of the image-1 keypoints of ``members``: every match of point p
    with every match of point q, for every point edge (p, q)."""
    pts, point_of = _point_groups(x, members)
    edges_pts = _point_edges(pts)
    if len(edges_pts) == 0:
        return np.empty((0, 2), np.int64)
    e, a = _matches_at(edges_pts[:, 0], point_of, members)
    f, b = _matches_at(edges_pts[e, 1], point_of, members)
    return np.c_[a[f], b]


def _insertion_edges(x: np.ndarray, kept: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Edges from each new candidate to the kept matches at the vertices of its enclosing triangle."""
    if len(kept) == 0 or len(new) == 0:
        return np.empty((0, 2), np.int64)
    pts, point_of = _point_groups(x, kept)
    q = x[new]
    verts = np.full((len(new), 3), -1, np.int64)
    if len(pts) >= 3:
        try:
            tri = Delaunay(pts)
            # find_simplex is slow for points outside the hull: test the hull's half-planes first.
            hull = ConvexHull(pts)
            inside = np.flatnonzero((q @ hull.equations[:, :2].T + hull.equations[:, 2] <= -1e-9).all(1))
            simplex = tri.find_simplex(q[inside])
            found = simplex >= 0
            verts[inside[found]] = tri.simplices[simplex[found]]
        except QhullError:
            pass
    out = verts[:, 0] < 0
    if out.any():
        kk = min(3, len(pts))
        _, nb = cKDTree(pts).query(q[out], k=kk)
        verts[np.flatnonzero(out)[:, None], np.arange(kk)[None, :]] = nb.reshape(-1, kk)
    cand, vert = np.nonzero(verts >= 0)
    e, b = _matches_at(verts[cand, vert], point_of, kept)  # every kept match at the vertex point
    return np.c_[new[cand[e]], b]


def _min_cut(n: int, unary: np.ndarray, edges: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Labels minimising ``sum unary_i l_i - sum w_ij l_i l_j`` (``w >= 0``) exactly, by a minimum cut."""
    if n == 0:
        return np.zeros(0, bool)
    # -w l_i l_j = -w/2 l_i - w/2 l_j + w/2 [l_i != l_j]
    a = unary.copy()
    np.add.at(a, edges[:, 0], -0.5 * weights)
    np.add.at(a, edges[:, 1], -0.5 * weights)
    src, sink = n, n + 1
    cap_a = np.rint(np.abs(a) * _CAP_SCALE).astype(np.int64)
    cap_w = np.rint(0.5 * weights * _CAP_SCALE).astype(np.int64)
    node = np.arange(n)
    rows = np.r_[np.where(a < 0, src, node), edges[:, 0], edges[:, 1]]
    cols = np.r_[np.where(a < 0, node, sink), edges[:, 1], edges[:, 0]]
    caps = np.r_[cap_a, cap_w, cap_w]
    keep = caps > 0
    if caps.sum() >= np.iinfo(np.int32).max:
        raise ValueError("pfm: energy too large for the integer max-flow; lower lam or t")
    graph = sp.csr_matrix((caps[keep].astype(np.int32), (rows[keep], cols[keep])), shape=(n + 2, n + 2))
    graph.sum_duplicates()
    flow = maximum_flow(graph, src, sink, method="dinic").flow
    residual = (graph.astype(np.int64) - flow.astype(np.int64)).tocsr()
    residual.data = (residual.data > 0).astype(np.int8)
    residual.eliminate_zeros()
    reach = breadth_first_order(residual, src, directed=True, return_predecessors=False)
    labels = np.zeros(n + 2, bool)
    labels[reach] = True
    return labels[:n]


@match_filter(label="PFM", shapes="both", positive=("sigma", "t", "lam", "seed_fraction"), non_negative=("beta",),
              integer=("k",))
def pfm_filter(
    ms: MatchSet,
    *,
    sigma: float = 0.5,
    t: float = 1.5,
    lam: float = 1.0,
    beta: float = 0.5,
    seed_fraction: float = 0.05,
    k: int = 8,
) -> np.ndarray:
    """Progressive Feature Matching: incremental Delaunay graph and exact min-cut labelling.

    %(parameters)s
    scores : ndarray of shape (K,) or None
        Lower is better: the order in which candidates join the graph, and a small bias of the labelling.
    %(image_sizes)s
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Keypoint shapes, for the local maps. Without them, if more than :data:`NO_MAP_WARN` of the
        candidates get no fitted map (e.g. many-to-many candidates), PFM warns (``UserWarning``).
    sigma : float, default 0.5
        Relative transfer error of the pairwise consistency (step 2).
    t, lam, beta : float, default 1.5, 1 and 0.5
        Cost of keeping a match, weight of the consistency, weight of the score rank (step 3).
    seed_fraction : float, default 0.05
        Fraction of the best-scored matches in the first graph (step 4).
    k : int, default 8
        Neighbours of the shape-less local affine fit.

    Returns
    -------
    %(keep)s

    Notes
    -----
    The paper's recall is that of a graph built on every candidate at once (``seed_fraction=1``); the
    default grows it from reliable seeds, as the PFM paper does (``docs/filters.md``).

    References
    ----------
    S. Lee, J. Lim, I. H. Suh, "Progressive feature matching: incremental graph construction and
    optimization", IEEE TIP 29, 2020. Y. Boykov, V. Kolmogorov, "An experimental comparison of
    min-cut/max-flow algorithms for energy minimization in vision", IEEE TPAMI 26(9), 2004.
    """
    if seed_fraction > 1:
        raise ValueError(f"seed_fraction must be in (0, 1], got {seed_fraction!r}")
    n = len(ms)
    if n < 3:
        return np.zeros(n, bool)
    # Qhull's barycentric transforms call LAPACK once per triangle: threads only slow that down.
    with one_blas_thread():
        return _pfm(ms, sigma, t, lam, beta, seed_fraction, k)


def _warn_without_maps(A: np.ndarray) -> None:
    """Warn when more than :data:`NO_MAP_WARN` of the candidates have no fitted map (their edges score 0)."""
    none = int((~np.isfinite(A).all(axis=(1, 2))).sum())
    if none > NO_MAP_WARN * len(A):
        warnings.warn(f"PFM: called without shapes1 / shapes2, it fits the local affine maps to the neighbours "
                      f"shared in both images, and {none} of {len(A)} candidates have none (too few of their "
                      "nearest neighbours agree: other candidates at the same keypoint, as in many-to-many "
                      "candidates, or wrong ones), so it cannot decide on them; pass the keypoint shapes as "
                      "shapes1 and shapes2", UserWarning, stacklevel=6)


def _pfm(ms, sigma: float, t: float, lam: float, beta: float, seed_fraction: float, k: int) -> np.ndarray:
    """The rounds of :func:`pfm_filter` on validated input."""
    n = len(ms)
    x, y = ms.x, ms.y
    A = local_affines(x, y, ms.A1, ms.A2, k)
    if ms.A1 is None:
        _warn_without_maps(A)
    order = np.argsort(ms.scores, kind="stable")  # best first; ties in the rows' canonical order (match_filter)
    rank = np.empty(n)
    rank[order] = np.arange(n) / max(n - 1, 1)
    flat = np.ptp(ms.scores) == 0
    cost = t + (0.0 if flat else beta) * (rank - 0.5)

    def optimise(nodes: np.ndarray, edges: np.ndarray) -> np.ndarray:
        local = np.full(n, -1)
        local[nodes] = np.arange(len(nodes))
        c = _edge_consistency(x, y, A, edges[:, 0], edges[:, 1], sigma) if len(edges) else np.empty(0)
        lab = _min_cut(len(nodes), cost[nodes], local[edges].reshape(-1, 2), lam * c)
        return nodes[lab]

    size = max(3, int(np.ceil(seed_fraction * n)))
    active = order[:size]
    kept = optimise(active, _graph_edges(x, active))
    while size < n:
        size = min(n, 2 * size)
        new = order[len(active) : size]
        active = order[:size]
        if len(kept) < 3:  # nothing reliable yet: the larger candidate set is a fresh seed graph
            kept = optimise(active, _graph_edges(x, active))
            continue
        edges = np.vstack([_graph_edges(x, kept), _insertion_edges(x, kept, new)])
        kept = optimise(np.sort(np.r_[kept, new]), edges)
    keep = np.zeros(n, bool)
    keep[kept] = True
    return keep
