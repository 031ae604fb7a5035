"""RFM-SCAN: Robust Feature Matching using SpatialClustering with heavy outliers (Jiang et al., TIP 2020).

Each match becomes a point of a motion space made of its two keypoints and its motion vector,
``[x, y, y - x]``, every coordinate min-max normalised to [0, 1] over the matches (Sec. III-A). The distance
between two matches adds the keypoint distances in both images and the motion-vector distance, the latter
amplified when the matches are close (Eq. (3)):

    d_ij = |x_i - x_j| + |y_i - y_j| + (1 + gamma * exp(-min(|x_i - x_j|, |y_i - y_j|))) * |v_i - v_j|.

Inliers form dense clusters, outliers are sparse: DBSCAN (Ester et al., KDD 1996) keeps the matches that are
core points (at least ``MinPts`` matches, itself included, within ``eps``) or lie within ``eps`` of a core
point. The parameters are adaptive (Sec. III-B): ``MinPts = clip(round(pct * N), 3, 30)`` and, with
``L_i`` the distance of match ``i`` to its ``MinPts``-th nearest match, ``eps = min L + mu * (max L - min
L)``. A second round (Sec. III-C) recomputes ``L`` and ``eps`` (``mu = 0.08``) with the matches not
clustered by the first round pushed away (their distances multiplied by 100), and clusters again.

As in the authors' demo, a few uniform random matches (``min(0.05 N, 20)``, seeded) are added before
clustering so that the adaptive ``eps`` stays meaningful when the input is almost outlier-free; they are
never returned. Only the kept/rejected mask is needed, so DBSCAN's cluster labels are not built: a match is
kept when it is a core point or is within ``eps`` of one, which is exactly the set DBSCAN assigns to some
cluster. The O(K^2) distances are computed in row blocks, never stored whole.
"""

from __future__ import annotations

import numpy as np

from ._common import check_positive, prepare

__all__ = ["rfm_scan_filter"]


class _MotionDistance:
    """Row blocks of the RFM-SCAN distance matrix (Eq. (3)) between normalised motion-space points.

    float32 is plenty for distances in [0, 20] and halves the memory traffic of the O(K^2) passes.
    """

    def __init__(self, feats: np.ndarray, gamma: float, block_cells: float = 2e6) -> None:
        f = feats.astype(np.float32)
        self.cols = [f[:, j] for j in range(6)]
        self.gamma = np.float32(gamma)
        self.n = len(feats)
        self.block = max(1, int(block_cells // max(self.n, 1)))

    def rows(self, idx: np.ndarray) -> np.ndarray:
        def pair_dist(a: int) -> np.ndarray:
            dx = self.cols[a][idx, None] - self.cols[a][None, :]
            dy = self.cols[a + 1][idx, None] - self.cols[a + 1][None, :]
            return np.sqrt(dx * dx + dy * dy)

        d1, d2, dv = pair_dist(0), pair_dist(2), pair_dist(4)
        return d1 + d2 + (1.0 + self.gamma * np.exp(-np.minimum(d1, d2))) * dv

    def blocks(self, idx: np.ndarray):
        for b in range(0, len(idx), self.block):
            sel = idx[b : b + self.block]
            yield sel, self.rows(sel)


def _clustered(dist: _MotionDistance, min_pts: int, mu: float, col_scale: np.ndarray | None) -> np.ndarray:
    """Matches that DBSCAN puts in a cluster, with the adaptive eps of Sec. III-B.

    ``col_scale`` multiplies the distances *to* each match (second round); ``None`` keeps the matrix
    symmetric, and then a non-core match can only be reached from a core match among its ``min_pts``
    nearest (else it would be core itself), so no second pass over the core rows is needed.
    """
    n = dist.n
    kth = np.empty(n, np.float32)
    symmetric = col_scale is None
    if symmetric:
        near = np.empty((n, min_pts), np.int64)
        near_d = np.empty((n, min_pts), np.float32)
    for sel, d in dist.blocks(np.arange(n)):
        if symmetric:
            nb = np.argpartition(d, min_pts - 1, axis=1)[:, :min_pts]
            near[sel], near_d[sel] = nb, np.take_along_axis(d, nb, axis=1)
            kth[sel] = near_d[sel].max(1)
        else:
            d *= col_scale[None, :]
            kth[sel] = np.partition(d, min_pts - 1, axis=1)[:, min_pts - 1]
    lo, hi = kth.min(), kth.max()
    eps = lo + np.float32(mu) * (hi - lo)
    core = kth <= eps
    if col_scale is None:
        return core | (core[near] & (near_d <= eps)).any(1)
    reached = core.copy()
    for _, d in dist.blocks(np.flatnonzero(core)):
        d *= col_scale[None, :]
        reached |= (d <= eps).any(axis=0)
    return reached


def rfm_scan_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    gamma: float = 10.0,
    pct: float = 0.05,
    min_pts_bounds=(3, 30),
    mu=(0.1, 0.08),
    add_noise: bool = True,
    rng=0,
) -> np.ndarray:
    """RFM-SCAN: density clustering of the matches in a normalised motion space.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        Unused by RFM-SCAN (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height); the extent of the added random matches.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    gamma : float, default 10
        Amplification of the motion distance for nearby matches, Eq. (3) (Sec. IV-A).
    pct : float, default 0.05
        ``MinPts`` as a fraction of the matches (Sec. IV-A: 0.02-0.05).
    min_pts_bounds : (int, int), default (3, 30)
        Range of ``MinPts``.
    mu : (float, float), default (0.1, 0.08)
        ``eps`` rates of the two rounds (Sec. III-B, IV-A).
    add_noise : bool, default True
        Add ``round(min(0.05 K, 20))`` uniform random matches before clustering (authors' demo).
    rng : None, int or numpy.random.Generator, default 0
        Seed of the added matches; the fixed default makes the result deterministic.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    X. Jiang, J. Ma, J. Jiang, X. Guo, "Robust feature matching using spatial clustering with heavy
    outliers", IEEE TIP 29, 2020.
    M. Ester, H.-P. Kriegel, J. Sander, X. Xu, "A density-based algorithm for discovering clusters in large
    spatial databases with noise", KDD 1996.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = rfm_scan_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                        image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    gamma = check_positive(gamma, "gamma", allow_zero=True)
    pct = check_positive(pct, "pct", allow_zero=True)
    lo_pts, hi_pts = (check_positive(v, "min_pts_bounds", integer=True) for v in min_pts_bounds)
    if lo_pts > hi_pts:
        raise ValueError(f"min_pts_bounds must be increasing, got {min_pts_bounds!r}")
    mu = [check_positive(v, "mu", allow_zero=True) for v in np.atleast_1d(mu)]
    if len(mu) != 2:
        raise ValueError(f"mu must hold two rates, got {mu!r}")
    rng = np.random.default_rng(rng)
    n = len(ms)
    if n == 0:
        return np.zeros(0, bool)
    x, y = ms.x, ms.y
    if add_noise:
        n_noise = int(round(min(0.05 * n, 20)))
        hi1, hi2 = np.asarray(ms.size1) - 0.5, np.asarray(ms.size2) - 0.5
        x = np.vstack([x, rng.uniform(-0.5, hi1, size=(n_noise, 2))])
        y = np.vstack([y, rng.uniform(-0.5, hi2, size=(n_noise, 2))])
    n_all = len(x)
    feats = np.hstack([x, y, y - x])
    span = feats.max(0) - feats.min(0)
    feats = (feats - feats.min(0)) / np.where(span > 0, span, 1.0)  # per-coordinate min-max to [0, 1]
    min_pts = int(min(max(round(n_all * pct), lo_pts), hi_pts))
    if n_all < min_pts:
        return np.zeros(n, bool)
    dist = _MotionDistance(feats, gamma)
    first = _clustered(dist, min_pts, mu[0], None)
    # Second round: only first-round clustered real matches stay near (Sec. III-C).
    ci = np.zeros(n_all, bool)
    ci[:n] = first[:n]
    return _clustered(dist, min_pts, mu[1], np.where(ci, 1.0, 100.0).astype(np.float32))[:n]
