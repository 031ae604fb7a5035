"""LPM (Locality Preserving Matching, Ma et al., IJCV 2019) and GLPM (Guided LPM, Ma et al., TGRS 2018).

Both keep a match when the neighbourhood of its keypoint is preserved across the images: the ``K`` nearest
matches of ``x_i`` in image 1 and those of ``y_i`` in image 2 should largely be the same matches.

LPM (IJCV 2019, Sec. 3.3 and 4): the cost of match ``i`` at scale ``K`` is ``(K - n_i + m_i) / K``, with
``n_i`` the common neighbours and ``m_i`` the common neighbours whose motion vector disagrees with that of
``i`` (consensus of neighbourhood topology, Eq. (13)-(15): ``min(|v_i|, |v_j|) / max(|v_i|, |v_j|) *
cos(v_i, v_j) <= tau``). The costs are averaged over the scales ``K + 2, K, K - 2`` (multi-scale
neighbourhoods, Sec. 4.2) and the match is kept when the mean is at most ``lambda``. A second iteration
recomputes the neighbourhoods among the matches kept by the first (Sec. 4.3).

GLPM (TGRS 2018, Sec. III): a small, reliable putative set made by a strict ratio test is filtered by two
locality-preserving passes; it then guides the filtering of the whole set, the neighbours of every match
being searched only among the guide matches. Each pass keeps a match when its neighbourhood cost
``2 (K - n_i)`` (both images, binary distances, Eq. (4)) is at most ``lambda``.
"""

from __future__ import annotations

import numpy as np

from ._common import check_positive, knn_without_self, merge_coincident, prepare

__all__ = ["lpm_filter", "glpm_filter", "GLPM_SCHEDULE"]


def _common_neighbours(nx: np.ndarray, ny: np.ndarray):
    """Sorted concatenation of the two neighbour lists and the mask of the entries present in both."""
    both = np.sort(np.concatenate([nx, ny], axis=1), axis=1)
    dup = both[:, 1:] == both[:, :-1]  # a match index appears twice: a common neighbour
    return both[:, :-1], dup


def _lpm_cost(x, y, candidates, k: int, tau: float) -> np.ndarray:
    """Multi-scale LPM cost (IJCV 2019, Eq. (15)) with neighbours searched among ``candidates``."""
    v = y - x
    norm = np.hypot(v[:, 0], v[:, 1])
    scales = [s for s in (k + 2, k, k - 2) if s > 0]
    nx_all = knn_without_self(x, candidates, max(scales))
    ny_all = knn_without_self(y, candidates, max(scales))
    cost = np.zeros(len(x))
    for s in scales:
        s_eff = min(s, nx_all.shape[1])
        if s_eff == 0:
            cost += 1.0
            continue
        nb, dup = _common_neighbours(nx_all[:, :s_eff], ny_all[:, :s_eff])
        vi, vj = v[:, None, :], v[nb]
        ni, nj = norm[:, None], norm[nb]
        lo, hi = np.minimum(ni, nj), np.maximum(ni, nj)
        with np.errstate(invalid="ignore", divide="ignore"):
            sim = (vi * vj).sum(-1) / (ni * nj) * lo / hi
        # Two null motions agree; a null and a non-null one do not.
        sim = np.where(hi == 0, 1.0, np.where(lo == 0, 0.0, sim))
        n_common = dup.sum(1)
        n_bad = (dup & (sim <= tau)).sum(1)
        cost += (s_eff - n_common + n_bad) / s_eff
    return cost / len(scales)


def lpm_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    k: int = 6,
    lambdas=(0.8, 0.5),
    tau: float = 0.2,
) -> np.ndarray:
    """Locality Preserving Matching, two iterations with multi-scale neighbourhoods.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        Unused by LPM (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), validated only.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    k : int, default 6
        Central neighbourhood size; the scales are ``k + 2, k, k - 2`` = {8, 6, 4} (Sec. 5.1).
    lambdas : (float, float), default (0.8, 0.5)
        Cost thresholds of the first and second iteration (Sec. 5.1).
    tau : float, default 0.2
        Motion-consistency threshold of Eq. (14) (Sec. 5.1).

    Returns
    -------
    keep : ndarray of shape (K,), bool

    Notes
    -----
    Coincident candidates: rows whose keypoints coincide in both images (SIFT's orientation copies of one
    correspondence, on distinct keypoint indices, or a row the matcher repeated) are one match here. The filter
    decides the distinct matches (each with the best score of its copies) and gives every copy the decision of
    its match, so a wrong correspondence cannot support itself through its own copies and a location counts once
    in the neighbourhoods. The authors' MATLAB demo (jiayi-ma/LPM, demo_LPM_v2.m and LPM_cosF.m) has no step for
    them: it drops the k-d tree's first answer as the query itself, so copies are neighbours of one another; it
    is silent, and counting them once is our choice. The result on inputs without coincident rows is unchanged.

    References
    ----------
    J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality preserving matching", IJCV 127(5), 2019.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(6) * 20.0, np.arange(6) * 20.0), -1).reshape(-1, 2)
    >>> y = g + 7.0
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = lpm_filter(g, y, np.c_[np.arange(36), np.arange(36)], image_size1=(400, 300),
    ...                   image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 35)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    k = check_positive(k, "k", integer=True)
    lam = [check_positive(v, "lambdas", allow_zero=True) for v in np.atleast_1d(lambdas)]
    if len(lam) != 2:
        raise ValueError(f"lambdas must hold two thresholds, got {lambdas!r}")
    merged = merge_coincident(ms)
    if merged is not None:  # coincident copies of a match are one match (see Notes)
        rows, group = merged
        keep = lpm_filter(kpts1, kpts2, ms.matches[rows], ms.scores[rows], image_size1=image_size1,
                          image_size2=image_size2, shapes1=shapes1, shapes2=shapes2,
                          k=k, lambdas=lambdas, tau=tau)
        return keep[group]
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    everyone = np.arange(n)
    keep = _lpm_cost(ms.x, ms.y, everyone, k, tau) <= lam[0]
    # Second iteration on the neighbourhoods of the first-pass inliers, when enough (demo code: k + 4).
    if keep.sum() >= k + 4:
        keep = _lpm_cost(ms.x, ms.y, np.flatnonzero(keep), k, tau) <= lam[1]
    return keep


def _glpm_pass(x, y, subset, candidates, k: int, lam: float) -> np.ndarray:
    """One GLPM pass over ``subset``: neighbourhood cost 2 (K - n_i) against guide ``candidates``."""
    if len(subset) == 0 or len(candidates) < 2:
        return np.zeros(len(subset), bool)
    nx = knn_without_self(x, candidates, k, queries=subset)
    ny = knn_without_self(y, candidates, k, queries=subset)
    kk = nx.shape[1]
    _, dup = _common_neighbours(nx, ny)
    n_common = dup.sum(1)
    # Eq. (4): every neighbour missing from the other image's neighbourhood costs 1, in both images.
    return 2 * (kk - n_common) <= lam * kk / k


# (K, lambda) of the four passes of GLPM: two on the small set, two guided ones on the whole set (Sec. IV).
GLPM_SCHEDULE = ((4, 6.0), (4, 4.0), (6, 6.0), (5, 4.0))


def glpm_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    ratio: float = 1.0 / 1.5,
    schedule=GLPM_SCHEDULE,
) -> np.ndarray:
    """Guided Locality Preserving Matching.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better. The guide is built from the matches with ``scores <= ratio``;
        ``None`` (all equal) puts every match in it.
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), validated only.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    ratio : float, default 1/1.5
        Strict NNR threshold of the small putative set (ratio 1.5 between second and first distance in
        Sec. IV of the paper; the large set is the whole input).
    schedule : sequence of four (K, lambda)
        Neighbourhood size and cost threshold (on ``2 (K - n_i)``) of the two small-set passes and of the
        two guided passes, default ((4, 6), (4, 4), (6, 6), (5, 4)) as published.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    Notes
    -----
    Coincident candidates: rows whose keypoints coincide in both images (SIFT's orientation copies of one
    correspondence, on distinct keypoint indices, or a row the matcher repeated) are one match here. The filter
    decides the distinct matches (each with the best score of its copies) and gives every copy the decision of
    its match, so a wrong correspondence cannot support itself through its own copies and a location counts once
    in the neighbourhoods and in the guide. The authors' demo (jiayi-ma/GLPM, demo.m) has no step for them
    (silent: our choice). It hands the small-set inliers to the whole set by their image-1 coordinates, so every
    candidate at such an image-1 location joins the guide; here the guide is the small-set inliers themselves
    (not changed: it would change the result on inputs without copies). The result on inputs without coincident
    rows is unchanged.

    References
    ----------
    J. Ma, J. Jiang, H. Zhou, J. Zhao, X. Guo, "Guided locality preserving feature matching for remote
    sensing image registration", IEEE TGRS 56(8), 2018.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(6) * 20.0, np.arange(6) * 20.0), -1).reshape(-1, 2)
    >>> y = g + 7.0
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = glpm_filter(g, y, np.c_[np.arange(36), np.arange(36)], None, image_size1=(400, 300),
    ...                    image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 35)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    ratio = check_positive(ratio, "ratio")
    sched = [(check_positive(kk, "schedule", integer=True), check_positive(lam, "schedule", allow_zero=True))
             for kk, lam in schedule]
    if len(sched) != 4:
        raise ValueError(f"schedule must hold four (K, lambda) pairs, got {len(sched)}")
    merged = merge_coincident(ms)
    if merged is not None:  # coincident copies of a match are one match (see Notes)
        rows, group = merged
        keep = glpm_filter(kpts1, kpts2, ms.matches[rows], ms.scores[rows], image_size1=image_size1,
                           image_size2=image_size2, shapes1=shapes1, shapes2=shapes2,
                           ratio=ratio, schedule=schedule)
        return keep[group]
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    x, y = ms.x, ms.y
    small = np.flatnonzero(ms.scores <= ratio)
    if len(small) < sched[0][0] + 1:
        small = np.arange(n)  # too few confident matches to guide anything: start from all of them
    # Passes 1-2: the small set filters itself (the second pass uses the first pass's survivors as guide).
    guide = small[_glpm_pass(x, y, small, small, *sched[0])]
    guide = small[_glpm_pass(x, y, small, guide, *sched[1])] if len(guide) > 1 else guide
    # Passes 3-4: the whole set, guided by the small-set inliers, then by the first guided inliers.
    everyone = np.arange(n)
    keep = _glpm_pass(x, y, everyone, guide, *sched[2])
    keep = _glpm_pass(x, y, everyone, np.flatnonzero(keep), *sched[3])
    return keep
