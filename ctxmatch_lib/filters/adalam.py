"""AdaLAM: Adaptive Locally-Affine Matching (Cavalli et al., ECCV 2020).

1. Seeds (Sec. 3.1): a match is a seed when its score passes the ratio test and is the best (lowest) among
   all matches whose image-1 keypoint lies within ``R1 = sqrt(w1 h1 / (pi * area_ratio))`` of its own
   (score ties broken in a seeded random order).
2. Neighbourhoods (Sec. 3.2): a match joins the neighbourhood of a seed when its keypoints are within
   ``search_expansion * R1`` and ``search_expansion * R2`` of the seed's in both images and, when the
   keypoint shapes are known, its relative orientation and scale agree with the seed's (within
   ``orientation_threshold`` degrees and a factor ``scale_rate_threshold``).
3. Local affine verification (Sec. 3.3): in each neighbourhood, coordinates are taken relative to the seed
   and divided by the neighbourhood radius; ``ransac_iters`` minimal hypotheses (two matches besides the
   seed, best-scored couples first, as PROSAC) give affine maps ``v = A u``. The inlier threshold of a
   hypothesis is adaptive: the largest residual ``r_k`` (k-th smallest) whose a-contrario confidence
   ``(k / n) / r_k^2`` (inlier rate over the rate expected of uniform outliers in the unit disc) reaches
   ``min_confidence``. The best hypothesis is refitted on its inliers by least squares (affine maps
   scaling by more than ``detected_scale_rate_threshold`` are rejected), and its inliers are accepted when
   the confidence passes and ``count * (1 - 1 / confidence) >= min_inliers``.
4. The output is the union of the accepted inliers of all neighbourhoods.

Orientation and scale come from the affine shapes ``A`` (patch ``{kpt + A u : |u| <= 1}``): the local map
of a match is ``L = A2 A1^-1``, its rotation the angle of the closest rotation (polar decomposition), its
scale ``sqrt(|det L|)``. Without shapes the orientation/scale checks are skipped (the paper's fallback).
No torch backend is offered here.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ._common import check_positive, prepare

__all__ = ["adalam_filter"]


def _couples(n: int) -> np.ndarray:
    """The first ``n`` index couples (i < j), ordered by j then i: best-ranked samples first."""
    out, j = [], 1
    while len(out) < n:
        out.extend((i, j) for i in range(j))
        j += 1
    return np.array(out[:n], dtype=np.int64).reshape(-1, 2)


def _relative_similarity(A1: np.ndarray, A2: np.ndarray):
    """Rotation (degrees) and scale of ``L = A2 A1^-1`` per match; NaN where ``A1`` is singular."""
    det1 = A1[:, 0, 0] * A1[:, 1, 1] - A1[:, 0, 1] * A1[:, 1, 0]
    ok = np.abs(det1) > 1e-12
    inv1 = np.stack([np.stack([A1[:, 1, 1], -A1[:, 0, 1]], -1), np.stack([-A1[:, 1, 0], A1[:, 0, 0]], -1)], 1)
    inv1 = inv1 / np.where(ok, det1, 1.0)[:, None, None]
    L = A2 @ inv1
    angle = np.degrees(np.arctan2(L[:, 1, 0] - L[:, 0, 1], L[:, 0, 0] + L[:, 1, 1]))
    scale = np.sqrt(np.abs(L[:, 0, 0] * L[:, 1, 1] - L[:, 0, 1] * L[:, 1, 0]))
    angle[~ok] = np.nan
    scale[~ok | (scale <= 0)] = np.nan
    return angle, scale


def _residuals(A: np.ndarray, U: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``|A_bt u_bm - v_bm|`` of shape (B, T, M) for maps ``A`` (B, T, 2, 2) and points (B, M, 2)."""
    u0, u1 = U[:, None, :, 0], U[:, None, :, 1]
    a = A[..., None]  # (B, T, 2, 2, 1)
    rx = a[:, :, 0, 0] * u0 + a[:, :, 0, 1] * u1 - V[:, None, :, 0]
    ry = a[:, :, 1, 0] * u0 + a[:, :, 1, 1] * u1 - V[:, None, :, 1]
    return np.sqrt(rx * rx + ry * ry)


def _adaptive_inliers(res: np.ndarray, n: np.ndarray, min_conf: float):
    """Adaptive threshold of every residual row (Sec. 3.3).

    ``res`` (..., m) holds residuals padded with ``inf``; ``n`` (...,) the real sizes. Returns the inlier
    count, the threshold residual and the confidence of the chosen threshold.
    """
    r = np.sort(res, axis=-1)
    r2 = r**2
    k = np.arange(1, r.shape[-1] + 1)
    rate = k / np.maximum(n, 1)[..., None]
    good = np.isfinite(r) & ((r2 * min_conf <= rate) | (r2 <= 1e-8))
    count = np.where(good, k, 0).max(-1)
    idx = np.maximum(count - 1, 0)[..., None]
    thr = np.take_along_axis(r, idx, -1)[..., 0]
    thr = np.where(count > 0, thr, -np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        conf = count / (np.maximum(n, 1) * thr**2)
    conf = np.where(count > 0, conf, 0.0)
    return count, thr, conf


def adalam_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    area_ratio: float = 100.0,
    search_expansion: float = 4.0,
    ransac_iters: int = 128,
    min_inliers: int = 6,
    min_confidence: float = 200.0,
    orientation_threshold: float = 30.0,
    scale_rate_threshold: float = 1.5,
    detected_scale_rate_threshold: float = 5.0,
    seed_threshold: float = 0.8,
    refit: bool = True,
    rng=0,
) -> np.ndarray:
    """Adaptive Locally-Affine Matching.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better: seeds must pass ``seed_threshold`` and beat their neighbours,
        samples are drawn best first. ``None`` means all equal (ties broken in a seeded random order).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), which set the radii ``R1`` and ``R2``.
    shapes1, shapes2 : ndarray of shape (N1, 2, 2) and (N2, 2, 2), optional
        Affine shapes of the keypoints; give relative orientation and scale. Both or neither.
    area_ratio : float, default 100
        Image area over seed-disc area (Sec. 4, default configuration).
    search_expansion : float, default 4
        Neighbourhood radius over seed radius (lambda, Sec. 3.2).
    ransac_iters : int, default 128
        Hypotheses per neighbourhood (Sec. 4).
    min_inliers : int, default 6
        Minimum neighbourhood size and minimum confident inlier count (Sec. 4).
    min_confidence : float, default 200
        Confidence threshold of the adaptive inlier selection (t_tau, Sec. 3.3 and 4).
    orientation_threshold : float, default 30
        Degrees (Sec. 3.2); ``None`` disables the orientation check.
    scale_rate_threshold : float, default 1.5
        Relative-scale factor (Sec. 3.2); ``None`` disables the scale check.
    detected_scale_rate_threshold : float, default 5
        Refitted affinities whose singular values leave [1/5, 5] are rejected.
    seed_threshold : float, default 0.8
        Seeds must have ``score < seed_threshold`` (ratio test of the reference implementation).
    refit : bool, default True
        Refit the best hypothesis of each neighbourhood on its inliers (Sec. 3.3).
    rng : None, int or numpy.random.Generator, default 0
        Seed of the random order that breaks score ties (all scores tie when ``scores`` is None); the
        fixed default makes the result deterministic.

    Returns
    -------
    keep : ndarray of shape (K,), bool
        With no valid neighbourhood (e.g. fewer than ``min_inliers`` matches) nothing is kept.

    References
    ----------
    L. Cavalli, V. Larsson, M. R. Oswald, T. Sattler, M. Pollefeys, "Handcrafted outlier detection
    revisited", ECCV 2020.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = adalam_filter(g, y, np.c_[np.arange(64), np.arange(64)], None, image_size1=(400, 300),
    ...                      image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    area_ratio = check_positive(area_ratio, "area_ratio")
    lam = check_positive(search_expansion, "search_expansion")
    iters = check_positive(ransac_iters, "ransac_iters", integer=True)
    min_inliers = check_positive(min_inliers, "min_inliers", allow_zero=True)
    min_conf = check_positive(min_confidence, "min_confidence")
    det_thr = check_positive(detected_scale_rate_threshold, "detected_scale_rate_threshold")
    seed_threshold = check_positive(seed_threshold, "seed_threshold")
    rng = np.random.default_rng(rng)
    if (shapes1 is None) != (shapes2 is None):
        raise ValueError("shapes1 and shapes2 must be given together")
    n = len(ms)
    keep = np.zeros(n, bool)
    if n < 3:
        return keep
    R1 = np.sqrt(ms.size1[0] * ms.size1[1] / (np.pi * area_ratio))
    R2 = np.sqrt(ms.size2[0] * ms.size2[1] / (np.pi * area_ratio))

    # 1. Seeds: best score within R1 in image 1. Ties are broken in a random (seeded) order: breaking
    # them by index would let one match suppress a whole chain of equal-scored matches on a regular layout.
    rank = np.empty(n, np.int64)
    rank[np.lexsort((rng.permutation(n), ms.scores))] = np.arange(n)
    tree1 = cKDTree(ms.x)
    seeds = _seeds(tree1, rank, ms.scores, R1, seed_threshold)
    if len(seeds) == 0:
        return keep

    # 2. Neighbourhoods, with the orientation and scale agreement of the seed when shapes are known.
    hood = _neighbourhoods(ms, tree1, seeds, rank, lam * R1, lam * R2, min_inliers, orientation_threshold,
                           scale_rate_threshold)
    if hood is None:
        return keep
    seeds, sid, mid, sizes, pos = hood
    u = (ms.x[mid] - ms.x[seeds[sid]]) / (lam * R1)
    v = (ms.y[mid] - ms.y[seeds[sid]]) / (lam * R2)

    # 3. Local affine RANSACs, a block of seeds at a time to bound memory.
    couples = _couples(iters)
    m_max = max(int(sizes.max()), int(couples.max()) + 1)  # room for every couple index
    U = np.zeros((len(seeds), m_max, 2))
    V = np.zeros((len(seeds), m_max, 2))
    U[sid, pos], V[sid, pos] = u, v
    present = np.zeros((len(seeds), m_max), bool)
    present[sid, pos] = True
    accepted = np.zeros((len(seeds), m_max), bool)
    block = max(1, int(2e6 // (iters * m_max)))
    for b0 in range(0, len(seeds), block):
        sl = slice(b0, b0 + block)
        accepted[sl] = _local_ransac(U[sl], V[sl], present[sl], sizes[sl], couples, min_conf, min_inliers,
                                     det_thr, refit)

    # 4. Union of the accepted inliers of every neighbourhood.
    keep[mid[accepted[sid, pos]]] = True
    return keep


def _seeds(tree1, rank, s, R1: float, seed_threshold: float) -> np.ndarray:
    """Matches whose score beats every other within ``R1`` in image 1 and passes ``seed_threshold``."""
    n = len(rank)
    pairs = tree1.query_pairs(R1, output_type="ndarray")
    beaten = np.zeros(n, bool)
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        beaten[np.where(rank[a] > rank[b], a, b)] = True
    return np.flatnonzero(~beaten & (s < seed_threshold))


def _neighbourhoods(ms, tree1, seeds, rank, r1: float, r2: float, min_inliers, orientation_threshold,
                    scale_rate_threshold):
    """The matches of each seed's neighbourhood (Sec. 3.2): within ``r1`` of the seed in image 1 and ``r2``
    in image 2, agreeing in orientation and scale when shapes are known; seeds with fewer than
    ``max(min_inliers, 3)`` are dropped.

    Returns ``None`` when no seed is left, else ``(seeds, sid, mid, sizes, pos)``: for each member, its
    seed's index in ``seeds``, its match index and its position in its group (seed last, best first).
    """
    x, y = ms.x, ms.y
    lists = tree1.query_ball_point(x[seeds], r1)
    lens = np.fromiter((len(v) for v in lists), np.int64, len(lists))
    sid = np.repeat(np.arange(len(seeds)), lens)
    mid = np.concatenate([np.asarray(v, np.int64) for v in lists])
    ok = ((y[mid] - y[seeds[sid]]) ** 2).sum(1) < r2 ** 2
    if ms.A1 is not None:
        angle, scale = _relative_similarity(ms.A1, ms.A2)
        if orientation_threshold is not None:
            d = np.abs((angle[mid] - angle[seeds[sid]] + 180.0) % 360.0 - 180.0)
            ok &= ~(d >= orientation_threshold)  # NaN (unknown) passes
        if scale_rate_threshold is not None:
            rate = scale[mid] / scale[seeds[sid]]
            ok &= ~((rate >= scale_rate_threshold) | (rate <= 1.0 / scale_rate_threshold))
    sid, mid = sid[ok], mid[ok]
    sizes = np.bincount(sid, minlength=len(seeds))
    valid = sizes >= max(min_inliers, 3)
    sid_map = np.cumsum(valid) - 1
    take = valid[sid]
    sid, mid = sid_map[sid[take]], mid[take]
    seeds = seeds[valid]
    if len(seeds) == 0:
        return None
    # Seed last in its group so that the sampled couples never contain it (it is the local origin),
    # then best scores first (PROSAC-like ordering of the reference implementation).
    order = np.lexsort((rank[mid], mid == seeds[sid], sid))
    sid, mid = sid[order], mid[order]
    sizes = np.bincount(sid, minlength=len(seeds))
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    pos = np.arange(len(sid)) - starts[sid]
    return seeds, sid, mid, sizes, pos


def _local_ransac(Ub, Vb, Pb, nb, couples, min_conf: float, min_inliers, det_thr: float, refit: bool):
    """Local affine RANSAC of a block of neighbourhoods (Sec. 3.3); the accepted inliers, ``(B, M)`` bool.

    ``Ub``, ``Vb``: normalised offsets to the seed in each image, ``(B, M, 2)``; ``Pb`` marks the members
    present; ``nb`` the group sizes.
    """
    # Minimal fits: v = A u through the seed (origin) and a couple; A = [v_i v_j][u_i u_j]^-1.
    ui, uj = Ub[:, couples[:, 0]], Ub[:, couples[:, 1]]  # (B, T, 2)
    vi, vj = Vb[:, couples[:, 0]], Vb[:, couples[:, 1]]
    det = ui[..., 0] * uj[..., 1] - ui[..., 1] * uj[..., 0]
    usable = (np.abs(det) > 1e-9) & (couples[:, 1][None, :] < (nb - 1)[:, None])
    d = np.where(usable, det, 1.0)
    inv = np.stack([np.stack([uj[..., 1], -uj[..., 0]], -1), np.stack([-ui[..., 1], ui[..., 0]], -1)], -2)
    inv = inv / d[..., None, None]  # rows of [u_i u_j]^-1
    A = np.stack([vi, vj], -1) @ inv  # (B, T, 2, 2)
    res = _residuals(A, Ub, Vb)
    res = np.where(Pb[:, None, :] & usable[..., None], res, np.inf)
    count, thr, conf = _adaptive_inliers(res, nb[:, None], min_conf)
    best = count.argmax(1)
    rows = np.arange(len(nb))
    thr_best, conf_best = thr[rows, best], conf[rows, best]
    count_best = count[rows, best]
    inl = res[rows, best] <= thr_best[:, None]
    if refit:
        w = inl.astype(np.float64)
        UtU = np.einsum("bm,bmi,bmj->bij", w, Ub, Ub)
        VtU = np.einsum("bm,bmi,bmj->bij", w, Vb, Ub)
        det_u = np.linalg.det(UtU)
        fine = np.abs(det_u) > 1e-12
        A_ref = VtU @ np.linalg.inv(np.where(fine[:, None, None], UtU, np.eye(2)))
        sv = np.linalg.svd(A_ref, compute_uv=False)
        fine &= (sv[:, 0] <= det_thr) & (sv[:, 1] >= 1.0 / det_thr) & (count_best > 0)
        res_ref = _residuals(A_ref[:, None], Ub, Vb)[:, 0]
        res_ref = np.where(Pb & fine[:, None], res_ref, np.inf)
        count_best, thr_best, conf_best = _adaptive_inliers(res_ref, nb, min_conf)
        inl = res_ref <= thr_best[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        strong = count_best * (1.0 - 1.0 / conf_best)
    good = (conf_best >= min_conf) & (strong >= min_inliers)
    return inl & good[:, None] & Pb
