"""Blob matching (Sec. 3): the public function and the ratio / combination steps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._numerics.scores import nnr_scores
from .._numerics.validation import as_finite_matrix, as_points
from . import _select_kernels
from .config import BlobConfig
from .context import BlobContext
from .overlap import as_shapes

__all__ = ["BlobMatches", "blob_matching", "nnr_ratio", "combine_ratios", "rank_candidates"]


@dataclass(frozen=True)
class BlobMatches:
    """Candidate matches of blob matching.

    Attributes
    ----------
    matches : ndarray of shape (K, 2), int64
        Row into image 1 (keypoint / descriptor index), row into image 2.
    scores : ndarray of shape (K,), float64
        D̄ of Eq. (15), lower is better, sorted (ties: row, column); an ``NNRScores`` carrying its ``ratio``.
    """

    matches: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return len(self.matches)

    @classmethod
    def empty(cls) -> "BlobMatches":
        return cls(np.empty((0, 2), np.int64), np.empty(0))


def nnr_ratio(dist: np.ndarray, second: np.ndarray, ratio: str) -> np.ndarray:
    """NNR-like similarity of step 3: ``"D>="`` ``d / d2`` (Eq. 13), ``"D+>="``/``"D+"`` ``d / (d + d2)``
    (Eq. 14). No second entry (``d2 = inf``) gives 0; ``d = d2 = 0`` gives 1 for D≥, 0.5 for D+."""
    dist = np.asarray(dist, np.float64)
    second = np.asarray(second, np.float64)
    den = second if ratio == "D>=" else dist + second
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(np.isinf(den), 0.0, dist / den)
    tie = (dist == 0) & (second == 0)
    out[tie] = 1.0 if ratio == "D>=" else 0.5
    return out


def combine_ratios(a: np.ndarray, b: np.ndarray, combine: str) -> np.ndarray:
    """W(a, b) of step 4 (Eq. 15): ``"a"``, ``"b"``, ``"min"``, ``"max"`` or ``"harmonic"`` 2ab/(a+b)."""
    if combine == "a":
        return np.asarray(a, np.float64).copy()
    if combine == "b":
        return np.asarray(b, np.float64).copy()
    if combine == "min":
        return np.minimum(a, b)
    if combine == "max":
        return np.maximum(a, b)
    if combine == "harmonic":
        s = a + b
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(s > 0, 2 * a * b / s, 0.0)
    raise ValueError(f"combine must be one of 'a', 'b', 'min', 'max', 'harmonic', got {combine!r}")


def rank_candidates(ctx: BlobContext, matches: np.ndarray, dist: np.ndarray, *, ratio: str,
                    t_o: float | None, t_o_kind: str) -> tuple[np.ndarray, np.ndarray]:
    """Step 3 for both references: ``a = D'_ij`` (image 1) and ``b = (D^T)'_ji`` (image 2); with ``"D>="``
    or ``"D+>="`` the second best is ``>= D_ij`` (Eq. 13); FGINN (Eq. 9) skips keypoints near the match."""
    return tuple(_side_ratio(ctx, matches, dist, side, ratio=ratio, t_o=t_o, t_o_kind=t_o_kind)
                 for side in (0, 1))


def _side_ratio(ctx: BlobContext, matches: np.ndarray, dist: np.ndarray, side: int, *, ratio: str,
                t_o: float | None, t_o_kind: str) -> np.ndarray:
    """Step 3 with image ``side + 1`` as the reference: ``a`` (side 0) or ``b`` (side 1) of Eq. (15)."""
    anchors, others = matches[:, side], matches[:, 1 - side]
    second = ctx.second_best(side, anchors, others, dist, geq=ratio != "D+", t_o=t_o, t_o_kind=t_o_kind)
    return nnr_ratio(dist, second, ratio)


def _sorted(matches: np.ndarray, scores: np.ndarray, ratio: str) -> BlobMatches:
    order = _select_kernels.break_ties(np.argsort(scores), scores, matches[:, 0], matches[:, 1])
    # The scores say which ratio made them (their scale), for the filters that read thresholds on them.
    return BlobMatches(np.ascontiguousarray(matches[order]), nnr_scores(scores[order], ratio))


def blob_matching(desc1=None, desc2=None, *, distances=None, kpts1=None, kpts2=None, shapes1=None,
                  shapes2=None, f=10, prefilter="cup", f_prime=5, ratio="D+", t_o=10.0, t_o_kind="px",
                  combine="harmonic", max_dense_bytes: int = 1 << 30, distance=None) -> BlobMatches:
    """Blob matching (Sec. 3): pre-filter, greedy many-to-many selection, NNR-like ratio, combination.

    Steps: pre-filter D with F∩/F∪ (Eqs. 10-11); greedily accept entries by increasing distance, each row
    and column at most ``f_prime`` times; score each match with D≥ (Eq. 13) or D+ / D+≥ (Eq. 14), with
    FGINN (Eq. 9), once per reference image; combine the two with W(a, b) (Eq. 15).

    Parameters
    ----------
    desc1, desc2 : ndarray of shape (n, d) and (m, d), optional
        Descriptors; D is their L2 distance or ``distance``. Or give ``distances``.
    distances : ndarray of shape (n, m), optional
        Precomputed non-negative distance matrix.
    kpts1, kpts2 : ndarray of shape (n, 2) and (m, 2), optional
        Keypoints (x, y) in pixels, origin at the centre of the top-left pixel; required when ``t_o`` is set.
    shapes1, shapes2 : ndarray of shape (n, 2, 2) and (m, 2, 2), optional
        Affine patch shapes (:func:`shapes_from_scale_angle`) or ``(n,)`` radii; for ``t_o_kind="overlap"``.
    f : int or "omega", default 10
        Pre-filter depth; ``"omega"`` (Ω = max(n, m)) disables the pre-filter.
    prefilter : {"cup", "cap"}, default "cup"
        F∪ (Eq. 11) or F∩ (Eq. 10).
    f_prime : int, default 5
        Greedy many-to-many cap f'.
    ratio : {"D+", "D+>=", "D>="}, default "D+"
        NNR-like similarity of step 3.
    t_o : float or None, default 10.0
        FGINN threshold; ``None`` or ``math.inf`` turns FGINN off.
    t_o_kind : {"px", "overlap"}, default "px"
        Skip keypoints closer than ``t_o`` pixels (``"px"``) or with overlap error ``<= t_o`` (``"overlap"``).
    combine : {"harmonic", "a", "b", "min", "max"}, default "harmonic"
        W(a, b) of Eq. (15).
    max_dense_bytes : int
        Memory cap for the whole D that f = Ω needs; above it, ``MemoryError``.
    distance : callable, optional
        The descriptors' own distance, ``distance(desc1_rows, desc2) -> (rows, m)``; default L2.

    Returns
    -------
    BlobMatches
        Sorted by score (lower is better).

    Notes
    -----
    Ties are broken by value, then row, then column; with no admissible second best the ratio is 0. Every
    decision is taken on exact float64 distances, so the output does not depend on the BLAS kernel or
    thread count (docs/blob-matching.md).

    References
    ----------
    F. Bellavia, "SIFT Matching by Context Exposed", IEEE TPAMI 2022, Sec. 3, Eqs. (5), (9)-(15).

    Examples
    --------
    The toy matrix of Fig. 1a with f = 3∩, f' = 2 (indices count from 0 here, from 1 in the paper):

    >>> from ctxmatch_lib.blob.toy import FIG1A_D
    >>> out = blob_matching(distances=FIG1A_D, f=3, prefilter="cap", f_prime=2, ratio="D>=", t_o=None)
    >>> sorted((int(i) + 1, int(j) + 1) for i, j in out.matches)
    [(1, 1), (1, 3), (2, 2), (2, 5), (3, 4), (4, 2), (4, 3), (7, 1), (7, 5)]
    """
    cfg = BlobConfig(f=f, prefilter=prefilter, f_prime=f_prime, ratio=ratio, t_o=t_o, t_o_kind=t_o_kind,
                     combine=combine)
    if distances is not None:
        if desc1 is not None or desc2 is not None:
            raise ValueError("give either desc1/desc2 or distances, not both")
        if distance is not None:
            raise ValueError("distance applies to desc1/desc2, not to precomputed distances")
        D = as_finite_matrix(distances, "distances")
        if D.size and D.min() < 0:
            raise ValueError("distances must be non-negative")
        n, m = D.shape
    else:
        if desc1 is None or desc2 is None:
            raise ValueError("desc1 and desc2 are required unless distances is given")
        desc1 = as_finite_matrix(desc1, "desc1")
        desc2 = as_finite_matrix(desc2, "desc2")
        if desc1.shape[1] != desc2.shape[1]:
            raise ValueError(
                f"desc1 and desc2 must have the same dimension, got {desc1.shape[1]} and {desc2.shape[1]}")
        n, m = len(desc1), len(desc2)
    if cfg.t_o is not None and (kpts1 is None or kpts2 is None):
        raise ValueError("kpts1 and kpts2 are required when t_o is set (FGINN)")
    if kpts1 is not None:
        kpts1 = as_points(kpts1, "kpts1", n=n)
    if kpts2 is not None:
        kpts2 = as_points(kpts2, "kpts2", n=m)
    if cfg.t_o is not None and cfg.t_o_kind == "overlap":
        if shapes1 is None or shapes2 is None:
            raise ValueError("shapes1 and shapes2 are required when t_o_kind='overlap'")
        shapes1 = as_shapes(shapes1, n, "shapes1")
        shapes2 = as_shapes(shapes2, m, "shapes2")
    if n == 0 or m == 0:
        return BlobMatches.empty()
    dense = cfg.f == "omega" or cfg.f >= max(n, m)  # no pre-filter: the greedy needs all of D
    depth = cfg.f_prime if dense else max(cfg.f_prime, cfg.f)
    ctx = BlobContext(desc1, desc2, distances=D if distances is not None else None, kpts1=kpts1, kpts2=kpts2,
                      shapes1=shapes1, shapes2=shapes2, depth=depth, keep_dense=True if dense else None,
                      max_dense_bytes=max_dense_bytes, distance=distance, margin=_margin(cfg, dense),
                      columns=not (dense and cfg.combine == "a"))  # f = Ω with W = a reads rows only
    try:
        return match_context(ctx, cfg)
    finally:
        ctx.release()  # f = Ω's codes of D serve the next call (blob._workspace)


def _margin(cfg: BlobConfig, dense: bool) -> int:
    """Entries kept per line beyond the depth (speed only): D≥'s and D+≥'s second best may lie far past
    ``D_ij``, D+'s is nearly always in the list."""
    return 2 if cfg.ratio == "D+" and not dense else 8


def match_context(ctx: BlobContext, cfg: BlobConfig) -> BlobMatches:
    """Run one :class:`BlobConfig` on a prepared :class:`BlobContext` (the sweep's fast path)."""
    matches, dist = ctx.candidates(cfg.f, cfg.prefilter, cfg.f_prime)
    if len(matches) == 0:
        return BlobMatches.empty()
    step3 = dict(ratio=cfg.ratio, t_o=cfg.t_o, t_o_kind=cfg.t_o_kind)
    if cfg.combine in ("a", "b"):  # W reads one reference only: the other's second best is not needed
        scores = _side_ratio(ctx, matches, dist, "ab".index(cfg.combine), **step3)
    else:
        scores = combine_ratios(*rank_candidates(ctx, matches, dist, **step3), cfg.combine)
    return _sorted(matches, scores, cfg.ratio)
