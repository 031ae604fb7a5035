"""PFM: Progressive Feature Matching, incremental graph construction and optimization (Lee, Lim, Suh, TIP 2020).

PFM grows a graph of reliable matches and optimises it repeatedly. Here, as a filter of given candidates
(no new matches are generated), it runs as follows.

1. **Local affine maps.** Every match carries the local map ``A_i`` from image 1 to image 2 around its
   keypoints: ``A_i = A2_i A1_i^-1`` from the keypoint shapes (patch ``{kpt + A u : |u| <= 1}``) when they
   are given; otherwise the least-squares affine map of the edges to its neighbours shared by the ``k``
   nearest matches in both images (LPM's neighbourhood, ``k = 8``), undefined below two such neighbours.
2. **Pairwise consistency.** Two matches joined by an edge agree when each one's map predicts the other's
   image-2 keypoint: with ``r_ij = |(y_j - y_i) - A_i (x_j - x_i)|`` over the mean of the observed and
   predicted edge lengths, ``c_ij = exp(-(r_ij^2 + r_ji^2) / (2 sigma^2))`` (a direction whose map is
   undefined is left out; both undefined: 0).
3. **Graph optimisation.** Binary labels ``l`` (1: inlier) minimise
   ``E(l) = sum_i t_i l_i - lam sum_(ij) c_ij l_i l_j``: a match is worth keeping when its consistency
   with the other kept matches it is linked to exceeds ``t_i = t + beta (rank_i - 1/2)`` (``rank_i`` in
   [0, 1], the score rank, best first; equal scores: 0 offset). The pairwise term is attractive
   (submodular), so the global minimum is a minimum s-t cut (Boykov and Kolmogorov), computed exactly with
   integer capacities by SciPy's maximum flow.
4. **Progressive, incremental graph.** Round 0 takes the best-scored ``seed_fraction`` of the matches,
   links them by the Delaunay triangulation of their image-1 keypoints and optimises. Each further round
   doubles the candidates (score order): the graph is the Delaunay triangulation of the matches kept so
   far, and each new candidate is inserted at the triangle containing its image-1 keypoint (its three
   vertices; outside the hull, its three nearest kept keypoints); the whole graph is optimised again, so
   earlier decisions can be revised. The last round holds every match.

Constants the paper leaves to the implementation, chosen here: ``sigma = 0.5`` (relative transfer error,
tolerant enough for the similarity frames of SIFT under perspective change: 0.3 lost most inliers of
Graffiti 1-3), ``t = 1.5`` and ``lam = 1`` (a match needs the consistency of about two kept neighbours),
``beta = 0.5`` (scores break near ties only), ``seed_fraction = 0.05`` (seeds few and reliable: with a
quarter of 13 000 Graffiti candidates as seeds, outlier seeds cut the inliers apart and nothing survived
on 1-4). When a round keeps fewer than three matches, the next, larger candidate set is triangulated
afresh as a new seed graph. Matches sharing an image-1 keypoint (many-to-many input) are linked
to the matches of the neighbouring keypoints, never to each other.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

from .._numerics.blas import one_blas_thread
from .._numerics.fixedmath import exp
from ._common import MatchSet, check_positive, knn_without_self, match_filter

__all__ = ["pfm_filter", "local_affines"]

_CAP_SCALE = 10_000  # max-flow capacities are integers: energies are multiplied by this and rounded
#: Without keypoint shapes, the share of candidates left with no local map above which PFM cannot decide (and
#: warns). Measured on SIFT + RootSIFT at 1500 keypoints: over 99 % on blob matching's many-to-many (paper-best)
#: candidates, 51-96 % on its one-to-one (baseline) ones, whose outliers have none.
NO_MAP_WARN = 0.9


def _inv2(A: np.ndarray) -> np.ndarray:
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    inv = np.stack([np.stack([A[:, 1, 1], -A[:, 0, 1]], -1), np.stack([-A[:, 1, 0], A[:, 0, 0]], -1)], 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return inv / det[:, None, None]


def local_affines(x: np.ndarray, y: np.ndarray, A1=None, A2=None, k: int = 8) -> np.ndarray:
    """Local affine map image 1 -> image 2 of every match, ``(K, 2, 2)``, NaN where undefined.

    From the shapes (``A2 A1^-1``) when both are given, else fitted by least squares to the edges towards
    the neighbours shared by the ``k`` nearest matches in both images (at least two, not collinear).
    """
    n = len(x)
    if A1 is not None and A2 is not None:
        out = A2 @ _inv2(A1)
        out[~np.isfinite(out).all(axis=(1, 2))] = np.nan
        return out
    out = np.full((n, 2, 2), np.nan)
    nx = knn_without_self(x, np.arange(n), k)
    ny = knn_without_self(y, np.arange(n), k)
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
    out[ok] = syx[ok] @ _inv2(sxx[ok])
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


def _expand(edges_pts: np.ndarray, point_of: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Match edges from point edges: every match of point p with every match of point q."""
    if len(edges_pts) == 0 or len(members) == 0:
        return np.empty((0, 2), np.int64)
    order = np.argsort(point_of, kind="stable")
    sorted_pts = point_of[order]
    starts = np.searchsorted(sorted_pts, np.arange(point_of.max() + 1))
    counts = np.bincount(point_of, minlength=point_of.max() + 1)
    p, q = edges_pts[:, 0], edges_pts[:, 1]
    cp, cq = counts[p], counts[q]
    reps = cp * cq
    e_idx = np.repeat(np.arange(len(p)), reps)
    within = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
    a = members[order[starts[p[e_idx]] + within // cq[e_idx]]]
    b = members[order[starts[q[e_idx]] + within % cq[e_idx]]]
    return np.c_[a, b]


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
    point_edges = np.c_[np.arange(len(new))[cand], verts[cand, vert]]
    # Every kept match at the vertex point; the candidate side is a single match.
    order = np.argsort(point_of, kind="stable")
    counts = np.bincount(point_of, minlength=len(pts))
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    reps = counts[point_edges[:, 1]]
    e_idx = np.repeat(np.arange(len(point_edges)), reps)
    within = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
    a = new[point_edges[e_idx, 0]]
    b = kept[order[starts[point_edges[e_idx, 1]] + within]]
    return np.c_[a, b]


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


@match_filter(label="PFM", shapes="both")
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

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    scores : ndarray of shape (K,) or None
        Lower is better: the order in which candidates join the graph and a small bias of the labelling
        (``None``: all equal, input order).
    %(image_sizes)s
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Affine shapes of the keypoints: the local maps ``A2 A1^-1``. Without them the maps are fitted to
        the neighbours shared in both images; where that leaves almost every candidate without a map (more
        than 90 %: on many-to-many candidates such as blob matching's, whose nearest neighbours are other
        candidates at one keypoint, or where nearly all are wrong), PFM cannot decide and says so
        (``UserWarning`` naming ``shapes1``).
    sigma : float, default 0.5
        Relative transfer error of the pairwise consistency (step 2 of the module notes).
    t, lam : float, default 1.5 and 1
        Cost of keeping a match and weight of the consistency between kept matches (step 3).
    beta : float, default 0.5
        Weight of the score rank in the cost of keeping a match.
    seed_fraction : float, default 0.05
        Fraction of the best-scored matches in the first graph; each round doubles it (step 4).
    k : int, default 8
        Neighbours of the shape-less local affine fit.

    Returns
    -------
    %(keep)s

    Notes
    -----
    Next to the paper's Table 2 (issue 22, item 2). The authors' code is distributed from the first author's
    Google Sites page (sites.google.com/view/sehyung, "progressive-feature-matching"), not on GitHub; it could
    not be fetched here, so it was not run. Bellavia's paper says the original code was "only modified to
    work with blob matches as input", not how. On the 55 shared real pairs (baseline configuration: SIFT +
    RootSIFT, ``baseline`` blob candidates at 1500 keypoints, the SIFT shapes giving the local maps; an empty
    output counts as 0 % precision, as in the paper's means) the defaults give P / R 75.0 / 68.2 (planar, 7
    empty outputs) and 86.3 / 63.5 (non-planar, 2), the paper 75.4 / 35.4 and 76.0 / 35.1: the same precision,
    twice the recall. What halves it: ``seed_fraction = 1`` (every candidate in the first graph, one
    optimisation, no progressive rounds) gives 64.8 / 34.9 and 79.4 / 30.0, the paper's recall (-0.5 / -5.1)
    at -10.6 / +3.4 precision; 0.25 / 0.5 give 71.3 / 61.1, 67.8 / 52.2 (planar) and 82.8 / 54.5,
    75.4 / 46.1. A tighter consistency does it too: ``sigma`` 0.3 / 0.2 give 72.1 / 53.8, 59.2 / 37.0 and
    76.2 / 48.6, 73.2 / 33.9. A larger cost ``t`` does not (2.5: 65.7 / 48.2, 72.3 / 42.2; 3.5: almost every
    output empty). So the paper's row matches a graph built on all the blob candidates at once (the inliers'
    Delaunay neighbours are then mostly wrong candidates, and fewer inliers gather the consistency ``t`` asks
    for) rather than grown from the best-scored ones, which is one way of feeding blob matches to PFM; but
    Bellavia's text does not say so and the PFM paper grows the graph from reliable seeds, so the default
    stays progressive. Commands (``OMP_NUM_THREADS=1``, ``CTXMATCH_DATA`` set; all 55 pairs by default)::

        python benchmarks/ablate_peer_filters.py --sweep pfm:seed_fraction=0.05,0.25,0.5,1.0
        python benchmarks/ablate_peer_filters.py --sweep pfm:sigma=0.2,0.3,0.5 --sweep pfm:t=1.5,2.5,3.5

    References
    ----------
    S. Lee, J. Lim, I. H. Suh, "Progressive feature matching: incremental graph construction and
    optimization", IEEE TIP 29, 2020.
    Y. Boykov, V. Kolmogorov, "An experimental comparison of min-cut/max-flow algorithms for energy
    minimization in vision", IEEE TPAMI 26(9), 2004.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = pfm_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                   image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    sigma, lam = check_positive(sigma, "sigma"), check_positive(lam, "lam")
    t = check_positive(t, "t")
    beta = check_positive(beta, "beta", allow_zero=True)
    seed_fraction = check_positive(seed_fraction, "seed_fraction")
    if seed_fraction > 1:
        raise ValueError(f"seed_fraction must be in (0, 1], got {seed_fraction!r}")
    k = check_positive(k, "k", integer=True)
    n = len(ms)
    if n < 3:
        return np.zeros(n, bool)
    # Qhull's barycentric transforms call LAPACK once per triangle: threads only slow that down.
    with one_blas_thread():
        return _pfm(ms, sigma, t, lam, beta, seed_fraction, k)


def _warn_without_maps(A: np.ndarray) -> None:
    """Warn (naming the shapes) when the shape-less fit leaves more than :data:`NO_MAP_WARN` of the
    candidates without a local map: the consistency of their edges is then 0, and an empty or near-empty
    output is no verdict on them."""
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
    pts, point_of = _point_groups(x, active)
    kept = optimise(active, _expand(_point_edges(pts), point_of, active))
    while size < n:
        size = min(n, 2 * size)
        new = order[len(active) : size]
        active = order[:size]
        if len(kept) < 3:  # nothing reliable yet: the larger candidate set is a fresh seed graph
            pts, point_of = _point_groups(x, active)
            kept = optimise(active, _expand(_point_edges(pts), point_of, active))
            continue
        pts, point_of = _point_groups(x, kept)
        edges = np.vstack([_expand(_point_edges(pts), point_of, kept), _insertion_edges(x, kept, new)])
        kept = optimise(np.sort(np.r_[kept, new]), edges)
    keep = np.zeros(n, bool)
    keep[kept] = True
    return keep
