"""Tests for ctxmatch_lib.report (tables, inlier bins) and the cached evaluation (evaluate_cached)."""

import math

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib import report
from ctxmatch_lib.evaluation import evaluate_cached, resolve_filters, select_pairs
from ctxmatch_lib.pipeline import ROW_COLUMNS


def _row(pair, kind, blob, method, model, precision, recall, *, features="sift-rootsift", correct=10, output=20,
         failure=False, time_s=0.5, n_gt=100, n_gt_star=150):
    return dict(dataset="toy", pair_id=pair, kind=kind, blob=blob, method=method, model=model, precision=precision,
                recall=recall, recall_star=recall / 2, ap=0.0, correct=correct, correct_norm=correct, output=output,
                failure=failure, time_s=time_s, model_time_s=0.01, n_kpts1=500, n_kpts2=500, n_candidates=1000,
                n_gt=n_gt, n_gt_star=n_gt_star, gt_method="D", features=features)


@pytest.fixture
def frame():
    """Two planar pairs and one non-planar pair, two blob setups, blob + dtm1 + dtm2, no model and 1SAC."""
    rows = []
    for pair, kind, inl in (("p1", "planar", 0.05), ("p2", "planar", 0.25), ("n1", "nonplanar", 0.15)):
        for blob, feats, shift in (("paper-best-overlap", "harrisz-sosnet", 0.0), ("baseline", "sift-rootsift", 0.5)):
            ratio = inl + shift
            f = dict(features=feats)
            rows.append(_row(pair, kind, blob, "blob", "none", ratio, 1.0, time_s=0.1, **f))
            rows.append(_row(pair, kind, blob, "blob", "1sac", 0.9, 0.8, **f))
            rows.append(_row(pair, kind, blob, "dtm2", "none", 0.8, 0.9, time_s=2.0, **f))
            rows.append(_row(pair, kind, blob, "dtm2", "1sac", 0.95, 0.85, **f))
            rows.append(_row(pair, kind, blob, "dtm1", "none", 0.82, 0.7, time_s=1.0, failure=(pair == "p1"), **f))
            rows.append(_row(pair, kind, blob, "dtm1", "1sac", 0.96, 0.65, failure=(pair == "p1"), **f))
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------------------- labels


def test_method_label_and_order():
    assert report.method_label("dtm1") == "DTM$_1$"
    assert report.method_label("adalam") == "AdaLAM"
    assert report.method_label("unknown") == "unknown"
    assert report.method_order(["adalam", "x", "dtm2", "blob", "th", "dtm2"]) == ["blob", "th", "dtm2", "adalam", "x"]


# ------------------------------------------------------------------------------------------- setups


def test_setup_rows(frame):
    assert len(report.setup_rows(frame, "global")) == len(frame)
    base = report.setup_rows(frame, "baseline")
    assert set(base.blob) == {"baseline"} and len(base) == len(frame) // 2
    assert set(report.setup_rows(frame, {"blob": "paper-best-overlap"}).blob) == {"paper-best-overlap"}
    assert len(report.setup_rows(frame, {"blob": ("baseline", "paper-best-overlap")})) == len(frame)
    assert len(report.setup_rows(frame.assign(blob="paper-best"), "global")) == 0  # global: the two setups only
    with pytest.raises(ValueError, match="setup must be one of"):
        report.setup_rows(frame, "best-of-all")
    # A frame from `ctxmatch eval` has no features column: that condition is ignored.
    assert len(report.setup_rows(frame.drop(columns="features"), "best")) == len(frame) // 2
    assert report.setup_rows(frame.assign(features="sift"), "best").empty


# ------------------------------------------------------------------------------------------- tables


def test_method_table_exact_values(frame):
    t = report.method_table(frame)
    assert list(t.index.names) == ["kind", "model", "method"]
    assert list(t.columns) == [*report.TABLE_COLUMNS, "pairs"]
    # Paper order: kinds planar first, model none first, blob first then DTM1, DTM2.
    assert list(t.index)[:3] == [("planar", "none", "blob"), ("planar", "none", "dtm1"), ("planar", "none", "dtm2")]
    blob = t.loc[("planar", "none", "blob")]
    # Inlier ratios 0.05, 0.55, 0.25, 0.75 -> mean 0.4.
    assert blob["precision (%)"] == pytest.approx(40.0)
    assert blob["recall (%)"] == pytest.approx(100.0)
    assert blob["recall* (%)"] == pytest.approx(50.0)
    assert blob["time (s)"] == pytest.approx(0.1)
    assert blob["pairs"] == 2
    # p1 fails under both blob setups: 2 failures over 2 setups = 1 per setup.
    assert t.loc[("planar", "none", "dtm1"), "failures"] == pytest.approx(1.0)
    assert t.loc[("nonplanar", "none", "dtm1"), "failures"] == 0
    assert (t["empty"] == 0).all()
    # Time only on the no-model rows, as the paper's "--".
    assert t.xs("1sac", level="model")["time (s)"].isna().all()
    assert t.xs("none", level="model")["time (s)"].notna().all()


def test_method_table_single_setup_counts_failures_plainly(frame):
    t = report.method_table(report.setup_rows(frame, "best"))
    assert t.loc[("planar", "1sac", "dtm1"), "failures"] == 1
    assert t.loc[("planar", "none", "blob"), "precision (%)"] == pytest.approx(15.0)


def test_method_table_counts_empty_outputs_apart_and_skips_errors(frame):
    # p2's dtm2 output is empty under both setups; n1 could not be evaluated for dtm1 under paper-best.
    empty = (frame.pair_id == "p2") & (frame.method == "dtm2")
    frame.loc[empty, ["output", "correct", "precision", "recall"]] = [0, 0, 0.0, 0.0]
    frame["empty_output"] = empty
    frame["error"] = ""
    bad = (frame.pair_id == "n1") & (frame.method == "dtm1") & (frame.blob == "paper-best-overlap")
    frame.loc[bad, ["error", "precision"]] = ["image1 n1.png: 0 keypoints", np.nan]
    t = report.method_table(frame)
    row = t.loc[("planar", "none", "dtm2")]
    assert row["empty"] == 1 and row["failures"] == 0  # one per setup, not a failure
    assert row["precision (%)"] == pytest.approx(40.0)  # (0.8 + 0) / 2: empty counts as 0 %
    assert t.loc[("nonplanar", "none", "dtm1"), "precision (%)"] == pytest.approx(82.0)  # the error row is skipped


def test_method_table_restrict_and_empty(frame):
    t = report.method_table(frame, models=["1sac"], kinds=["nonplanar"])
    assert set(t.index.get_level_values("kind")) == {"nonplanar"}
    assert set(t.index.get_level_values("model")) == {"1sac"}
    empty = report.method_table(frame.iloc[:0])
    assert empty.empty and list(empty.index.names) == ["kind", "model", "method"]


def test_method_table_skips_nan_recall(frame):
    frame.loc[(frame.pair_id == "p1") & (frame.method == "dtm2"), "recall"] = np.nan
    t = report.method_table(report.setup_rows(frame, "best"))
    assert t.loc[("planar", "none", "dtm2"), "recall (%)"] == pytest.approx(90.0)


def test_gt_counts(frame):
    c = report.gt_counts(frame)
    assert list(c.columns) == ["n_gt", "n_gt_star"]
    assert c.loc["planar", "n_gt"] == 100 and c.loc["nonplanar", "n_gt_star"] == 150


def test_markdown_table(frame):
    t = report.method_table(report.setup_rows(frame, "best"))
    md = report.markdown_table(t)
    lines = md.strip().splitlines()
    assert len(lines) == 2 + len(t)
    assert lines[0].startswith("| kind | model | method | precision (%)")
    assert lines[2].startswith("| planar | no model | blob | 15.00 |")
    # Repeated kind and model cells are blank; subscripts are rendered; NaN times are a dash.
    assert lines[3].startswith("|  |  | DTM<sub>1</sub> |")
    assert "| – |" in md
    assert report.markdown_table(t, formats={"precision (%)": ".0f"}).splitlines()[2].startswith(
        "| planar | no model | blob | 15 |")


def test_markdown_table_rows_in_full(frame):
    t = report.method_table(report.setup_rows(frame, "best"))
    lines = report.markdown_table(t, blank_repeats=False, missing="").strip().splitlines()
    assert lines[3].startswith("| planar | no model | DTM<sub>1</sub> |")
    assert "–" not in "".join(lines) and "|  |" in "".join(lines)  # the NaN times


def test_paper_table():
    all_tables = report.paper_table()
    assert len(all_tables) == 3 * 2 * 2 * 18
    t = report.paper_table("global")
    assert list(t.columns) == list(report.TABLE_COLUMNS)
    row = t.loc[("planar", "none", "dtm2")]
    assert row["precision (%)"] == pytest.approx(79.82) and row["recall (%)"] == pytest.approx(78.85)
    assert math.isnan(t.loc[("planar", "1sac", "dtm2"), "time (s)"])
    best = report.paper_table("best")
    assert best.loc[("nonplanar", "1sac", "blob"), "output"] > 0
    with pytest.raises(ValueError, match="setup"):
        report.paper_table("nope")


# ------------------------------------------------------------------------------------------- inlier bins


def test_with_inlier_ratio(frame):
    d = report.with_inlier_ratio(frame)
    assert len(d) == len(frame)
    sel = d[(d.pair_id == "p1") & (d.blob == "paper-best-overlap")]
    assert len(sel) == 6
    assert (sel.inlier_ratio == 0.05).all()
    assert report.with_inlier_ratio(d).equals(d)  # idempotent


def test_inlier_bin_table(frame):
    t = report.inlier_bin_table(frame, bins=(0.0, 0.1, 0.2, 0.3, 1.0))
    assert list(t.index.names) == ["bin", "model", "method"]
    none = t.xs("none", level="model")
    # Cases: 0.05 (p1 best), 0.15 (n1 best), 0.25 (p2 best), 0.55 / 0.65 / 0.75 (baseline).
    assert none.loc[("0-10 %", "blob"), "n"] == 1
    assert none.loc[("0-10 %", "blob"), "precision (%)"] == pytest.approx(5.0)
    assert none.loc[("30-100 %", "dtm2"), "n"] == 3
    share = none.groupby(level="bin", observed=True)["share (%)"].first()
    assert share.sum() == pytest.approx(100.0)
    assert share["30-100 %"] == pytest.approx(50.0)


def test_inlier_bin_table_edges_and_empty_bins(frame):
    frame.loc[(frame.method == "blob") & (frame.model == "none") & (frame.pair_id == "p2"), "precision"] = 1.0
    t = report.inlier_bin_table(frame, bins=(0.0, 0.5, 0.9, 1.0))
    none = t.xs("none", level="model")
    assert none.loc[("90-100 %", "blob"), "n"] == 2  # 1.0 falls in the last, closed bin
    t2 = report.inlier_bin_table(frame, bins=(0.0, 0.01, 1.0))
    empty = t2.xs("none", level="model").loc["0-1 %"]
    assert (empty["n"] == 0).all() and empty["precision (%)"].isna().all()
    with pytest.raises(ValueError, match="increasing"):
        report.inlier_bin_table(frame, bins=(0.5, 0.1))
    with pytest.raises(ValueError, match="at least two"):
        report.inlier_bin_table(frame, bins=(0.5,))


# ------------------------------------------------------------------------------------ evaluate_cached


def test_resolve_filters():
    names = resolve_filters("all")
    assert names[:3] == ("th", "dtm1", "dtm2")
    assert "dtm" not in names and len(set(names)) == len(names)
    assert resolve_filters(["gms", "dtm1"]) == ("gms", "dtm1")
    with pytest.raises(ValueError, match="unknown filter"):
        resolve_filters(["nope"])


def test_select_pairs():
    all_pairs = select_pairs("embedded")
    step2 = select_pairs("embedded", step=2)
    assert len(step2) < len(all_pairs)
    assert {p.kind for p in step2} == {p.kind for p in all_pairs}  # every kind keeps its first pair
    assert [p.pair_id for p in select_pairs("embedded", kinds=["depth"])] == ["depth/motorcycle"]
    ids = ["nonplanar/cards", "planar/poster/1-3"]
    assert [p.pair_id for p in select_pairs("embedded", pair_ids=ids)] == ids
    assert [p.pair_id for p in select_pairs(all_pairs, pair_ids=ids)] == ids
    with pytest.raises(ValueError, match="pair_ids"):
        select_pairs("embedded", pair_ids=["nope"])
    with pytest.raises(ValueError, match="step"):
        select_pairs("embedded", step=0)


def test_evaluate_cached_reads_back(tmp_path, monkeypatch):
    from ctxmatch_lib.evaluation import SWEEP_COLUMNS

    pairs = select_pairs("embedded", pair_ids=["planar/poster/1-2"])
    kw = dict(blobs=["baseline"], filters=["th"], models=["none"], cache_dir=tmp_path)
    first = evaluate_cached(pairs, **kw)
    assert list(first.columns) == list(SWEEP_COLUMNS) and set(ROW_COLUMNS) <= set(first.columns)
    assert set(first.method) == {"blob", "th"} and (first.features == "sift-rootsift").all()
    assert set(first.blob) == {"baseline"}  # preset names, as the report's SETUPS select them
    assert len(list((tmp_path / "results").glob("*.parquet"))) == 1

    def boom(*args, **kwargs):
        raise AssertionError("run_unit called despite a cache hit")

    monkeypatch.setattr("ctxmatch_lib.evaluation.run.run_unit", boom)  # where run_units looks it up
    again = evaluate_cached(pairs, **kw)
    pd.testing.assert_frame_equal(first, again)
    # Another setting is another key; cache=False never reads.
    with pytest.raises(AssertionError, match="cache hit"):
        evaluate_cached(pairs, **{**kw, "models": ["1sac"]})
    with pytest.raises(AssertionError, match="cache hit"):
        evaluate_cached(pairs, **{**kw, "cache": False})


def test_evaluate_cached_no_pairs(tmp_path):
    out = evaluate_cached([], filters=["th"], cache_dir=tmp_path)
    assert out.empty and "features" in out.columns
