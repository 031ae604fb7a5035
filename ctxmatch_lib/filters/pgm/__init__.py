"""PGM: Progressive Graph Matching (Cho & Lee, CVPR 2012), :func:`pgm_filter`, with :func:`rrwm` (ECCV 2010).

Graph matching (RRWM, greedy discretisation) alternates with graph progression (votes of the matches pick
the next active set) until ``X' W X`` stops growing. Affinity: the mutual projection error of the local
affine maps (ICCV 2009), else the relative edge-length distortion (Leordeanu & Hebert, ICCV 2005); sparse,
for memory, over each candidate's ``k`` nearest (Bellavia, Sec. 2: "defined by the k closest matches").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from ..._numerics.fixedmath import exp
from .._common import MatchSet, inverse_2x2, knn_without_self, match_filter
from ._kernels import pair_affinity as _pair_affinity
from ._kernels import sinkhorn as _pgm_sinkhorn
from ._kernels import votes as _pgm_votes

__all__ = ["pgm_filter", "rrwm"]


def _local_affines(A1: np.ndarray | None, A2: np.ndarray | None) -> np.ndarray | None:
    """Image-1 -> image-2 local affine transformation ``A2 inv(A1)`` of every match, or None."""
    if A1 is None or A2 is None:
        return None
    T = A2 @ inverse_2x2(A1)
    # A singular image-1 shape gives no transformation: such a match predicts nothing (infinite error).
    T[~np.isfinite(T).all(axis=(1, 2))] = np.inf
    return T


def _unique(key: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an int64 array (a sort, much faster here than ``np.unique``'s hashing)."""
    key = np.sort(key)
    return key[np.r_[True, key[1:] != key[:-1]]] if len(key) else key


def _affinity(x, y, T, m, k: int, tau: float, rho: float) -> sp.csr_matrix:
    """Symmetric sparse affinity over the candidates ``x, y, m`` restricted to spatial k-NN pairs."""
    n = len(x)
    everyone = np.arange(n)
    rows, cols = [], []
    for p in (x, y):
        nb = knn_without_self(p, everyone, k)
        rows.append(np.repeat(everyone, nb.shape[1]))
        cols.append(nb.ravel())
    r = np.concatenate(rows + cols)
    c = np.concatenate(cols + rows)
    key = _unique(r * n + c)
    r, c = key // n, key % n
    # Candidates that share a keypoint are in conflict: no walk between them (ECCV 2010).
    ok = (m[r, 0] != m[c, 0]) & (m[r, 1] != m[c, 1])
    r, c = r[ok], c[ok]
    w = _pair_affinity(x, y, T, r, c, tau, rho)
    pos = w > 0
    return sp.csr_matrix((w[pos], (r[pos], c[pos])), shape=(n, n))


def _sinkhorn(a: np.ndarray, g1: np.ndarray, g2: np.ndarray, tol: float, max_iter: int) -> np.ndarray:
    """Sinkhorn normalisation of the entries ``a`` at ``(g1, g2)`` of an ``n1 x n2`` assignment matrix.

    Made square by ``|n1 - n2|`` dummy rows of ones, as the authors' code; they stay equal, so one is kept."""
    return _pgm_sinkhorn(a, g1, g2, tol, max_iter)  # compiled, same arithmetic as the array form


def rrwm(
    W: sp.spmatrix,
    group1: np.ndarray,
    group2: np.ndarray,
    *,
    c: float = 0.2,
    amp_max: float = 30.0,
    max_iter: int = 300,
    tol: float = 1e-25,
    sinkhorn_tol: float = 1e-3,
    sinkhorn_iter: int = 10,
) -> np.ndarray:
    """Reweighted random walks graph matching (Cho, Lee & Lee, ECCV 2010, Alg. 1) on a sparse affinity.

    Defaults are the authors' code's, but ``sinkhorn_iter`` (theirs 1000).

    Parameters
    ----------
    W : sparse matrix of shape (n, n)
        Non-negative symmetric affinity between candidates (zero between conflicting ones).
    group1, group2 : ndarray of shape (n,), int
        Conflict group of every candidate in image 1 and in image 2 (e.g. its keypoint index).
    c, amp_max : float, default 0.2 and 30
        Probability of a plain walk step; inflation ``exp(amp_max x / max x)`` of the reweighted jump.
    max_iter, tol : int, float, default 300 and 1e-25
        Step limit, and bound of the squared change against either of the last two iterates.
    sinkhorn_tol, sinkhorn_iter : float, int, default 1e-3 and 10
        Stopping rule of the Sinkhorn normalisation of each step.

    Returns
    -------
    x : ndarray of shape (n,)
        Stationary scores, summing to 1 (all zero when ``W`` has no edge).
    """
    W = sp.csr_matrix(W)
    n = W.shape[0]
    if n == 0:
        return np.zeros(0)
    deg = np.asarray(W.sum(axis=0)).ravel()
    if deg.max() <= 0:
        return np.zeros(n)
    P = W / deg.max()  # the walk matrix, normalised by the maximum degree
    g1 = np.unique(np.asarray(group1), return_inverse=True)[1].ravel()
    g2 = np.unique(np.asarray(group2), return_inverse=True)[1].ravel()
    x = np.full(n, 1.0 / n)
    x_prev = x.copy()
    jump = x.copy()
    for _ in range(max_iter):
        s = P @ (c * x + (1.0 - c) * jump)
        total = s.sum()
        if total > 0:
            s /= total
        top = s.max()
        jump = exp(amp_max * s / top) if top > 0 else np.ones(n)
        jump = _sinkhorn(jump, g1, g2, sinkhorn_tol, sinkhorn_iter)
        jump /= jump.sum()
        diff = min(((s - x) ** 2).sum(), ((s - x_prev) ** 2).sum())
        x_prev, x = x, s
        if diff < tol:
            break
    return x


def greedy_assignment(score: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Greedy one-to-one discretisation of ``score`` > 0 (ties: the lower index)."""
    keep = np.zeros(len(score), bool)
    used1, used2 = set(), set()
    for i in np.argsort(-score, kind="stable"):
        if score[i] <= 0:
            break
        a, b = int(m[i, 0]), int(m[i, 1])
        if a in used1 or b in used2:
            continue
        used1.add(a)
        used2.add(b)
        keep[i] = True
    return keep


def _top_per_keypoint(vote: np.ndarray, key: np.ndarray, per_node: int, positive: bool = True) -> np.ndarray:
    """Mask of the ``per_node`` highest ``vote`` candidates of every keypoint ``key`` (only votes > 0 if
    ``positive``); ties go to the lower index."""
    order = np.lexsort((np.arange(len(key)), -vote, key))
    k_sorted = key[order]
    start = np.r_[0, np.flatnonzero(k_sorted[1:] != k_sorted[:-1]) + 1]
    rank = np.arange(len(key)) - np.repeat(start, np.diff(np.r_[start, len(key)]))
    sel = np.zeros(len(key), bool)
    sel[order[rank < per_node]] = True
    return sel & (vote > 0) if positive else sel


@match_filter(label="PGM", merge=True, one_to_one=True, integer=("k", "max_rounds", "per_node", "n_init", "max_iter"),
              positive=("tau", "rho", "amp_max"), non_negative=("min_support", "c"))
def pgm_filter(
    ms: MatchSet,
    *,
    k: int = 10,
    tau: float = 50.0,
    rho: float = 0.5,
    max_rounds: int = 3,
    per_node: int = 3,
    n_init: int = 1,
    min_support: float = 2.0,
    c: float = 0.2,
    amp_max: float = 30.0,
    max_iter: int = 300,
) -> np.ndarray:
    """Progressive Graph Matching with RRWM on a sparse k-NN affinity.

    %(parameters)s
        Candidates sharing a keypoint are RRWM's conflict groups; the output is one-to-one.
    scores : ndarray of shape (K,) or None
        Lower is better; they pick the initial active set. ``None``: all equal.
    %(image_sizes)s
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Keypoint shapes, for the mutual projection error; without them, the length distortion.
    k : int, default 10
        Neighbours per image that get an affinity entry (and vote).
    tau, rho : float, default 50 and 0.5
        Cut-offs of the mutual projection error (pixels) and of the relative length distortion.
    max_rounds : int, default 3
        Maximum number of matching/progression rounds.
    per_node, n_init : int, default 3 and 1
        Candidates per image-1 keypoint in the next active set (best voted) and the first (best scored).
    min_support : float, default 2
        Affinity sum with the other matches needed to output a match of the final matching.
    c, amp_max, max_iter : float, float, int
        RRWM parameters, see :func:`rrwm`.

    Returns
    -------
    %(keep)s

    Notes
    -----
    Constants and departures from the authors' release: ``docs/filters.md`` ("PGM and PFM ...").
    %(coincident)s
    A location counts once in the graph and the votes; of rows repeating a keypoint pair only the best is output.

    References
    ----------
    M. Cho, K. M. Lee, "Progressive graph matching: Making a move of graphs via probabilistic voting", CVPR 2012.
    M. Cho, J. Lee, K. M. Lee, "Reweighted random walks for graph matching", ECCV 2010; "Feature correspondence
    and deformable object matching via agglomerative correspondence clustering", ICCV 2009.
    """
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    x, y, m = ms.x, ms.y, ms.matches
    T = _local_affines(ms.A1, ms.A2)
    # Initial active set: the best-scored candidate of every image-1 keypoint.
    active = _top_per_keypoint(-ms.scores, m[:, 0], n_init, positive=False)
    sol = np.empty(0, np.int64)  # the current matching
    best = -1.0
    for _ in range(max_rounds):
        idx = np.flatnonzero(active)
        if len(idx) < 2:
            break
        W = _affinity(x[idx], y[idx], None if T is None else T[idx], m[idx], k, tau, rho)
        s = rrwm(W, m[idx, 0], m[idx, 1], c=c, amp_max=amp_max, max_iter=max_iter)
        assigned = greedy_assignment(s, m[idx])
        # The graph matching objective X' W X of the discrete solution; PGM stops when it no longer grows.
        objective = float(W[assigned][:, assigned].sum())
        if objective <= best:
            break
        best = objective
        sol = idx[assigned]
        if len(sol) < 2:
            break
        # Graph progression (CVPR 2012): the current matches vote for every candidate.
        vote = _votes(x, y, T, m, sol, s[assigned], k, tau, rho)
        new_active = _top_per_keypoint(vote, m[:, 0], per_node)
        new_active[sol] = True
        if np.array_equal(new_active, active):
            break
        active = new_active
    if len(sol) < 2:
        return np.zeros(n, bool)
    # Support of each output match: consistent matches of the solution among its neighbours.
    W = _affinity(x[sol], y[sol], None if T is None else T[sol], m[sol], k, tau, rho)
    support = np.asarray(W.sum(axis=1)).ravel()
    keep = np.zeros(n, bool)
    keep[sol[support >= min_support]] = True
    return keep


def _votes(x, y, T, m, sol: np.ndarray, weight: np.ndarray, k: int, tau: float, rho: float) -> np.ndarray:
    """Vote ``sum_j w(a, j) weight_j`` of every candidate ``a`` over its ``k`` nearest matches ``j`` of ``sol``."""
    n = len(x)
    kk = min(k, len(sol))
    nbs = []
    for p, key in ((x, m[:, 0]), (y, m[:, 1])):
        # The candidates of one keypoint share its location, hence its neighbours: one query per keypoint.
        _, first, inv = np.unique(key, return_index=True, return_inverse=True)
        _, nb = cKDTree(p[sol]).query(p[first], k=kk)
        nbs.append(np.asarray(nb).reshape(len(first), kk)[inv.reshape(-1)])
    # Each candidate's neighbours in either image, ascending (the pairs in (a, b) order), each voting once.
    nb = sol[np.sort(np.concatenate(nbs, axis=1), axis=1)]
    score = np.zeros(n)
    score[sol] = weight
    return _pgm_votes(x, y, T, m, nb, score, tau, rho)
