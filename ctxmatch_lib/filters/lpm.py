"""LPM (Locality Preserving Matching, Ma et al., IJCV 2019) and GLPM (Guided LPM, Ma et al., TGRS 2018).

Both keep a match whose ``K`` nearest matches in image 1 and in image 2 are largely the same.
:func:`lpm_filter` (IJCV 2019, Sec. 3.3-4.3): cost ``(K - n_i + m_i) / K`` (Eq. (13)-(15)), ``m_i`` the
common neighbours whose motion disagrees, over the scales ``K + 2, K, K - 2``, in two iterations.
:func:`glpm_filter` (TGRS 2018, Sec. III): cost ``2 (K - n_i)`` (Eq. (4)), two passes on a small set of
strict ratio-test matches, which then guides two passes over the whole set (:data:`GLPM_SCHEDULE`).
"""

from __future__ import annotations

import numpy as np

from ._common import MatchSet, check_positive, knn_without_self, match_filter

__all__ = ["lpm_filter", "glpm_filter", "GLPM_SCHEDULE"]


def _tree_neighbours(points, candidates, k: int, queries=None, *, drop_outside: bool) -> np.ndarray:
    """The authors' demos' neighbour lists: the ``k + 1`` nearest ``candidates``, the first dropped as "self".

    A query outside ``candidates`` drops it too if ``drop_outside`` (LPM), else keeps ``k`` (GLPM's ffm2);
    among rows at one location the smallest index is the one dropped (as VLFeat's tree)."""
    q = np.arange(len(points)) if queries is None else np.asarray(queries)
    cand = np.asarray(candidates)
    nb = knn_without_self(points, cand, k + 1, queries=q)
    w = nb.shape[1]
    if w == 0:
        return nb
    member = np.zeros(len(points), bool)
    member[cand] = True
    inside = member[q]
    # Candidates at the query's location with a smaller index precede it in the (distance, index) ranking:
    # sorted by (x, y, index), a candidate's count is its distance to the first of its run of equal points.
    pts = np.asarray(points)
    sc = cand[np.lexsort((cand, pts[cand, 1], pts[cand, 0]))]
    new_run = np.r_[True, (np.diff(pts[sc], axis=0) != 0).any(axis=1)]
    run_start = np.maximum.accumulate(np.where(new_run, np.arange(len(sc)), 0))
    count = np.zeros(len(points), np.int64)
    count[sc] = np.arange(len(sc)) - run_start
    before = np.where(inside, np.minimum(count[q], w), 0)
    width = min(k, w) if not drop_outside or inside.all() else min(k, w - 1)
    if before.any():
        cols = np.arange(w + 1)[None, :]
        src = np.clip(np.where(cols < before[:, None], cols, cols - 1), 0, w - 1)
        with_self = np.where(cols == before[:, None], q[:, None], np.take_along_axis(nb, src, axis=1))
        out = with_self[:, 1:1 + width]
    else:  # every candidate query is the first at its location: it is the answer dropped
        out = nb[:, :width]
    if not inside.all():
        outside = nb[:, 1:1 + width] if drop_outside else nb[:, :width]
        out = np.where(inside[:, None], out, outside)
    return out


def _lpm_cost(x, y, candidates, k: int, tau: float, reading: str = "code",
              tree_ties: bool = True) -> np.ndarray:
    """Multi-scale LPM cost (IJCV 2019, Eq. (15)), neighbours among ``candidates`` (see :func:`lpm_filter`)."""
    v = y - x
    norm = np.hypot(v[:, 0], v[:, 1])
    scales = [s for s in (k + 2, k, k - 2) if s > 0]
    code = reading == "code"
    if code and tree_ties:
        # The demo asks the tree for K + 3 answers and drops the first one: the query itself when it is a
        # candidate and first among the rows at its location, its nearest candidate otherwise.
        nx_all, ny_all = (_tree_neighbours(p, candidates, max(scales), drop_outside=True) for p in (x, y))
    else:
        nx_all, ny_all = (knn_without_self(p, candidates, max(scales) + (1 if code else 0)) for p in (x, y))
    if code and not tree_ties:  # the query always excluded, the nearest candidate of an outside query dropped
        outside = np.ones(len(x), bool)
        outside[candidates] = False
        if outside.any() and nx_all.shape[1] > 0:
            nx_all, ny_all = (np.where(outside[:, None], nb[:, 1:], nb[:, :-1]) for nb in (nx_all, ny_all))
    # Motion similarity of every query to each of its image-1 neighbours (a common neighbour is one of them).
    nbr = nx_all
    vj = v[nbr]
    ni, nj = norm[:, None], norm[nbr]
    lo, hi = np.minimum(ni, nj), np.maximum(ni, nj)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = lo / hi
        if code:
            ratio = ratio * ratio
        sim = (v[:, None, 0] * vj[..., 0] + v[:, None, 1] * vj[..., 1]) / (ni * nj) * ratio
    # Two null motions agree; a null and a non-null one do not.
    sim = np.where(hi == 0, 1.0, np.where(lo == 0, 0.0, sim))
    # The code counts a disagreement when s < tau, the IJCV reading when s <= tau (measure zero).
    disagree = (sim < tau) if code else (sim <= tau)
    cost = np.zeros(len(x))
    for j, s in enumerate(scales):
        first = j if code else 0
        nx, ny = nx_all[:, first:first + s], ny_all[:, first:first + s]
        s_eff = nx.shape[1]
        if s_eff == 0:
            cost += 1.0
            continue
        # Both lists hold distinct rows: an image-1 neighbour is common when it is in the image-2 list.
        common = (nx[:, :, None] == ny[:, None, :]).any(axis=2)
        n_common = common.sum(1)
        n_bad = (common & disagree[:, first:first + s]).sum(1)
        cost += (s_eff - n_common + n_bad) / s_eff
    return cost / len(scales)


@match_filter(label="LPM", merge=True, integer=("k",))
def lpm_filter(
    ms: MatchSet,
    *,
    k: int = 6,
    lambdas=(0.8, 0.5),
    tau: float = 0.2,
    reading: str = "code",
    tree_ties: bool = True,
) -> np.ndarray:
    """Locality Preserving Matching, two iterations with multi-scale neighbourhoods.

    %(parameters_unused)s
    k : int, default 6
        Central neighbourhood size; the scales are ``k + 2, k, k - 2`` (Sec. 5.1).
    lambdas : (float, float), default (0.8, 0.5)
        Cost thresholds of the first and second iteration (Sec. 5.1).
    tau : float, default 0.2
        Motion-consistency threshold of Eq. (14) (Sec. 5.1).
    reading : {"code", "ijcv"}, default "code"
        Neighbourhoods and motion similarity of the authors' MATLAB code (see Notes) or of the IJCV text.
    tree_ties : bool, default True
        With ``"code"``: the tree answer dropped as "self" is the smallest-index row at the query's
        location (True), or always the query (False).

    %(keep_coincident)s
    A location counts once in the neighbourhoods.

    The paper ran the authors' code, so ``reading="code"`` follows ``demo_LPM_v2.m``/``LPM_cosF.m``:
    neighbour ranks 1..K+2, 2..K+1, 3..K per scale; squared length ratio in Eq. (13); ``s < tau``; the
    tree's first answer dropped as "self"; a second iteration with K + 4 inliers (``docs/filters.md``).

    References
    ----------
    J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality preserving matching", IJCV 127(5), 2019.
    """
    lam = [check_positive(v, "lambdas", allow_zero=True) for v in np.atleast_1d(lambdas)]
    if len(lam) != 2:
        raise ValueError(f"lambdas must hold two thresholds, got {lambdas!r}")
    if reading not in ("code", "ijcv"):
        raise ValueError(f"reading must be 'code' or 'ijcv', got {reading!r}")
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    keep = _lpm_cost(ms.x, ms.y, np.arange(n), k, tau, reading, tree_ties) <= lam[0]
    # Second iteration on the neighbourhoods of the first-pass inliers, when enough (demo code: k + 4).
    if keep.sum() >= k + 4:
        keep = _lpm_cost(ms.x, ms.y, np.flatnonzero(keep), k, tau, reading, tree_ties) <= lam[1]
    return keep


def _glpm_pass(x, y, subset, candidates, k: int, lam: float, tree_ties: bool = True) -> np.ndarray:
    """One GLPM pass over ``subset``: cost ``2 (K - n_i)`` against the guide ``candidates`` (Eq. (4))."""
    if len(subset) == 0 or len(candidates) < 2:
        return np.zeros(len(subset), bool)
    if tree_ties:
        nx, ny = (_tree_neighbours(p, candidates, k, queries=subset, drop_outside=False) for p in (x, y))
    else:
        nx, ny = (knn_without_self(p, candidates, k, queries=subset) for p in (x, y))
    kk = nx.shape[1]
    both = np.sort(np.concatenate([nx, ny], axis=1), axis=1)
    n_common = (both[:, 1:] == both[:, :-1]).sum(1)  # a match index twice: a common neighbour
    # Eq. (4): every neighbour missing from the other image's neighbourhood costs 1, in both images.
    return 2 * (kk - n_common) <= lam * kk / k


# (K, lambda) of the four passes of GLPM: two on the small set, two guided ones on the whole set (Sec. IV).
GLPM_SCHEDULE = ((4, 6.0), (4, 4.0), (6, 6.0), (5, 4.0))


@match_filter(label="GLPM", merge=True, nnr=("ratio",))
def glpm_filter(
    ms: MatchSet,
    *,
    ratio: float = 1.0 / 1.5,
    schedule=GLPM_SCHEDULE,
    guide: str = "location",
    tree_ties: bool = True,
) -> np.ndarray:
    """Guided Locality Preserving Matching.

    %(parameters)s
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better; ``scores <= ratio`` make the small set (``None``: every match).
        %(nnr_scale)s
    %(image_sizes)s
    %(shapes_unused)s
    ratio : float, default 1/1.5
        Strict NNR threshold of the small putative set (Sec. IV).
    schedule : sequence of four (K, lambda), default :data:`GLPM_SCHEDULE`
        Neighbourhood size and cost threshold of the two small-set and the two guided passes.
    guide : {"location", "rows"}, default "location"
        The guide of the whole set: every candidate at a small-set inlier's image-1 location (the demo), or
        the small-set inliers alone.
    tree_ties : bool, default True
        As in :func:`lpm_filter`, for ``ffm2``'s skipped answer.

    %(keep_coincident)s
    A location counts once in the neighbourhoods and in the guide. Passes, schedule and cost follow the
    authors' ``demo.m`` with ``ffm2.cpp``, as do ``guide`` and ``tree_ties``. Agreement: ``docs/filters.md``.

    References
    ----------
    J. Ma, J. Jiang, H. Zhou, J. Zhao, X. Guo, "Guided locality preserving feature matching for remote
    sensing image registration", IEEE TGRS 56(8), 2018.
    """
    sched = [(check_positive(kk, "schedule", integer=True), check_positive(lam, "schedule", allow_zero=True))
             for kk, lam in schedule]
    if len(sched) != 4:
        raise ValueError(f"schedule must hold four (K, lambda) pairs, got {len(sched)}")
    if guide not in ("location", "rows"):
        raise ValueError(f"guide must be 'location' or 'rows', got {guide!r}")
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    x, y = ms.x, ms.y
    small = np.flatnonzero(ms.scores <= ratio)
    if len(small) < sched[0][0] + 1:
        small = np.arange(n)  # too few confident matches to guide anything: start from all of them
    # Passes 1-2: the small set filters itself (the second pass uses the first pass's survivors as guide).
    inl = small[_glpm_pass(x, y, small, small, *sched[0], tree_ties)]
    inl = small[_glpm_pass(x, y, small, inl, *sched[1], tree_ties)] if len(inl) > 1 else inl
    if guide == "location":  # every candidate at the image-1 location of a small-set inlier (demo.m)
        _, loc = np.unique(x, axis=0, return_inverse=True)
        loc = loc.reshape(-1)
        inl = np.flatnonzero(np.isin(loc, loc[inl]))
    # Passes 3-4: the whole set, guided by the small-set inliers, then by the first guided inliers.
    everyone = np.arange(n)
    keep = _glpm_pass(x, y, everyone, inl, *sched[2], tree_ties)
    keep = _glpm_pass(x, y, everyone, np.flatnonzero(keep), *sched[3], tree_ties)
    return keep
