"""AdaLAM: Adaptive Locally-Affine Matching (Cavalli et al., ECCV 2020), :func:`adalam_filter`.

Seeds (Sec. 3.1: the best score within ``R1 = sqrt(w1 h1 / (pi area_ratio))``), their neighbourhoods
(Sec. 3.2) and a local affine RANSAC with a-contrario confidence per neighbourhood (Sec. 3.3); the output is
the union of the accepted inliers. Where the paper is silent, the defaults follow kornia's port of the
authors' code (Sec. 5.3's "original code"); the agreement: ``docs/filters.md``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..._numerics.fixedmath import atan2
from ._kernels import beaten_by_neighbours, best_confident_maps
from .._common import MatchSet, match_filter

__all__ = ["adalam_filter"]


def _couples(n: int) -> np.ndarray:
    """The ``n`` sample couples ``(j, i)`` of positions in a score-sorted neighbourhood, best first.

    All ``i < j <= m`` (``m (m + 1) / 2 <= n``), then ``(r, 0 .. r - 1)`` for the ``r`` left, as the
    reference draws them; used modulo the neighbourhood size."""
    m = int(np.sqrt(2 * n + 0.25) - 0.5)
    r = n - m * (m + 1) // 2
    js = [j for j in range(1, m + 1) for _ in range(j)] + [r] * r
    is_ = [i for j in range(1, m + 1) for i in range(j)] + list(range(r))
    return np.array([js, is_], dtype=np.int64).T.reshape(-1, 2)


def _orientation_scale(A: np.ndarray):
    """Rotation (degrees, polar decomposition, _fixedmath's atan2) and ``sqrt(|det A|)`` of each (2, 2) ``A``."""
    return (np.degrees(atan2(A[:, 1, 0] - A[:, 0, 1], A[:, 0, 0] + A[:, 1, 1])),
            np.sqrt(np.abs(A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0])))


def _relative_similarity(A1: np.ndarray, A2: np.ndarray):
    """Rotation (degrees) and scale of ``L = A2 A1^-1`` per match; NaN where ``A1`` is singular."""
    det1 = A1[:, 0, 0] * A1[:, 1, 1] - A1[:, 0, 1] * A1[:, 1, 0]
    ok = np.abs(det1) > 1e-12
    inv1 = np.stack([np.stack([A1[:, 1, 1], -A1[:, 0, 1]], -1), np.stack([-A1[:, 1, 0], A1[:, 0, 0]], -1)], 1)
    angle, scale = _orientation_scale(A2 @ (inv1 / np.where(ok, det1, 1.0)[:, None, None]))
    angle[~ok] = np.nan
    scale[~ok | (scale <= 0)] = np.nan
    return angle, scale


def _keypoint_similarity(A1: np.ndarray, A2: np.ndarray):
    """Orientation difference (degrees) and scale ratio (:func:`_orientation_scale`); NaN if singular."""
    (o1, s1), (o2, s2) = _orientation_scale(A1), _orientation_scale(A2)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where((s1 > 1e-12) & (s2 > 0), s2 / s1, np.nan)
    return np.where(np.isfinite(scale), o2 - o1, np.nan), scale


def _residuals(A: np.ndarray, U: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``|A_bt u_bm - v_bm|`` of shape (B, T, M) for maps ``A`` (B, T, 2, 2) and points (B, M, 2)."""
    u0, u1 = U[:, None, :, 0], U[:, None, :, 1]
    a = A[..., None]  # (B, T, 2, 2, 1)
    rx = a[:, :, 0, 0] * u0 + a[:, :, 0, 1] * u1 - V[:, None, :, 0]
    ry = a[:, :, 1, 0] * u0 + a[:, :, 1, 1] * u1 - V[:, None, :, 1]
    return np.sqrt(rx * rx + ry * ry)


def _confident_inliers(A, usable, distinct, Ub, Vb, nb, min_conf: float):
    """Confidence-based inlier count of the best map of each neighbourhood (Sec. 3.3), as the reference counts.

    A member is good when ``r^2 * min_conf`` is at most the inlier rate so far along the sorted residuals.
    Arguments and returns: see :func:`._kernels.best_confident_maps`."""
    return best_confident_maps(np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(Ub, dtype=np.float64),
                              np.ascontiguousarray(Vb, dtype=np.float64), np.ascontiguousarray(nb, dtype=np.int64),
                              np.ascontiguousarray(usable, dtype=np.bool_),
                              np.ascontiguousarray(distinct, dtype=np.bool_), float(min_conf))


@match_filter(label="AdaLAM", nnr=("seed_threshold",), shapes="both", integer=("ransac_iters",),
              positive=("area_ratio", "search_expansion", "min_confidence", "detected_scale_rate_threshold"),
              non_negative=("min_inliers",))
def adalam_filter(
    ms: MatchSet,
    *,
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
    similarity: str = "keypoints",
    rng=0,
) -> np.ndarray:
    """Adaptive Locally-Affine Matching.

    %(parameters)s
    scores : ndarray of shape (K,) or None
        NNR-like scores, lower is better (seeds, sampling order); ``None``: all equal.
    image_size1, image_size2 : (int, int)
        Image sizes (width, height); they set the radii ``R1`` and ``R2``.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Keypoint shapes, for the orientation and scale checks. Both or neither.
    area_ratio, search_expansion : float, default 100 and 4
        Image area over seed-disc area (Sec. 4); neighbourhood over seed radius (lambda, Sec. 3.2).
    ransac_iters, min_inliers : int, default 128 and 6
        Hypotheses per neighbourhood; minimum neighbourhood size and confident inlier count (Sec. 4).
    min_confidence : float, default 200
        Confidence threshold of the adaptive inlier selection (t_tau, Sec. 3.3).
    orientation_threshold, scale_rate_threshold : float or None, default 30 and 1.5
        Degrees and relative-scale factor of the neighbourhood checks (Sec. 3.2); ``None`` disables one.
    detected_scale_rate_threshold : float, default 5
        Maps with a singular value outside [1/5, 5] are no exact fits, and refits become the identity.
    seed_threshold : float, default 0.8
        Seeds need ``score < seed_threshold``, an NNR ratio read on the scale of the scores.
    refit : bool, default True
        Refit the best hypothesis of each neighbourhood on its inliers (Sec. 3.3).
    similarity : {"keypoints", "map"}, default "keypoints"
        Orientation and scale per keypoint shape, as the reference, or from the map ``A2 A1^-1``.
    rng : None, int or numpy.random.Generator, default 0
        Seed of the order of equal scores inside a neighbourhood.

    Returns
    -------
    %(keep)s

    References
    ----------
    L. Cavalli et al., "Handcrafted outlier detection revisited", ECCV 2020.
    """
    # ``seed_threshold`` comes on the scores' scale (match_filter).
    rng = np.random.default_rng(rng)
    if similarity not in ("keypoints", "map"):
        raise ValueError(f"similarity must be 'keypoints' or 'map', got {similarity!r}")
    n = len(ms)
    keep = np.zeros(n, bool)
    if n < 3:
        return keep
    R1 = np.sqrt(ms.size1[0] * ms.size1[1] / (np.pi * area_ratio))
    r1 = search_expansion * R1  # the neighbourhood radii (Sec. 3.2)
    r2 = search_expansion * np.sqrt(ms.size2[0] * ms.size2[1] / (np.pi * area_ratio))

    # 1. Seeds: no strictly better score within R1 in image 1. ``rank`` orders the members of each
    # neighbourhood (step 3), equal scores in a seeded random order rather than by index.
    rank = np.empty(n, np.int64)
    rank[np.lexsort((rng.permutation(n), ms.scores))] = np.arange(n)
    locs = _Locations(ms.x)
    seeds = _seeds(locs, ms.scores, R1, seed_threshold)
    if len(seeds) == 0:
        return keep

    # 2. Neighbourhoods, with the orientation and scale agreement of the seed when shapes are known.
    hood = _neighbourhoods(ms, locs, seeds, rank, r1, r2, min_inliers, orientation_threshold,
                           scale_rate_threshold, similarity)
    if hood is None:
        return keep
    seeds, sid, mid, sizes, pos = hood
    u = (ms.x[mid] - ms.x[seeds[sid]]) / r1
    v = (ms.y[mid] - ms.y[seeds[sid]]) / r2

    # 3. Local affine RANSACs, a block of seeds at a time to bound memory.
    couples = _couples(ransac_iters)
    m_max = int(sizes.max())
    U = np.zeros((len(seeds), m_max, 2))
    V = np.zeros((len(seeds), m_max, 2))
    U[sid, pos], V[sid, pos] = u, v
    present = np.zeros((len(seeds), m_max), bool)
    present[sid, pos] = True
    accepted = np.zeros((len(seeds), m_max), bool)
    block = max(1, int(2e6 // (ransac_iters * m_max)))
    for b0 in range(0, len(seeds), block):
        sl = slice(b0, b0 + block)
        accepted[sl] = _local_ransac(U[sl], V[sl], present[sl], sizes[sl], couples, min_confidence, min_inliers,
                                     detected_scale_rate_threshold, refit)

    # 4. Union of the accepted inliers of every neighbourhood.
    keep[mid[accepted[sid, pos]]] = True
    return keep


class _Locations:
    """Distinct image-1 locations: ``tree`` over them, ``inv`` each match's, ``by_loc``/``starts`` the groups.

    Searched instead of the matches (fewer points); group ``l`` is ``by_loc[starts[l]:starts[l + 1]]``."""

    def __init__(self, x: np.ndarray):
        loc, inv = np.unique(x, axis=0, return_inverse=True)
        self.inv = inv.reshape(-1)
        self.tree = cKDTree(loc)
        self.by_loc = np.argsort(self.inv, kind="stable")
        self.starts = np.r_[0, np.cumsum(np.bincount(self.inv, minlength=len(loc)))]

    def members(self, lists) -> tuple[np.ndarray, np.ndarray]:
        """``(lid, mid)``: the list index and match index of every match at the locations of each list."""
        lens = np.fromiter((len(v) for v in lists), np.int64, len(lists))
        lid = np.repeat(np.arange(len(lists)), lens)
        ll = np.concatenate([np.asarray(v, np.int64) for v in lists]) if len(lists) else np.zeros(0, np.int64)
        cnt = self.starts[ll + 1] - self.starts[ll]
        first = np.repeat(self.starts[ll] - np.r_[0, np.cumsum(cnt)[:-1]], cnt)
        return np.repeat(lid, cnt), self.by_loc[first + np.arange(int(cnt.sum()))]


def _seeds(locs: _Locations, s, R1: float, seed_threshold: float) -> np.ndarray:
    """Matches passing ``seed_threshold`` with the best score within ``R1`` in image 1 (ties do not beat)."""
    pairs = locs.tree.query_pairs(np.nextafter(R1, 0.0), output_type="ndarray")  # distance < R1
    beaten = beaten_by_neighbours(np.ascontiguousarray(s, dtype=np.float64), locs.inv,
                                  np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2), len(locs.starts) - 1)
    return np.flatnonzero(~beaten & (s < seed_threshold))


def _neighbourhoods(ms, locs: _Locations, seeds, rank, r1: float, r2: float, min_inliers, orientation_threshold,
                    scale_rate_threshold, similarity: str = "keypoints"):
    """The neighbourhood of each seed with at least ``max(min_inliers, 3)`` members (Sec. 3.2), or None.

    Returns ``(seeds, sid, mid, sizes, pos)``: per member its seed's index, match index and rank (best first)."""
    x, y = ms.x, ms.y
    sid, mid = locs.members(locs.tree.query_ball_point(x[seeds], r1))
    ok = ((y[mid] - y[seeds[sid]]) ** 2).sum(1) < r2 ** 2
    if ms.A1 is not None:
        relative = _keypoint_similarity if similarity == "keypoints" else _relative_similarity
        angle, scale = relative(ms.A1, ms.A2)
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
    # Best scores first (PROSAC-like ordering of the reference implementation), the seed among them.
    order = np.lexsort((rank[mid], sid))
    sid, mid = sid[order], mid[order]
    sizes = np.bincount(sid, minlength=len(seeds))
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    pos = np.arange(len(sid)) - starts[sid]
    return seeds, sid, mid, sizes, pos


def _distinct_members(Ub, Vb, Pb) -> np.ndarray:
    """Members whose image-1 and image-2 locations both occur first in their neighbourhood, ``(B, M)``."""
    B, M = Pb.shape
    distinct = Pb.copy()
    b = np.repeat(np.arange(B), M)
    for P in (Ub, Vb):
        x, y = P[..., 0].ravel(), P[..., 1].ravel()
        order = np.lexsort((np.arange(B * M), y, x, b))
        same = (b[order][1:] == b[order][:-1]) & (x[order][1:] == x[order][:-1]) & (y[order][1:] == y[order][:-1])
        distinct.ravel()[order[1:][same]] = False
    return distinct


def _exact_support(raw, raw_distinct, valid, nb, min_inliers, min_conf: float):
    """``(recover, best, raw, conf)`` of neighbourhoods fitted exactly by a map, which the reference recovers.

    ``raw``, ``raw_distinct`` (B, T): residuals up to ``2^-12`` per map, of all and of distinct members."""
    cand = (raw >= min_inliers + 3) & valid
    support = np.where(cand, np.maximum(raw_distinct - 3, 0), 0)
    best = support.argmax(1)
    rows = np.arange(len(nb))
    conf = support[rows, best] / (np.maximum(nb, 1) * 2.0 ** -24)
    recover = (support[rows, best] >= min_inliers) & (conf >= min_conf)
    return recover, best, raw[rows, best], conf


def _scale_ok(A: np.ndarray, det_thr: float) -> np.ndarray:
    """Maps whose singular values lie in ``[1 / det_thr, det_thr]`` (NaN maps fail)."""
    sv = np.linalg.svd(np.nan_to_num(A, nan=0.0), compute_uv=False)
    return np.isfinite(A).all((-2, -1)) & (sv[..., 0] <= det_thr) & (sv[..., -1] >= 1.0 / det_thr)


def _select(A, usable, valid, distinct, Ub, Vb, Pb, nb, min_inliers, min_conf: float):
    """Inliers ``(inl (B, M), count, conf)`` of the best map per neighbourhood, confident or exact."""
    B, M = Pb.shape
    count_b, conf_b, order_b, near, near_distinct = _confident_inliers(A, usable, distinct, Ub, Vb, nb, min_conf)
    inl = np.zeros((B, M), bool)
    np.put_along_axis(inl, order_b, np.arange(M)[None, :] < count_b[:, None], 1)
    if (near >= min_inliers + 3).any():  # some map fits enough members exactly
        recover, t, raw, exact_conf = _exact_support(near, near_distinct, valid, nb, min_inliers, min_conf)
        with np.errstate(divide="ignore", invalid="ignore"):
            accepted = (conf_b >= min_conf) & (count_b * (1.0 - 1.0 / conf_b) >= min_inliers)
        recover &= ~accepted | (raw > count_b)
        if recover.any():
            r = np.flatnonzero(recover)
            res = np.where(usable[r, t[r], None], _residuals(A[r, t[r], None], Ub[r], Vb[r])[:, 0], 2.0)
            inl[r] = (res <= 2.0 ** -12) & Pb[r]
            count_b = np.where(recover, raw, count_b)
            conf_b = np.where(recover, exact_conf, conf_b)
    return inl, count_b, conf_b


def _local_ransac(Ub, Vb, Pb, nb, couples, min_conf: float, min_inliers, det_thr: float, refit: bool):
    """Local affine RANSAC of a block of neighbourhoods (Sec. 3.3); the accepted inliers, ``(B, M)`` bool.

    ``Ub``, ``Vb`` (B, M, 2): normalised offsets to the seed, best score first; ``Pb``: present; ``nb``: sizes."""
    B, M = Pb.shape
    rows = np.arange(B)[:, None]
    # Minimal fits through the seed (the origin) and a couple: v = A u, A = [v_i v_j][u_i u_j]^-1. Couples
    # index the sorted members modulo the group size; a degenerate couple (the seed, a repeated member,
    # collinear with the seed) gives no map, under the reference's relative rank test.
    ci, cj = couples[None, :, 0] % nb[:, None], couples[None, :, 1] % nb[:, None]  # (B, T)
    ui, uj, vi, vj = Ub[rows, ci], Ub[rows, cj], Vb[rows, ci], Vb[rows, cj]
    det = ui[..., 0] * uj[..., 1] - ui[..., 1] * uj[..., 0]
    usable = np.abs(det) > np.sqrt(np.finfo(np.float32).eps) * (ui ** 2 + uj ** 2).sum(-1)
    d = np.where(usable, det, 1.0)
    inv = np.stack([np.stack([uj[..., 1], -uj[..., 0]], -1), np.stack([-ui[..., 1], ui[..., 0]], -1)], -2)
    inv = inv / d[..., None, None]  # rows of [u_i u_j]^-1
    A = np.stack([vi, vj], -1) @ inv  # (B, T, 2, 2)
    distinct = _distinct_members(Ub, Vb, Pb)
    inl, count_b, conf_b = _select(A, usable, usable & _scale_ok(A, det_thr), distinct, Ub, Vb, Pb, nb,
                                   min_inliers, min_conf)
    if refit:
        # Least squares through the seed on the inliers; a map changing scale beyond ``det_thr`` is replaced
        # by the identity, as in the reference.
        w = inl.astype(np.float64)
        UtU = np.einsum("bm,bmi,bmj->bij", w, Ub, Ub)
        VtU = np.einsum("bm,bmi,bmj->bij", w, Vb, Ub)
        det_u = UtU[:, 0, 0] * UtU[:, 1, 1] - UtU[:, 0, 1] * UtU[:, 1, 0]
        fine = det_u > np.finfo(np.float32).eps * (UtU[:, 0, 0] + UtU[:, 1, 1]) ** 2
        A_ref = VtU @ np.linalg.inv(np.where(fine[:, None, None], UtU, np.eye(2)))
        scale_ok = fine & _scale_ok(A_ref, det_thr)
        A_ref[fine & ~scale_ok] = np.eye(2)
        inl, count_b, conf_b = _select(A_ref[:, None], fine[:, None], scale_ok[:, None], distinct, Ub, Vb, Pb,
                                       nb, min_inliers, min_conf)
    with np.errstate(divide="ignore", invalid="ignore"):
        strong = count_b * (1.0 - 1.0 / conf_b)
    good = (conf_b >= min_conf) & (strong >= min_inliers)
    return inl & good[:, None] & Pb
