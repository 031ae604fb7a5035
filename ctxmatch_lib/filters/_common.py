"""Input handling shared by the peer spatial filters (private).

Every filter of this package starts with :func:`prepare`, which validates the common arguments with the
helpers of :mod:`ctxmatch_lib._validation` and returns the matched coordinates as two aligned ``(K, 2)``
arrays. Keypoints are (x, y) pixels with the origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validation import as_image_size, as_matches, as_points, as_scores

__all__ = ["MatchSet", "prepare", "knn_without_self", "normalize_points", "check_positive"]


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


# Neighbours queried beyond the k needed, to see distance ties at the k-th place without a second query.
_SPARE = 6


def knn_without_self(points: np.ndarray, candidates: np.ndarray, k: int, queries: np.ndarray | None = None):
    """Indices (into ``points``) of the ``k`` nearest ``candidates`` of every query, the query excluded.

    ``candidates`` and ``queries`` (default: every point) are index arrays into ``points``; the answer has
    shape ``(len(queries), k')`` with ``k' = min(k, len(candidates) - 1)``, nearest first. A query that is
    itself a candidate is not its own neighbour.

    Ties (equal distances, frequent with many-to-many matches, which repeat a keypoint) are broken by the
    smaller index, not by the k-d tree's traversal order: that order is an implementation detail that
    changed the LPM and GLPM results between machines. The distances are recomputed here in one fixed
    arithmetic, and a row whose k-th distance may tie with points beyond those returned is completed
    with every candidate within that distance.
    """
    queries = np.arange(len(points)) if queries is None else np.asarray(queries)
    cand = np.asarray(candidates)
    n = len(queries)
    kk = min(k, len(cand) - 1)
    if kk <= 0 or n == 0:
        return np.empty((n, 0), np.int64)
    pts = np.asarray(points, np.float64)
    tree = cKDTree(pts[cand])
    m = min(kk + 1 + _SPARE, len(cand))  # spare neighbours to see ties at the k-th place
    _, j = tree.query(pts[queries], k=m)
    j = j.reshape(n, m)

    def ranked(rows, jj, valid=None):
        """Candidates ``cand[jj]`` of the queries ``queries[rows]`` sorted by (distance, index), the query
        itself and entries not ``valid`` last (squared distance ``inf``), with their squared distances."""
        idx = cand[jj]
        q = queries[rows]
        d2 = ((pts[idx] - pts[q][:, None, :]) ** 2).sum(-1)
        d2[idx == q[:, None]] = np.inf
        if valid is not None:
            d2[~valid] = np.inf
        key = np.lexsort((idx, d2), axis=1)
        return np.take_along_axis(idx, key, axis=1), np.take_along_axis(d2, key, axis=1)

    out, d2 = ranked(np.arange(n), j)
    out = out[:, :kk]
    if m < len(cand):
        # The k-th neighbour may tie with candidates the tree did not return: for those rows, take every
        # candidate within the k-th distance (one vectorised ball query) and rank them the same way.
        far = np.where(np.isfinite(d2), d2, -np.inf).max(axis=1)
        unsure = np.flatnonzero(d2[:, kk - 1] >= far * (1 - 1e-12))
        if len(unsure):
            radius = np.sqrt(d2[unsure, kk - 1]) * (1 + 1e-9) + 1e-12
            near = tree.query_ball_point(pts[queries[unsure]], radius)
            lens = np.array([len(x) for x in near])
            width = max(int(lens.max()), kk)
            jj = np.zeros((len(unsure), width), np.int64)
            valid = np.arange(width)[None, :] < lens[:, None]
            jj[valid] = np.concatenate([np.asarray(x, np.int64) for x in near])
            out[unsure] = ranked(unsure, jj, valid)[0][:, :kk]
    return out


def normalize_points(p: np.ndarray) -> np.ndarray:
    """Zero mean and unit root-mean-square norm, the normalisation used by VFC and LLT (scale 1 if flat)."""
    c = p - p.mean(axis=0)
    scale = np.sqrt((c**2).sum() / max(len(p), 1))
    return c / scale if scale > 1e-12 else c
