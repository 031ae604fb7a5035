"""Helpers comparing the ground-truth methods (Appendix "Ground truth estimation methods")."""

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib.report.gt_compare import correct_per_pair, method_groups, setup_rank_agreement, worst_in_groups


def test_groups_are_disjoint_and_cover_the_union():
    rng = np.random.default_rng(0)
    b = rng.random(200) < 0.5
    c = b & (rng.random(200) < 0.7)
    d = c | (~b & (rng.random(200) < 0.3))  # B ∩ D ⊆ C, as the ground truth guarantees
    groups = method_groups({"B": b, "C": c, "D": d})
    stack = np.stack(list(groups.values()))
    assert (stack.sum(0) <= 1).all()
    np.testing.assert_array_equal(stack.any(0), b | c | d)
    ad = method_groups({"A": b, "D": d}, "AD")
    np.testing.assert_array_equal(ad["A ∩ D"] | ad["A ∖ D"], b)


def test_groups_errors():
    with pytest.raises(ValueError, match="scheme"):
        method_groups({}, "XY")
    with pytest.raises(ValueError, match="lacks"):
        method_groups({"B": np.ones(2, bool)}, "BCD")


def test_worst_in_groups():
    groups = {"x": np.array([1, 1, 0, 1], bool), "empty": np.zeros(4, bool)}
    assert worst_in_groups(groups, [1.0, np.nan, 9.0, 3.0]) == {"x": 3}


def test_correct_per_pair_and_rank_agreement():
    rows = pd.DataFrame({
        "kind": ["planar"] * 4 + ["nonplanar"] * 4,
        "features": "sift",
        "gt_method": ["C", "D"] * 4,
        "pair_id": ["p1", "p1", "p2", "p2", "n1", "n1", "n2", "n2"],
        "method": "blob", "model": "none",
        "correct": [10, 20, 30, 40, 5, 6, 7, 8],
    })
    t = correct_per_pair(rows)
    assert t.loc[("planar", "sift"), "C"] == 20 and t.loc[("planar", "sift"), "D"] == 30
    assert t.loc[("nonplanar", "sift"), "pairs"] == 2
    with pytest.raises(ValueError, match="lacks columns"):
        correct_per_pair(rows.drop(columns="kind"))
    a = pd.DataFrame({"features": "f", "blob": list("abcd"), "mAP": [1.0, 2.0, 3.0, 4.0]})
    b = a.assign(mAP=[10.0, 20.0, 40.0, 30.0])
    r = setup_rank_agreement(a, b)
    assert r.loc["f", "spearman"] == pytest.approx(0.8) and r.loc["f", "setups"] == 4
    assert r.loc["f", "best_a"] == "d" and r.loc["f", "best_b"] == "c"
