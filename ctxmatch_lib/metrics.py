"""Match-set statistics of Sec. 5.1 and Appendix "DTM evaluation": precision, normalised recall, recall*,
correct/output counts, failure, AP and mAP.

A set of many-to-many matches counts ``min(|Z_rows|, |Z_cols|)`` (:func:`normalised_count`, Fig. 4) in both
terms of the recall; the reference is the correct blob candidates (recall) or the union over configurations
(recall*). An empty output has precision, recall and AP 0 and ``empty_output`` set; ``failure`` means
matches, none correct (the paper's failure is either); an empty reference gives NaN. See docs/evaluation.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ._numerics.ranking import area_terms
from ._numerics.validation import as_matches, as_scores, cumulative_distinct

__all__ = [
    "MatchMetrics", "normalised_count", "cumulative_normalised_count", "precision", "recall", "ground_truth_union",
    "average_precision", "mean_average_precision", "evaluate_matches",
]


def normalised_count(matches) -> int:
    """``min(|Z_rows|, |Z_cols|)``: distinct image-1 or image-2 keypoints, whichever fewer (Sec. 5.1, Fig. 4).

    Examples
    --------
    >>> normalised_count([[0, 0], [0, 1], [1, 2], [2, 3], [3, 4], [3, 0]])
    4
    """
    m = as_matches(matches)
    return int(min(len(np.unique(m[:, 0])), len(np.unique(m[:, 1]))))


def cumulative_normalised_count(matches) -> np.ndarray:
    """``out[k]`` = :func:`normalised_count` of ``matches[:k + 1]`` (int64, for ranked lists)."""
    m = as_matches(matches)
    return np.minimum(cumulative_distinct(m[:, 0]), cumulative_distinct(m[:, 1])).astype(np.int64)


def _labels(is_correct, k: int) -> np.ndarray:
    lab = np.asarray(is_correct, dtype=bool).reshape(-1)
    if len(lab) != k:
        raise ValueError(f"is_correct must have one label per match ({k}), got {len(lab)}")
    return lab


def precision(is_correct) -> float:
    """``correct / output``; 0 for an empty output.

    Examples
    --------
    >>> precision([True, False, True, True])
    0.75
    """
    lab = np.asarray(is_correct, dtype=bool).reshape(-1)
    return float(lab.mean()) if len(lab) else 0.0


def recall(matches, is_correct, reference) -> float:
    """Normalised recall: :func:`normalised_count` of the correct output over that of ``reference``.

    Parameters
    ----------
    matches : array_like of shape (K, 2), int
    is_correct : array_like of shape (K,), bool
    reference : array_like of shape (M, 2), int
        The correct matches to recall (for recall*, :func:`ground_truth_union`); NaN when empty.

    Examples
    --------
    >>> recall([[0, 0], [0, 1]], [True, True], [[0, 0], [0, 1], [1, 1], [2, 2]])
    0.3333333333333333
    """
    m = as_matches(matches)
    lab = _labels(is_correct, len(m))
    den = normalised_count(reference)
    if den == 0:
        return float("nan")
    return normalised_count(m[lab]) / den


def ground_truth_union(*correct_sets) -> np.ndarray:
    """Union of ``(M_i, 2)`` sets of correct matches: the distinct matches, sorted lexicographically."""
    sets = [as_matches(s, name=f"correct_sets[{i}]") for i, s in enumerate(correct_sets)]
    if not sets:
        return np.empty((0, 2), np.int64)
    return np.unique(np.concatenate(sets, axis=0), axis=0)


def average_precision(matches, is_correct, scores, reference) -> float:
    """Average precision of the ranking by ascending score, with the normalised recall of Sec. 5.1.

    ``AP = sum_k P_k (N_k - N_{k-1}) / normalised_count(reference)``, ``P_k`` the precision of the top ``k``
    (stable sort), ``N_k`` the normalised count of its correct matches.

    Parameters
    ----------
    matches : array_like of shape (K, 2), int
    is_correct : array_like of shape (K,), bool
    scores : array_like of shape (K,)
        Lower is better; ``None`` keeps the given order.
    reference : array_like of shape (M, 2), int
        As in :func:`recall`.

    Examples
    --------
    >>> average_precision([[0, 0], [1, 1], [2, 2]], [True, False, True], [0.1, 0.2, 0.3], [[0, 0], [2, 2]])
    0.8333333333333333
    """
    m = as_matches(matches)
    lab = _labels(is_correct, len(m))
    s = as_scores(scores, len(m))
    den = normalised_count(reference)
    if den == 0:
        return float("nan")
    if len(m) == 0:
        return 0.0
    return float(ranked_area(m[:, 0], m[:, 1], lab, s) / den)


def _area_terms_numpy(rows, cols, lab, scores) -> np.ndarray:
    """The terms of :func:`ranked_area` at their ranks, the direct way (any scores, NaN ranked last)."""
    order = np.argsort(scores, kind="stable")
    pos = np.flatnonzero(lab[order])
    ranked = order[pos]
    r, c = np.asarray(rows)[ranked], np.asarray(cols)[ranked]
    # N_k counts the correct matches only: cumulative distinct keypoints among the correct ones so far.
    n = np.maximum.accumulate(np.minimum(cumulative_distinct(r), cumulative_distinct(c)).astype(np.int64))
    terms = np.zeros(len(lab))
    # P_k at the j-th correct candidate (rank pos + 1) is j / (pos + 1); wrong ones add 0 * P_k = +0.0.
    terms[pos] = np.arange(1, len(pos) + 1) / (pos + 1) * np.diff(np.r_[0, n])
    return terms


def ranked_area(rows, cols, lab, scores) -> np.float64:
    """``sum_k P_k * (N_k - N_{k-1})``, the numerator of :func:`average_precision` (compiled terms,
    :func:`ctxmatch_lib._numerics.ranking.area_terms`, bit-identical to :func:`_area_terms_numpy`)."""
    lab = np.asarray(lab, bool)
    scores = np.asarray(scores, np.float64)
    if not lab.any():
        return np.zeros(len(lab)).sum()
    if np.isnan(scores).any():
        return _area_terms_numpy(rows, cols, lab, scores).sum()
    return area_terms(rows, cols, lab, scores).sum()


def mean_average_precision(aps) -> float:
    """Mean of per-pair APs, skipping undefined (NaN) ones; NaN when none is defined."""
    a = np.asarray(list(aps), dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if len(a) else float("nan")


@dataclass(frozen=True)
class MatchMetrics:
    """Statistics of one output match set (one row of the Appendix tables).

    Attributes
    ----------
    precision, recall, recall_star, ap : float
    correct, correct_norm, output : int
        Correct output matches (plain and normalised count), output matches.
    failure, empty_output : bool
        Matches, none correct; no match at all.
    n_gt, n_gt_star : int
        Normalised size of the recall and recall* references.
    time_s : float
    """

    precision: float
    recall: float
    recall_star: float
    ap: float
    correct: int
    correct_norm: int
    output: int
    failure: bool
    n_gt: int
    n_gt_star: int
    time_s: float = float("nan")
    empty_output: bool = False

    def as_dict(self) -> dict:
        return asdict(self)


def evaluate_matches(matches, is_correct, *, reference, reference_star=None, scores=None,
                     time_s: float = float("nan")) -> MatchMetrics:
    """All statistics of one output match set.

    Parameters
    ----------
    matches : array_like of shape (K, 2), int
    is_correct : array_like of shape (K,), bool
    reference : array_like of shape (M, 2), int
        Correct blob candidates of the same configuration (recall).
    reference_star : array_like of shape (M*, 2), int, optional
        Union of correct matches over all configurations (recall*); default ``reference``.
    scores : array_like of shape (K,), optional
        Ranking for the AP, lower is better; ``None`` keeps the given order.
    time_s : float

    Examples
    --------
    >>> mm = evaluate_matches([[0, 0], [1, 1]], [True, False], reference=[[0, 0], [2, 2]])
    >>> mm.precision, mm.recall, mm.correct, mm.output, mm.failure
    (0.5, 0.5, 1, 2, False)
    """
    m = as_matches(matches)
    lab = _labels(is_correct, len(m))
    ref_star = reference if reference_star is None else reference_star
    correct = int(lab.sum())
    return MatchMetrics(
        precision=precision(lab), recall=recall(m, lab, reference), recall_star=recall(m, lab, ref_star),
        ap=average_precision(m, lab, scores, reference), correct=correct, correct_norm=normalised_count(m[lab]),
        output=len(m), failure=len(m) > 0 and correct == 0, empty_output=len(m) == 0,
        n_gt=normalised_count(reference), n_gt_star=normalised_count(ref_star), time_s=float(time_s),
    )
