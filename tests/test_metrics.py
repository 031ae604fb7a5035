"""Precision, normalised recall (Fig. 4), recall*, AP / mAP and their edge cases."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ctxmatch_lib.metrics import (
    average_precision,
    cumulative_normalised_count,
    evaluate_matches,
    ground_truth_union,
    mean_average_precision,
    normalised_count,
    precision,
    recall,
)

# Fig. 4: many-to-many correct matches using 4 distinct rows and 5 distinct columns.
FIG4_Z = np.array([[0, 0], [0, 1], [1, 1], [1, 2], [2, 3], [3, 3], [3, 4]])

EMPTY = np.empty((0, 2), np.int64)


def test_fig4_normalised_count():
    assert len(np.unique(FIG4_Z[:, 0])) == 4 and len(np.unique(FIG4_Z[:, 1])) == 5
    assert normalised_count(FIG4_Z) == 4  # |Z| = min(4, 5), not 7


def test_fig4_recall_normalises_numerator_and_denominator():
    # An output holding all of Z recalls everything, although |Z| = 7 > 4.
    assert recall(FIG4_Z, np.ones(7, bool), FIG4_Z) == 1.0
    # Keeping (0, 0), (0, 1), (1, 1): rows {0, 1}, cols {0, 1} -> 2 / 4.
    assert recall(FIG4_Z[:3], np.ones(3, bool), FIG4_Z) == 0.5
    # The duplicates (0, 0) and (0, 1) add one to the numerator, not two.
    assert recall(FIG4_Z[:2], np.ones(2, bool), FIG4_Z) == 0.25


def test_one_to_one_reduces_to_standard_recall():
    z = np.c_[np.arange(10), np.arange(10)]
    assert normalised_count(z) == 10
    assert recall(z[:3], [True, True, False], z) == 0.2


def test_cumulative_normalised_count():
    np.testing.assert_array_equal(cumulative_normalised_count(FIG4_Z), [1, 1, 2, 2, 3, 4, 4])
    assert cumulative_normalised_count(EMPTY).shape == (0,)


def test_precision_exact_and_empty():
    assert precision([True, True, False, False, False]) == 0.4
    assert precision([]) == 0.0


def test_ground_truth_union():
    a = np.array([[0, 0], [1, 1]])
    b = np.array([[1, 1], [2, 5]])
    np.testing.assert_array_equal(ground_truth_union(a, b), [[0, 0], [1, 1], [2, 5]])
    assert ground_truth_union().shape == (0, 2)
    assert ground_truth_union(EMPTY, EMPTY).shape == (0, 2)


def test_average_precision_exact():
    m = np.c_[np.arange(4), np.arange(4)]
    lab = np.array([True, False, True, False])
    ref = m[lab]
    # Ranks 1 and 3 are correct: (1/1 + 2/3) / 2.
    assert average_precision(m, lab, [0.1, 0.2, 0.3, 0.4], ref) == pytest.approx(5 / 6)
    # Perfect ranking.
    assert average_precision(m, lab, [0.1, 0.3, 0.2, 0.4], ref) == pytest.approx(1.0)
    # Ties keep the given order (stable sort).
    assert average_precision(m, lab, [0.0, 0.0, 0.0, 0.0], ref) == pytest.approx(5 / 6)


def test_average_precision_duplicates_add_no_area():
    # Fig. 4 matches in order, all correct: AP = sum over recall steps of precision 1 -> 1.
    assert average_precision(FIG4_Z, np.ones(7, bool), None, FIG4_Z) == pytest.approx(1.0)
    # A filtered subset integrates only up to its recall.
    assert average_precision(FIG4_Z[:3], np.ones(3, bool), None, FIG4_Z) == pytest.approx(0.5)


def test_edge_cases_empty_output_and_no_ground_truth():
    mm = evaluate_matches(EMPTY, np.empty(0, bool), reference=FIG4_Z)
    # An empty output is reported as empty, not as a failure; it counts 0 in the precision and recall.
    assert (mm.precision, mm.recall, mm.ap, mm.correct, mm.output, mm.failure, mm.empty_output) == \
        (0.0, 0.0, 0.0, 0, 0, False, True)
    mm = evaluate_matches([[0, 0], [1, 1]], [False, False], reference=EMPTY)
    assert mm.precision == 0.0 and mm.failure and not mm.empty_output and mm.n_gt == 0
    assert math.isnan(mm.recall) and math.isnan(mm.recall_star) and math.isnan(mm.ap)
    mm = evaluate_matches(EMPTY, np.empty(0, bool), reference=EMPTY)
    assert mm.output == 0 and mm.empty_output and not mm.failure and math.isnan(mm.recall)


def test_evaluate_matches_recall_star_and_counts():
    union = ground_truth_union(FIG4_Z, np.array([[7, 7], [8, 8], [9, 9], [10, 10]]))
    out = np.array([[0, 0], [0, 1], [1, 1], [5, 6]])
    mm = evaluate_matches(out, [True, True, True, False], reference=FIG4_Z, reference_star=union, time_s=0.5)
    assert mm.correct == 3 and mm.correct_norm == 2 and mm.output == 4 and not mm.failure and not mm.empty_output
    assert mm.precision == 0.75 and mm.recall == 0.5 and mm.recall_star == 2 / 8
    assert mm.n_gt == 4 and mm.n_gt_star == 8 and mm.time_s == 0.5
    assert set(mm.as_dict()) >= {"precision", "recall", "recall_star", "correct", "output", "failure", "ap"}


def test_bad_input_names_argument():
    with pytest.raises(ValueError, match="is_correct"):
        recall([[0, 0]], [True, False], FIG4_Z)
    with pytest.raises(ValueError, match="matches"):
        normalised_count([[0, 0, 0]])


def test_mean_average_precision_skips_undefined():
    assert mean_average_precision([0.5, float("nan"), 1.0]) == 0.75
    assert math.isnan(mean_average_precision([float("nan")]))
    assert math.isnan(mean_average_precision([]))


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6)), min_size=1, max_size=30, unique=True),
    st.integers(0, 10_000),
)
def test_recall_and_ap_bounded_for_subsets(pairs, seed):
    """For any output that is a subset of the candidates, 0 <= recall, AP <= 1 and AP <= recall."""
    rng = np.random.default_rng(seed)
    cand = np.array(pairs)
    lab = rng.random(len(cand)) < 0.6
    keep = rng.random(len(cand)) < 0.5
    ref = cand[lab]
    r = recall(cand[keep], lab[keep], ref)
    ap = average_precision(cand[keep], lab[keep], rng.random(keep.sum()), ref)
    if len(ref) == 0:
        assert math.isnan(r) and math.isnan(ap)
    else:
        assert 0.0 <= ap <= r + 1e-12 <= 1.0 + 1e-12
        assert recall(cand, lab, ref) == 1.0
        assert normalised_count(ref) <= min(len(ref), len(np.unique(ref[:, 0])))


def _direct_ap(m, lab, scores, den):
    """The definition of average_precision walked over the whole stable ranking (the code before the
    value-search ranking): the reference the fast one must equal bit for bit."""
    order = np.argsort(scores, kind="stable")
    lab = lab[order]
    prec = np.cumsum(lab) / np.arange(1, len(lab) + 1)
    n = np.zeros(len(lab), np.int64)
    if lab.any():
        n[lab] = cumulative_normalised_count(m[order][lab])
        n = np.maximum.accumulate(n)
    return float((prec * np.diff(np.r_[0, n])).sum() / den)


@pytest.mark.parametrize("seed", range(8))
def test_average_precision_bit_identical_to_the_whole_ranking(seed):
    # Ties (integers, rounded values, +0.0 beside -0.0, inf), few and many correct, short and long lists.
    rng = np.random.default_rng(seed)
    for trial in range(300):
        k = int(rng.integers(1, 400 if trial % 10 else 5000))
        m = rng.integers(0, max(2, k // 3), size=(k, 2))
        lab = rng.random(k) < rng.random()
        kind = trial % 4
        if kind == 0:
            s = rng.integers(0, 6, size=k).astype(float)
        elif kind == 1:
            s = rng.random(k)
        elif kind == 2:
            s = np.where(rng.random(k) < 0.5, 0.0, -0.0)
            s[rng.random(k) < 0.3] = np.inf
            s[rng.random(k) < 0.3] = rng.random()
        else:
            s = np.round(rng.random(k), 2)
        ref = m[rng.random(k) < 0.6]
        den = normalised_count(ref)
        expected = _direct_ap(m, lab, s, den) if den else float("nan")
        got = average_precision(m, lab, s, ref)
        assert (math.isnan(expected) and math.isnan(got)) or got == expected, (seed, trial)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_area_terms_equal_the_direct_ones(seed):
    # The compiled pass behind ranked_area places the same float64 terms at the same ranks as the numpy
    # definition (bit for bit, signs of zero included), with ties (integers, +0.0 beside -0.0) or without.
    from ctxmatch_lib._numerics.ranking import area_terms
    from ctxmatch_lib.metrics import _area_terms_numpy

    rng = np.random.default_rng(seed)
    for trial in range(200):
        k = int(rng.integers(0, 50 if trial % 5 else 4000))
        rows, cols = rng.integers(0, max(1, k // 2), k), rng.integers(0, max(1, k // 3), k)
        lab = rng.random(k) < rng.random()
        if trial % 3 == 0:
            s = rng.random(k)
        elif trial % 3 == 1:
            s = rng.integers(0, 9, k).astype(float)
        else:
            s = np.where(rng.random(k) < 0.5, 0.0, -0.0)
        expected, got = _area_terms_numpy(rows, cols, lab, s), area_terms(rows, cols, lab, s)
        assert got.dtype == np.float64 and got.shape == (k,)
        assert np.array_equal(got.view(np.int64), expected.view(np.int64)), (seed, trial)
