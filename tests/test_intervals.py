"""Repeated estimator runs and the intervals over pairs and runs: the bootstrap on planted cases, the paired
differences, the engine's ``runs`` and the tables' interval columns."""

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib.evaluation import evaluate_cached, select_pairs
from ctxmatch_lib.evaluation.steps import run_seed
from ctxmatch_lib.geometry_metrics import (_auc_sorted, bootstrap_interval, geometry_table, paired_differences,
                                           pose_auc)
from ctxmatch_lib.report import geometry_markdown, paired_markdown


def test_batched_auc_equals_pose_auc():
    rng = np.random.default_rng(0)
    for _ in range(100):
        e = rng.exponential(4.0, rng.integers(1, 40))
        e[rng.random(len(e)) < 0.2] = np.inf
        for t in (1.0, 3.0, 10.0):
            assert _auc_sorted(np.sort(e)[None], t)[0] == pytest.approx(pose_auc(e, [t])[0], abs=1e-12)


def test_interval_covers_a_known_mean_at_its_level():
    """Planted: 30 pairs, one run, values ~ N(0.5, 0.1); the 95 % interval holds the true mean 50 % in about
    95 % of 200 draws, and its width is about 2 x 1.96 sigma / sqrt(n)."""
    rng = np.random.default_rng(1)
    hits, widths = 0, []
    for _ in range(200):
        lo, hi = bootstrap_interval(rng.normal(0.5, 0.1, (30, 1)), n_resamples=1000)
        hits += lo <= 50.0 <= hi
        widths.append(hi - lo)
    assert 0.88 <= hits / 200 <= 0.99
    assert np.mean(widths) == pytest.approx(2 * 1.96 * 10 / np.sqrt(30), rel=0.1)


def test_interval_widens_with_the_spread_over_runs():
    rng = np.random.default_rng(2)
    pair_effect = rng.normal(0.5, 0.05, (20, 1))
    quiet = bootstrap_interval(pair_effect + rng.normal(0, 0.001, (20, 5)))
    noisy = bootstrap_interval(pair_effect + rng.normal(0, 0.2, (20, 5)))
    assert noisy[1] - noisy[0] > 1.5 * (quiet[1] - quiet[0])


def test_interval_of_constant_values_and_of_nothing():
    auc = 100 * pose_auc(np.full(12, 2.0), [5.0])[0]  # SuperGlue's trapezoid: (2 / 12 / 2 + 3) / 5
    assert auc == pytest.approx(100 * (1 / 12 + 3) / 5)
    assert bootstrap_interval(np.full((4, 3), 2.0), auc_at=5.0) == pytest.approx((auc, auc))
    assert all(np.isnan(bootstrap_interval(np.empty((0, 3)))))
    with pytest.raises(ValueError, match="confidence"):
        bootstrap_interval(np.ones((3, 1)), confidence=1.5)


def _planted_rows(shift: float) -> pd.DataFrame:
    """Three methods on 12 planar pairs x 4 runs: ``b`` is ``a`` moved by ``shift`` px, ``c`` equals ``a``."""
    rng = np.random.default_rng(3)
    a = rng.uniform(0.5, 4.0, (12, 4))
    rows = []
    for method, err in (("a", a), ("b", a + shift), ("c", a)):
        for p in range(12):
            for r in range(4):
                rows.append({"dataset": "d", "pair_id": f"p{p:02d}", "kind": "planar", "blob": "x", "method": method,
                             "model": "magsac", "run": r, "corner_error": err[p, r], "model_inliers": 10.0,
                             "error": "", "time_s": 0.0, "model_time_s": 0.0, "features": "f"})
    return pd.DataFrame(rows)


def test_paired_differences_resolve_a_planted_gap_and_not_a_tie():
    out = paired_differences(_planted_rows(1.0), references=("a",), by=("kind", "model"), metrics=["auc_5px"])
    b = out[out.method == "b"].iloc[0]
    c = out[out.method == "c"].iloc[0]
    assert b.difference < 0 and b.hi < 0 and b.resolved
    assert c.difference == 0 and c.lo == 0 and c.hi == 0 and not c.resolved
    assert (b.pairs, b.runs) == (12, 4)


def test_tables_repeat_for_any_row_order():
    rows = _planted_rows(0.5)
    shuffled = rows.sample(frac=1.0, random_state=4)
    # The groups come in the order of the rows; their values do not depend on it.
    for build in (lambda r: geometry_table(r, by=("kind", "method", "model")).sort_index(),
                  lambda r: paired_differences(r, by=("kind", "model"), metrics=["auc_3px"])
                  .sort_values(["method", "reference"], ignore_index=True)):
        pd.testing.assert_frame_equal(build(rows), build(shuffled))
    t = geometry_table(rows, by=("kind", "method", "model"))
    assert (t["runs"] == 4).all() and (t["pairs"] == 12).all()
    assert (t["auc_5px_lo"] <= t["auc_5px_pct"]).all() and (t["auc_5px_pct"] <= t["auc_5px_hi"]).all()
    md = geometry_markdown(t, title="t", provenance={})
    assert f"{t.loc[('planar', 'a', 'magsac'), 'auc_5px_pct']:.2f} [" in md and "auc_5px_lo" not in md
    md = paired_markdown(paired_differences(rows, references=("a",), by=("kind", "model")), title="p", provenance={})
    assert "not resolved" in md and "| yes |" in md


def test_run_seed_keeps_run_zero_and_varies_the_rest():
    assert run_seed(11, "th", "magsac", 0) == 11
    seeds = {run_seed(11, m, "magsac", r) for m in ("th", "dtm2") for r in (1, 2, 3)}
    assert len(seeds) == 6


@pytest.mark.slow
def test_engine_runs_rows_are_seeded_and_repeat(tmp_path):
    pairs = select_pairs("embedded-planar", step=4)[:2]
    kw = dict(features=["sift-rootsift"], blobs=["baseline"], filters=["th"], models=["none", "1sac", "magsac"],
              cache=False)
    one = evaluate_cached(pairs, **kw)
    three = evaluate_cached(pairs, runs=3, **kw)
    again = evaluate_cached(pairs, runs=3, **kw)
    fitted = three[three.model == "magsac"]
    assert sorted(fitted.groupby(["pair_id", "method"]).run.apply(tuple).unique()) == [(0, 1, 2)]
    assert (three[three.model != "magsac"].run == 0).all()
    assert len(three[three.model != "magsac"]) == len(one[one.model != "magsac"])
    cols = ["pair_id", "method", "model", "model_inliers", "corner_error", "precision"]
    # Run 0 is the single run; a rerun gives the same rows and the same table, byte for byte.
    pd.testing.assert_frame_equal(three[three.run == 0][cols].reset_index(drop=True), one[cols].reset_index(drop=True))
    pd.testing.assert_frame_equal(three.drop(columns=["time_s", "model_time_s"]),
                                  again.drop(columns=["time_s", "model_time_s"]))
    t1, t2 = (geometry_table(d).drop(columns=["geometry_time_s", "geometry_time_median_s"]) for d in (three, again))
    assert t1.to_csv() == t2.to_csv()
    assert t1.xs("magsac", level="model")["runs"].eq(3).all() and t1.xs("1sac", level="model")["runs"].eq(1).all()
    with pytest.raises(ValueError, match="runs must be a positive integer"):
        evaluate_cached(pairs, runs=0, **kw)


def test_paired_differences_name_a_bad_metric():
    with pytest.raises(ValueError, match="auc_<t>px, auc_<t>deg or epi_share_"):
        paired_differences(_planted_rows(0.0), metrics=["precision"])
    with pytest.raises(ValueError, match="'auc_xpx'"):
        paired_differences(_planted_rows(0.0), metrics=["auc_xpx"])


def test_too_few_pairs_never_resolve():
    rows = _planted_rows(1.0)
    few = rows[rows.pair_id.isin(["p00", "p01", "p02"])]
    out = paired_differences(few, references=("a",), by=("kind", "model"), metrics=["auc_5px"])
    b = out[out.method == "b"].iloc[0]
    assert b.hi < 0 and not b.resolved and b.pairs == 3
    assert "too few pairs" in paired_markdown(out, title="p", provenance={})
