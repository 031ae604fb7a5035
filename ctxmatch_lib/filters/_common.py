"""Input handling shared by the peer spatial filters (private).

Every filter of this package starts with :func:`prepare`, which validates the common arguments with the
helpers of :mod:`ctxmatch_lib._validation` and returns the matched coordinates as two aligned ``(K, 2)``
arrays. Keypoints are (x, y) pixels with the origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_image_size, as_matches, as_points, as_scores

__all__ = ["MatchSet", "prepare", "knn_without_self", "zero_mean_unit_rms", "check_positive", "serial_blas",
           "coincident_groups", "merge_coincident"]


@dataclass(frozen=True)
class MatchSet:
    """The validated input of a filter, one row per match."""

    x: np.ndarray  # (K, 2) keypoint of each match in image 1, (x, y) pixels
    y: np.ndarray  # (K, 2) keypoint of each match in image 2
    matches: np.ndarray  # (K, 2) int64
    scores: np.ndarray  # (K,) lower is better, zeros when not given
    size1: tuple[int, int]  # (width, height)
    size2: tuple[int, int]
    A1: np.ndarray | None  # (K, 2, 2) affine shape of the image-1 keypoint of each match, or None
    A2: np.ndarray | None

    def __len__(self) -> int:
        return len(self.matches)


def _as_shapes(shapes, n: int, name: str) -> np.ndarray | None:
    if shapes is None:
        return None
    arr = np.asarray(shapes, dtype=np.float64)
    if arr.size == 0 and n == 0:
        return arr.reshape(0, 2, 2)
    if arr.shape != (n, 2, 2):
        raise ValueError(f"{name} must have shape ({n}, 2, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1=None, shapes2=None) -> MatchSet:
    """Validate the common filter arguments (``ValueError`` naming the argument on bad input)."""
    k1 = as_points(kpts1, "kpts1")
    k2 = as_points(kpts2, "kpts2")
    m = as_matches(matches, len(k1), len(k2))
    s = as_scores(scores, len(m))
    size1 = as_image_size(image_size1, "image_size1")
    size2 = as_image_size(image_size2, "image_size2")
    sh1 = _as_shapes(shapes1, len(k1), "shapes1")
    sh2 = _as_shapes(shapes2, len(k2), "shapes2")
    A1 = A2 = None
    if sh1 is not None and sh2 is not None:
        A1, A2 = sh1[m[:, 0]], sh2[m[:, 1]]
    return MatchSet(k1[m[:, 0]], k2[m[:, 1]], m, s, size1, size2, A1, A2)


def check_positive(value, name: str, *, integer: bool = False, allow_zero: bool = False):
    """Return ``value`` if it is a positive number (an int when ``integer``), else raise ``ValueError``."""
    ok = np.isscalar(value) and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if integer:
        ok = ok and float(value) == int(value)
    if not ok:
        kind = "integer" if integer else "number"
        sign = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be a {sign} {kind}, got {value!r}")
    return int(value) if integer else float(value)


def knn_without_self(points: np.ndarray, candidates: np.ndarray, k: int, queries: np.ndarray | None = None):
    """Indices (into ``points``) of the ``k`` nearest ``candidates`` of every query, the query excluded.

    ``candidates`` and ``queries`` (default: every point) are index arrays into ``points``; the answer has
    shape ``(len(queries), k')`` with ``k' = min(k, len(candidates) - 1)``, nearest first. A query that is
    itself a candidate is not its own neighbour.

    Ties (equal distances) are broken by the smaller index, not by the k-d tree's traversal order: that
    order is an implementation detail of the scipy build, and it changed the LPM and GLPM results between
    machines. Ties are frequent because many-to-many matches repeat a keypoint: the tree is built on the
    distinct locations, each standing for all the candidates there (smallest indices first), and each
    distinct query location is answered once; a row where two of the locations it needs lie at the same
    distance, or where more may lie at the k-th distance, takes every candidate within that distance and
    sorts them. Distances are recomputed here in one fixed arithmetic. Tested against a brute-force
    (distance, index) sort; on a 4040-candidate embedded pair it takes 2x the plain tree query.
    """
    queries = np.arange(len(points)) if queries is None else np.asarray(queries)
    cand = np.asarray(candidates)
    n = len(queries)
    kk = min(k, len(cand) - 1)
    if kk <= 0 or n == 0:
        return np.empty((n, 0), np.int64)
    pts = np.asarray(points, np.float64)
    # Work per distinct query location (duplicated queries share their neighbours, all but themselves):
    # the kk + 1 nearest candidates of each location by (distance, index), then each query drops itself
    # (or, when it is not among them, the last one).
    qlocs, qinv = np.unique(pts[queries], axis=0, return_inverse=True)
    qinv = qinv.reshape(-1)
    kq = kk + 1

    def ranked(rows, jj, valid):
        """Candidates ``cand[jj]`` of the query locations ``qlocs[rows]`` sorted by (distance, index), the
        entries not ``valid`` last (squared distance ``inf``), with their squared distances."""
        idx = cand[jj]
        d2 = ((pts[idx] - qlocs[rows][:, None, :]) ** 2).sum(-1)
        d2[~valid] = np.inf
        key = np.lexsort((idx, d2), axis=1)
        return np.take_along_axis(idx, key, axis=1), np.take_along_axis(d2, key, axis=1)

    # Distinct candidate locations; the members of each, by index (``order[start[u]:start[u] + cnt[u]]``).
    locs, inv, cnt = np.unique(pts[cand], axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    order = np.lexsort((cand, inv))
    start = np.r_[0, np.cumsum(cnt)[:-1]]
    # kq locations hold kq candidates at least; one more shows whether the last one needed is tied.
    nq = len(qlocs)
    mu = min(kq + 1, len(locs))
    _, L = cKDTree(locs).query(qlocs, k=mu)
    L = L.reshape(nq, mu)
    # Where the returned locations are strictly increasing in distance (recomputed here), the ranking by
    # (distance, index) is the members of each location in turn, by index: element t of a row lies in
    # location rank r[t].
    dl = ((locs[L] - qlocs[:, None, :]) ** 2).sum(-1)
    cum = np.cumsum(cnt[L], axis=1)
    t = np.arange(kq)
    r = (cum[:, :, None] <= t[None, None, :]).sum(axis=1)
    prev = np.where(r > 0, np.take_along_axis(cum, np.maximum(r - 1, 0), axis=1), 0)
    near_idx = cand[order[start[np.take_along_axis(L, r, axis=1)] + t[None, :] - prev]]
    # Exact unless two of the locations up to the one after the last needed tie (or the last needed one is
    # the last returned and more may lie at its distance): those rows take every candidate within the
    # distance of their kq-th neighbour and rank them by (distance, index).
    last = r[:, -1]
    tie = np.diff(dl, axis=1) <= dl[:, 1:] * 1e-12
    first_tie = np.where(tie.any(axis=1), tie.argmax(axis=1), mu) if mu > 1 else np.full(nq, mu)
    unsure = np.flatnonzero((first_tie <= last) | ((last == mu - 1) & (mu < len(locs))))
    if len(unsure):
        d_k = dl[unsure, last[unsure]]
        radius = np.sqrt(d_k) * (1 + 1e-9) + 1e-12
        balls = cKDTree(pts[cand]).query_ball_point(qlocs[unsure], radius)
        lens = np.array([len(b) for b in balls])
        width = max(int(lens.max()), kq)
        jj = np.zeros((len(unsure), width), np.int64)
        ok = np.arange(width)[None, :] < lens[:, None]
        jj[ok] = np.concatenate([np.asarray(b, np.int64) for b in balls])
        near_idx[unsure] = ranked(unsure, jj, ok)[0][:, :kq]
    lists = near_idx[qinv]
    is_self = lists == queries[:, None]
    drop = np.argsort(is_self, axis=1, kind="stable")
    return np.take_along_axis(lists, drop, axis=1)[:, :kk]


def zero_mean_unit_rms(p: np.ndarray) -> np.ndarray:
    """Zero mean and unit root-mean-square norm, the normalisation used by VFC and LLT (scale 1 if flat)."""
    c = p - p.mean(axis=0)
    scale = np.sqrt((c**2).sum() / max(len(p), 1))
    return c / scale if scale > 1e-12 else c


def serial_blas():
    """Context manager running BLAS single-threaded (a no-op without ``threadpoolctl``).

    The EM filters (VFC, LLT) multiply skinny ``(K, m)`` matrices hundreds of times; a multi-threaded
    BLAS spends more time waking and synchronising its threads than computing (5x slower on a loaded
    2-core machine), so those loops run serially. ``threadpoolctl`` comes with scikit-learn.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn depends on it
        return nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def coincident_groups(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group the matches whose keypoints coincide in both images (same coordinates, any keypoint index).

    SIFT keeps one keypoint per dominant orientation, so one correspondence can appear as several candidate
    rows on coincident keypoints, and a many-to-many matcher can repeat a row; a filter that counts such
    copies as distinct matches lets a wrong correspondence support itself through its own copies.

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoint of each match, (x, y) pixels, origin at the centre of the top-left
        pixel. Coincidence is exact equality of the coordinates.

    Returns
    -------
    first : ndarray of shape (G,) int64
        The first row of each group, increasing: ``x[first], y[first]`` are the distinct matches in input
        order.
    group : ndarray of shape (K,) int64
        The group of every row (``first[group[i]]`` is the first copy of row ``i``).
    """
    n = len(x)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    _, first, group = np.unique(np.c_[x, y], axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return first[order].astype(np.int64), rank[group]


def merge_coincident(ms: MatchSet) -> tuple[np.ndarray, np.ndarray] | None:
    """One row per group of coincident matches (see :func:`coincident_groups`), and the map back.

    Returns None when no two matches coincide, so a filter's result on an input without copies is exactly
    what it was. Otherwise ``(rows, group)``: ``rows`` (G,) picks, for each group in the order of its first
    copy, its best-scored copy (lowest score, the first one on ties), whose keypoint indices and shapes then
    stand for the group; ``group`` (K,) is the position in ``rows`` of every input row. A filter decides
    ``matches[rows]`` and maps the decision back with ``keep[group]``, so every copy gets the decision of its
    group and no copy counts in the support or neighbourhood of another.
    """
    first, group = coincident_groups(ms.x, ms.y)
    if len(first) == len(ms):
        return None
    order = np.lexsort((np.arange(len(ms)), ms.scores, group))
    starts = np.r_[0, np.flatnonzero(np.diff(group[order])) + 1]
    return order[starts], group  # groups are numbered 0..G-1 in order of first copy
