"""The per-pair pipeline and ``ctxmatch eval`` end to end on a tiny dataset synthesised in tmp_path."""

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib.datasets.base import HomographyGT, Pair
from ctxmatch_lib.features import Features
from ctxmatch_lib.filters import register_filter
from ctxmatch_lib.geometry import apply_homography
from ctxmatch_lib.pipeline import (
    ROW_COLUMNS,
    evaluate_dataset,
    evaluate_pair,
    summary_table,
)

H_TRUE = np.array([[0.95, -0.08, 25.0], [0.06, 1.02, -10.0], [1e-4, -5e-5, 1.0]])
REQUIRED = ["pair_id", "kind", "method", "model", "precision", "recall", "correct", "output", "failure", "time_s"]


@register_filter("test-first-half")
def _first_half(kpts1, kpts2, matches, scores, *, image_size1, image_size2, shapes1=None, shapes2=None):
    """A trivial filter for the plumbing tests: keeps the better-ranked half."""
    keep = np.zeros(len(matches), bool)
    keep[: len(matches) // 2] = True
    return keep


# ------------------------------------------------------------------------------ synthetic features


def _features(kpts, desc):
    n = len(kpts)
    return Features(np.asarray(kpts, float), np.tile(2 * np.eye(2), (n, 1, 1)), desc.astype(np.float32),
                    np.full(n, 2.0), np.zeros(n), np.linspace(1, 0, n))


def _planted_pair(n_in=120, n_out=80, rng=0):
    """Keypoints and descriptors where the first ``n_in`` keypoints correspond through ``H_TRUE``."""
    rng = np.random.default_rng(rng)
    k1 = rng.uniform([40, 40], [600, 440], (n_in + n_out, 2))
    k2 = rng.uniform([0, 0], [639, 479], (n_in + n_out, 2))
    k2[:n_in] = apply_homography(H_TRUE, k1[:n_in])
    d1 = rng.normal(size=(n_in + n_out, 128))
    d2 = rng.normal(size=(n_in + n_out, 128))
    d2[:n_in] = d1[:n_in] + 0.3 * rng.normal(size=(n_in, 128))
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    pair = Pair("synthetic/h", Path("none1.png"), Path("none2.png"), (640, 480), (640, 480), "planar",
                HomographyGT(H_TRUE), dataset="synthetic")
    return pair, (_features(k1, d1), _features(k2, d2))


def test_evaluate_pair_rows_and_intermediates():
    pair, feats = _planted_pair()
    ev = evaluate_pair(pair, blobs=["paper-best", "baseline"], filters=["test-first-half"],
                       models=["none", "1sac", "ransac"], precomputed_features=feats)
    assert len(ev.rows) == 2 * 2 * 3  # blob setups x (blob + 1 filter) x models
    df = pd.DataFrame(ev.rows)
    assert list(df.columns) == list(ROW_COLUMNS)
    stage = ev.stages["paper-best"]
    # Candidates: every planted pair's keypoints are nearest neighbours, so each correct match is found.
    assert stage.labels.sum() >= 110
    blob_none = df[(df.blob == "paper-best") & (df.method == "blob") & (df.model == "none")].iloc[0]
    assert blob_none.recall == 1.0 and blob_none.output == len(stage.matches)
    assert blob_none.correct == stage.labels.sum()
    # The filter's output is the first half of the candidates; the model masks that output further.
    half = ev.stages["paper-best"].final_mask("test-first-half", "none")
    assert half.sum() == len(stage.matches) // 2 and half[: half.sum()].all()
    sac = stage.final_mask("test-first-half", "1sac")
    assert not (sac & ~half).any()
    # The planted homography is easy: 1SAC keeps the correct matches and drops most wrong ones.
    row = df[(df.blob == "paper-best") & (df.method == "blob") & (df.model == "1sac")].iloc[0]
    assert row.precision > 0.9 and row.recall > 0.9
    # recall* uses the union over both blob setups: never above the recall.
    assert (df.recall_star <= df.recall + 1e-12).all()
    assert (df.n_gt_star >= df.n_gt).all()
    # Seeded RANSAC: the same pair gives the same rows.
    again = evaluate_pair(pair, blobs=["paper-best", "baseline"], filters=["test-first-half"],
                          models=["none", "1sac", "ransac"], precomputed_features=feats)
    pd.testing.assert_frame_equal(df.drop(columns=["time_s", "model_time_s"]),
                                  pd.DataFrame(again.rows).drop(columns=["time_s", "model_time_s"]))


def test_evaluate_pair_without_correct_candidates_and_without_keypoints():
    pair, feats = _planted_pair()
    # A wrong homography: no candidate is correct, so recall is undefined and every row fails.
    wrong = Pair(pair.pair_id, pair.image1, pair.image2, pair.image_size1, pair.image_size2, "planar",
                 HomographyGT(np.array([[1.0, 0, 300], [0, 1, 200], [0, 0, 1]])))
    df = pd.DataFrame(evaluate_pair(wrong, filters=[], models=["none", "1sac"], precomputed_features=feats).rows)
    assert df.failure.all() and df.recall.isna().all() and (df.n_gt == 0).all()
    empty = (Features.empty(), Features.empty())
    df = pd.DataFrame(evaluate_pair(pair, filters=["test-first-half"], models=["none", "1sac"],
                                    precomputed_features=empty).rows)
    # No keypoints: every output is empty, which is reported as empty, not as a failure.
    assert len(df) == 4 and (df.output == 0).all() and df.empty_output.all() and not df.failure.any()


def test_pipeline_rejects_bad_names():
    pair, feats = _planted_pair()
    with pytest.raises(ValueError, match="unknown filter 'nope'"):
        evaluate_pair(pair, filters=["nope"], precomputed_features=feats)
    with pytest.raises(ValueError, match="unknown model 'lmeds'"):
        evaluate_pair(pair, filters=[], models=["lmeds"], precomputed_features=feats)
    with pytest.raises(ValueError, match="unknown blob preset 'best'"):
        evaluate_pair(pair, blobs="best", filters=[], precomputed_features=feats)
    with pytest.raises(ValueError, match="gt_method"):
        evaluate_pair(pair, filters=[], gt_method="Z", precomputed_features=feats)


def test_summary_table_means_and_order():
    df = pd.DataFrame({
        "pair_id": ["a", "a", "b", "b"], "kind": "planar", "blob": "paper-best",
        "method": ["blob", "dtm", "blob", "dtm"], "model": "none",
        "precision": [0.5, 1.0, 0.3, float("nan")], "recall": [1.0, 0.5, 1.0, 0.0], "recall_star": 1.0,
        "ap": [0.5, 0.4, 0.7, 0.0], "correct": [10, 5, 6, 0], "output": [20, 5, 20, 0],
        "correct_norm": [9, 5, 6, 0], "failure": [False, False, False, False],
        "empty_output": [False, False, False, True], "time_s": [0.1, 0.2, 0.1, 0.2],
        "model_time_s": [0.01, 0.02, 0.03, 0.04], "error": "",
    })
    t = summary_table(df)
    assert list(t.index.get_level_values("method")) == ["blob", "dtm"]
    assert list(t.columns) == ["pairs", "precision_pct", "recall_pct", "recall_star_pct", "mAP_pct", "correct",
                               "correct_norm", "output", "failures", "empty_outputs", "time_s", "model_time_s",
                               "errors"]
    assert t.loc[("planar", "dtm", "none"), "failures"] == 0
    assert t.loc[("planar", "dtm", "none"), "empty_outputs"] == 1
    assert t.loc[("planar", "blob", "none"), "precision_pct"] == pytest.approx(40.0)
    assert t.loc[("planar", "dtm", "none"), "recall_pct"] == pytest.approx(25.0)
    assert t.loc[("planar", "blob", "none"), "correct_norm"] == pytest.approx(7.5)
    assert t.loc[("planar", "blob", "none"), "model_time_s"] == pytest.approx(0.02)
    # A row that could not be evaluated is counted under errors and left out of the means.
    bad = pd.concat([df, df.iloc[[0]].assign(pair_id="c", precision=float("nan"), error="image1 x.png: 0 keypoints")])
    tb = summary_table(bad)
    assert tb.loc[("planar", "blob", "none"), "errors"] == 1 and tb.loc[("planar", "blob", "none"), "pairs"] == 2
    assert tb.loc[("planar", "blob", "none"), "precision_pct"] == pytest.approx(40.0)
    assert summary_table(df.iloc[:0]).empty


# ------------------------------------------------------------------------- ctxmatch eval end to end


def _texture(h=240, w=320, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    img = rng.uniform(0, 255, (h // 8, w // 8)).astype(np.float32)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)
    img += rng.normal(0, 20, (h, w))
    return np.clip(cv2.GaussianBlur(img, (0, 0), 1.2), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """Two pairs in the custom format: a homography warp and a two-layer rectified 'stereo' pair."""
    import cv2

    root = tmp_path_factory.mktemp("tiny")
    img = _texture()
    H = np.array([[0.97, -0.05, 8.0], [0.04, 1.0, -5.0], [5e-5, 0.0, 1.0]])
    cv2.imwrite(str(root / "p1.png"), img)
    cv2.imwrite(str(root / "p2.png"), cv2.warpPerspective(img, H, (320, 240)))
    np.savetxt(root / "H.txt", H)
    # Non-planar: left half shifts 6 px, right half 14 px (two depths); epipolar lines are the rows.
    s2 = np.empty_like(img)
    s2[:, :160] = np.roll(img, -6, axis=1)[:, :160]
    s2[:, 160:] = np.roll(img, -14, axis=1)[:, 160:]
    cv2.imwrite(str(root / "s2.png"), s2)
    hand1 = np.array([[x, y] for x in (30.0, 90.0, 150.0, 200.0, 260.0, 300.0) for y in (30.0, 120.0, 210.0)])
    hand2 = hand1 - np.where(hand1[:, :1] < 160, 6.0, 14.0) * [1.0, 0.0]
    np.savetxt(root / "hand.txt", np.c_[hand1, hand2])
    np.savetxt(root / "F.txt", np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]]))
    (root / "pairs.csv").write_text(
        "pair_id,image1,image2,kind,gt,F\n"
        "warp,p1.png,p2.png,planar,H.txt,\n"
        "layers,p1.png,s2.png,nonplanar,hand.txt,F.txt\n"
    )
    return root


def _cli(argv):
    from ctxmatch_lib.cli import eval as eval_cli

    parser = argparse.ArgumentParser(prog="ctxmatch")
    eval_cli.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["eval", *argv])
    return args.func(args)


def test_cli_eval_end_to_end(tiny_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "res" / "results.parquet"
    rc = _cli(["--dataset", str(tiny_dataset), "--blob", "paper-best", "--filters", "th,test-first-half",
               "--model", "none,1sac,ransac", "--out", str(out), "--max-keypoints", "600", "--no-progress"])
    assert rc == 0
    df = pd.read_parquet(out)
    assert set(REQUIRED) <= set(df.columns)
    assert len(df) == 2 * 3 * 3
    assert set(df.method) == {"blob", "th", "test-first-half"} and set(df.model) == {"none", "1sac", "ransac"}
    assert set(df.kind) == {"planar", "nonplanar"}
    blob = df[(df.method == "blob") & (df.model == "none")].set_index("pair_id")
    # Both synthetic pairs are easy: many correct candidates, full recall for the unfiltered set.
    assert (blob.correct > 50).all() and (blob.recall == 1.0).all()
    sac = df[(df.method == "blob") & (df.model == "1sac")].set_index("pair_id")
    assert (sac.precision > blob.precision).all()
    import pyarrow.parquet as pq

    assert b"ctxmatch" in pq.read_schema(out).metadata
    assert not list(out.parent.glob(".*.tmp"))  # atomic write leaves no temporary file
    text = capsys.readouterr().out
    assert "precision" in text and "nonplanar" in text and "test-first-half" in text


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--filters", "nope"], "unknown filter 'nope'"),
        (["--model", "none,lmeds"], "unknown model 'lmeds'"),
        (["--blob", "best"], "unknown blob preset 'best'"),
        (["--out", "results.csv"], "--out must end with .parquet"),
    ],
)
def test_cli_eval_bad_arguments(tiny_dataset, tmp_path, capsys, argv, message):
    argv = ["--dataset", str(tiny_dataset), "--out", str(tmp_path / "r.parquet"), "--no-progress", "--filters", "th",
            *argv]
    assert _cli(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "r.parquet").exists()


def test_cli_eval_missing_dataset(tmp_path, capsys):
    assert _cli(["--dataset", str(tmp_path / "nowhere"), "--filters", "none", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot load dataset" in err and "nowhere" in err


def test_eval_registered_in_cli():
    from ctxmatch_lib.cli import _COMMANDS

    assert "eval" in _COMMANDS


def test_evaluate_dataset_with_dtm_on_tiny_dataset(tiny_dataset, tmp_path, monkeypatch):
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    df = evaluate_dataset(load_dataset(str(tiny_dataset)), progress=False, features=FeatureConfig(max_keypoints=600),
                          filters=["dtm"], models=["none", "1sac"])
    dtm = df[(df.method == "dtm") & (df.model == "none")]
    blob = df[(df.method == "blob") & (df.model == "none")]
    assert len(dtm) == 2 and (dtm.precision.values >= blob.precision.values).all()


# ------------------------------------------------------------------------------ nothing lost, one engine


@register_filter("test-raises")
def _raises(kpts1, kpts2, matches, scores, *, image_size1, image_size2, shapes1=None, shapes2=None):
    """A filter that fails on every pair whose first keypoint lies in the left half (the plumbing test)."""
    raise RuntimeError("deliberate failure")


@pytest.fixture
def broken_dataset(tiny_dataset, tmp_path):
    """The tiny dataset plus a pair with a truncated PNG and a pair whose image has no keypoints."""
    import shutil

    import cv2

    root = tmp_path / "broken"
    shutil.copytree(tiny_dataset, root)
    data = (root / "p2.png").read_bytes()
    (root / "cut.png").write_bytes(data[: len(data) // 2])
    cv2.imwrite(str(root / "flat.png"), np.full((240, 320), 128, np.uint8))
    with open(root / "pairs.csv", "a") as fh:
        fh.write("truncated,p1.png,cut.png,planar,H.txt,\nflat,flat.png,p2.png,planar,H.txt,\n")
    return root


def test_cli_eval_keeps_going_past_broken_pairs(broken_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    rc = _cli(["--dataset", str(broken_dataset), "--filters", "th,test-raises", "--model", "none,1sac",
               "--max-keypoints", "600", "--out", str(out), "--no-progress"])
    assert rc == 0
    df = pd.read_parquet(out)
    # Every pair is in the output; the good ones are evaluated, the broken ones say why.
    assert set(df.pair_id) == {"warp", "layers", "truncated", "flat"}
    good = df[df.pair_id.isin(["warp", "layers"]) & (df.method != "test-raises")]
    assert (good.error == "").all() and good.precision.notna().all()
    raised = df[(df.method == "test-raises") & df.pair_id.isin(["warp", "layers"])]
    assert raised.error.str.contains("filter 'test-raises' raised RuntimeError: deliberate failure").all()
    assert raised.precision.isna().all()
    cut = df[df.pair_id == "truncated"].error.unique()
    assert len(cut) == 1 and "image2" in cut[0] and "cut.png" in cut[0] and "cannot be read" in cut[0]
    flat = df[df.pair_id == "flat"].error.unique()
    assert len(flat) == 1 and "image1" in flat[0] and "flat.png" in flat[0] and "0 keypoints" in flat[0]
    err = capsys.readouterr().err
    assert "truncated" in err and "cut.png" in err and "flat.png: 0 keypoints" in err
    # Finished pairs are kept as parts; failed ones are not, so the next run tries them again.
    parts = list((tmp_path / "cache" / "sweep" / "results").glob("*.parquet"))
    assert len(parts) == 0  # both good pairs carry the test-raises error rows


def test_evaluate_dataset_warns_with_pair_and_reason(broken_dataset, tmp_path):
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    with pytest.warns(RuntimeWarning, match=r"flat: image1 .*flat\.png: 0 keypoints"):
        df = evaluate_dataset(load_dataset(str(broken_dataset)), progress=False, results_dir=tmp_path / "res",
                              cache_dir=tmp_path / "feat", features=FeatureConfig(max_keypoints=600),
                              filters=["th"], models=["none"])
    assert set(ROW_COLUMNS) <= set(df.columns)
    assert (df.loc[df.pair_id.isin(["warp", "layers"]), "error"] == "").all()
    assert len(list((tmp_path / "res" / "results").glob("*.parquet"))) == 2  # the two good pairs


@pytest.mark.parametrize("argv, message", [
    (["--gt-threshold", "-1"], "--gt-threshold must be a positive number"),
    (["--model-threshold", "0"], "--model-threshold must be a positive number"),
    (["--gt-threshold", "nan"], "--gt-threshold"),
    (["--max-keypoints", "-5"], "--max-keypoints"),
    (["--max-keypoints", "sparse"], "--max-keypoints must be a non-negative integer or a budget name (paper, dense)"),
    (["--seed", "-1"], "--seed"),
    (["--runs", "0"], "--runs must be a positive number of estimator runs"),
    (["--limit", "0"], "--limit"),
    (["--model-threshold", "-1"], "--model-threshold must be a positive number"),
    (["--jobs", "0"], "--jobs must be a positive number"),
    (["--jobs", "2", "--dask", "tcp://localhost:8786"], "--dask"),
    (["--filters", "all,nope"], "--filters: 'all' and 'none' stand alone"),
    (["--pairs", "no-such-pair"], "--pairs: unknown pair ids"),
    (["--kind", "planar,flat"], "--kind must be among planar, nonplanar, depth, calibrated, got flat"),
    (["--gt", "Z"], None),
])
def test_cli_eval_validates_before_any_work(tiny_dataset, tmp_path, monkeypatch, capsys, argv, message):
    import ctxmatch_lib.features as features

    monkeypatch.setattr(features.cache, "_extract", lambda *a, **k: pytest.fail("features computed for bad arguments"))
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    if message is None:  # a choice argparse refuses (exit status 2, its own message naming the flag)
        with pytest.raises(SystemExit) as exc:
            _cli(["--dataset", str(tiny_dataset), "--out", str(tmp_path / "r.parquet"), "--no-progress", *argv])
        assert exc.value.code == 2 and "--gt" in capsys.readouterr().err
        return
    assert _cli(["--dataset", str(tiny_dataset), "--out", str(tmp_path / "r.parquet"), "--no-progress", *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "r.parquet").exists()


def test_cli_eval_accepts_dtm_stages_and_prints_units(tiny_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    assert _cli(["--dataset", str(tiny_dataset), "--filters", "dtm1,dtm2", "--model", "none", "--limit", "1",
                 "--max-keypoints", "600", "--out", str(out), "--no-progress"]) == 0
    df = pd.read_parquet(out)
    assert set(df.method) == {"blob", "dtm1", "dtm2"} and (df.error == "").all()
    assert df.precision.between(0, 1).all()  # fractions in the file
    text = capsys.readouterr().out
    for col in ("precision_pct", "recall_pct", "correct_norm", "model_time_s", "failures", "empty_outputs"):
        assert col in text


def test_output_files_honour_the_umask(tiny_dataset, tmp_path, monkeypatch):
    import os
    import stat

    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    old = os.umask(0o022)
    try:
        assert _cli(["--dataset", str(tiny_dataset), "--filters", "th", "--model", "none", "--limit", "1",
                     "--max-keypoints", "600", "--out", str(out), "--no-progress"]) == 0
        os.umask(0o027)
        out2 = tmp_path / "r2.parquet"
        assert _cli(["--dataset", str(tiny_dataset), "--filters", "th", "--model", "none", "--limit", "1",
                     "--max-keypoints", "600", "--out", str(out2), "--no-progress"]) == 0
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o644
    assert stat.S_IMODE(out2.stat().st_mode) == 0o640
    parts = list((tmp_path / "cache").rglob("*.parquet")) + list((tmp_path / "cache").rglob("*.npz"))
    assert parts and all(stat.S_IMODE(p.stat().st_mode) == 0o644 for p in parts)


def test_progress_bar_names_the_pair_in_progress(tiny_dataset, tmp_path, monkeypatch):
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    shown, seen = [], []
    orig_set = __import__("tqdm").std.tqdm.set_postfix_str
    monkeypatch.setattr(__import__("tqdm").std.tqdm, "set_postfix_str",
                        lambda self, s="", refresh=True: shown.append(s) or orig_set(self, s, refresh))
    from ctxmatch_lib.evaluation import run as ev_run

    orig = ev_run.run_unit
    monkeypatch.setattr(ev_run, "run_unit", lambda unit, **kw: seen.append(shown[-1]) or orig(unit, **kw))
    evaluate_dataset(load_dataset(str(tiny_dataset)), progress=True, results_dir=tmp_path,
                     features=FeatureConfig(max_keypoints=300), filters=[], models=["none"])
    # While each pair runs, the bar shows that pair (not the one before it).
    assert [s.split("/")[-1].split(" ")[0] for s in seen] == ["warp", "layers"]


def test_cli_eval_resumes_after_sigkill(tiny_dataset, tmp_path, monkeypatch, kill_after_first_part):
    """A real kill -9 of `ctxmatch eval` mid-run; the rerun completes it with no lost or duplicated row."""
    import os
    import shutil
    import subprocess
    import sys

    root = tmp_path / "four"
    shutil.copytree(tiny_dataset, root)
    with open(root / "pairs.csv", "a") as fh:
        fh.write("warp2,p2.png,p1.png,planar,H.txt,\nwarp3,p1.png,p2.png,planar,H.txt,\n"
                 "layers2,p1.png,s2.png,nonplanar,hand.txt,F.txt\n")
    argv = ["--dataset", str(root), "--filters", "th", "--model", "none,1sac", "--max-keypoints", "300",
            "--no-progress"]
    env = {**os.environ, "CTXMATCH_CACHE": str(tmp_path / "killed"), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "ctxmatch_lib.cli", "eval", *argv, "--out",
                             str(tmp_path / "a.parquet")], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    n_parts = kill_after_first_part(proc, tmp_path / "killed" / "sweep" / "results", 0.02)
    assert 1 <= n_parts <= 5
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "killed"))
    assert _cli([*argv, "--out", str(tmp_path / "a.parquet")]) == 0
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "fresh"))
    assert _cli([*argv, "--out", str(tmp_path / "b.parquet")]) == 0
    resumed, fresh = pd.read_parquet(tmp_path / "a.parquet"), pd.read_parquet(tmp_path / "b.parquet")
    keys = ["pair_id", "blob", "method", "model"]
    assert not resumed.duplicated(keys).any() and len(resumed) == 5 * 2 * 2
    drop = ["time_s", "model_time_s"]
    pd.testing.assert_frame_equal(resumed.drop(columns=drop), fresh.drop(columns=drop))


def test_keypoints_outside_the_image_size_are_rejected(tiny_dataset, tmp_path):
    from ctxmatch_lib._numerics.validation import check_inside

    pair, feats = _planted_pair()
    swapped = Pair(pair.pair_id, pair.image1, pair.image2, (480, 640), pair.image_size2, "planar", pair.gt)
    with pytest.raises(ValueError, match=r"\(width, height\) = \(480, 640\).*\(height, width\)"):
        evaluate_pair(swapped, filters=[], precomputed_features=feats)
    # Pixel centres: x in [-0.5, w - 0.5] is inside, beyond is not.
    assert len(check_inside([[-0.5, -0.5], [639.5, 479.5]], (640, 480))) == 2
    with pytest.raises(ValueError, match="kpts outside"):
        check_inside([[639.6, 0.0]], (640, 480), "kpts outside")
    assert check_inside(np.empty((0, 2)), (640, 480)).shape == (0, 2)
    # In a dataset run the pair is reported (the convention in the message) and the run goes on.
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    good = load_dataset(str(tiny_dataset)).pairs[0]
    bad = Pair("swapped", good.image1, good.image2, good.image_size1[::-1], good.image_size2, good.kind, good.gt,
               dataset=good.dataset)
    with pytest.warns(RuntimeWarning, match="swapped"):
        df = evaluate_dataset([good, bad], progress=False, results_dir=tmp_path / "res", filters=[],
                              models=["none"], features=FeatureConfig(max_keypoints=300))
    assert (df.loc[df.pair_id == good.pair_id, "error"] == "").all()
    assert df.loc[df.pair_id == "swapped", "error"].str.contains(r"\(width, height\) = \(240, 320\)").all()


# ------------------------------------------------------------------ one command surface, one cache


@pytest.mark.parametrize("command", ["eval", "sweep"])
def test_cli_out_is_checked_before_any_work(command, tmp_path, monkeypatch, capsys):
    """`--out DIR/x.parquet` with DIR a regular file fails at once, naming --out (no traceback after the run)."""
    import ctxmatch_lib.features as features
    from ctxmatch_lib.cli import main

    monkeypatch.setattr(features.cache, "_extract", lambda *a, **k: pytest.fail("features computed for a bad --out"))
    (tmp_path / "DIR").write_text("a file, not a folder")
    argv = [command, "--pairs", "1", "--blob", "paper-best", "--cache-dir", str(tmp_path / "c"), "--no-progress"]
    assert main([*argv, "--out", str(tmp_path / "DIR" / "x.parquet")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "DIR" in err and "Traceback" not in err
    assert main([*argv, "--out", str(tmp_path)]) == 2  # a folder where the file goes
    assert "--out" in capsys.readouterr().err
    assert not (tmp_path / "c" / "results").exists()


def test_eval_and_sweep_share_flags_and_units(tmp_path, monkeypatch, capsys):
    """`ctxmatch sweep`, then `ctxmatch eval` with the same settings: eval computes nothing, same numbers."""
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.evaluation import run as ev_run

    same = ["--dataset", "embedded", "--pairs", "2", "--blob", "paper-best", "--filters", "th",
            "--model", "none,1sac", "--max-keypoints", "300", "--cache-dir", str(tmp_path / "cache"), "--no-progress"]
    assert main(["sweep", *same, "--out", str(tmp_path / "s.parquet")]) == 0
    monkeypatch.setattr(ev_run, "run_unit", lambda *a, **k: pytest.fail("eval recomputed a unit sweep computed"))
    assert main(["eval", *same, "--out", str(tmp_path / "e.parquet")]) == 0
    capsys.readouterr()
    s, e = pd.read_parquet(tmp_path / "s.parquet"), pd.read_parquet(tmp_path / "e.parquet")
    assert len(e) == 2 * 2 * 2
    pd.testing.assert_frame_equal(s[list(e.columns)], e)
    # And the reverse: after eval, a sweep over the same units reads them (the returned count says so).
    monkeypatch.undo()
    from ctxmatch_lib.evaluation import run_sweep

    again = run_sweep("embedded", blobs=["paper-best"], filters=["th"], models=["none", "1sac"], pairs=2,
                      max_keypoints=300, cache_dir=tmp_path / "cache", progress=False)
    assert again.attrs["units_computed"] == 0 and again.attrs["units"] == 2


def test_eval_accepts_all_filters_and_several_datasets(tmp_path):
    """--filters all and several --dataset values plan as in ctxmatch sweep (no work done here)."""
    from ctxmatch_lib.cli import main  # noqa: F401  (the parser is built the way main builds it)
    from ctxmatch_lib.cli import eval as eval_cli
    from ctxmatch_lib.cli._engine_args import plan, resolve_args
    from ctxmatch_lib.evaluation import resolve_filters

    parser = argparse.ArgumentParser(prog="ctxmatch")
    eval_cli.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["eval", "--dataset", "embedded,embedded", "--filters", "all", "--pairs", "1",
                              "--out", str(tmp_path / "r.parquet")])
    settings, msg = resolve_args(args)
    assert msg is None and settings["filters"] == resolve_filters("all")
    units, msg = plan(args, settings)
    assert msg is None and len(units) == 2 and units[0].filters == resolve_filters("all")


def test_engine_rows_identical_to_before_the_refactor():
    """The rows of the engine, recomputed now, against those computed before its refactor into units.

    tests/data/engine_rows_before.csv was written by the engine as it was before (commit 4315919): the eval
    path (2 embedded pairs, paper-best + baseline, filters dtm/th/adalam, models none/1sac, 400 keypoints)
    and the sweep path (39 grid setups with every t_o kind, 1 pair, 300 keypoints). Every column but the
    running times is compared as text written with 17 significant digits, i.e. bit for bit. The 8 AdaLAM rows
    were rewritten once, when AdaLAM's defaults were aligned with kornia's AdaLAM, and the AP of 5
    rows once, when blob matching's scores became exact float64 distances instead of float32 GEMM values (the
    AP ranks by score, and scores moved by under 1e-5, reordering near ties; AP moved by under 6e-6,
    every other column stayed bit for bit). Every row was rewritten once more when the features and the
    embedded dataset were made the same on any CPU (dataset version 2: new images; features from IEEE basic
    operations and OpenCV's baseline build): the inputs changed, the engine did not, and the rows are again
    compared bit for bit.
    """
    import io

    from ctxmatch_lib.blob import blob_grid
    from ctxmatch_lib.evaluation import run_sweep, select_pairs
    from ctxmatch_lib.features import FeatureConfig

    pairs = select_pairs("embedded")
    pp = [pairs[0], pairs[16]]
    df1 = evaluate_dataset(pp, features=FeatureConfig(max_keypoints=400), blobs=["paper-best", "baseline"],
                           filters=("dtm", "th", "adalam"), models=("none", "1sac"), results_dir=False,
                           progress=False)
    grid = [c for c in blob_grid() if c.candidate_key in {(1, "cup", 1), (10, "cup", 5), (3, "cap", 3)}][::7]
    df2 = run_sweep("embedded", blobs=grid, pairs=[pp[1].pair_id], max_keypoints=300, cache_dir=False,
                    progress=False)
    df1["source"], df2["source"] = "eval", "sweep"
    from ctxmatch_lib.evaluation.rows import GEOMETRY_COLUMNS  # added after the reference, as "run"

    df = pd.concat([df1, df2], ignore_index=True).drop(columns=["time_s", "model_time_s", "run", *GEOMETRY_COLUMNS])
    buf = io.StringIO()
    df.to_csv(buf, index=False, float_format="%.17g")
    before = (Path(__file__).parent / "data" / "engine_rows_before.csv").read_text()
    got, ref = buf.getvalue().splitlines(), before.splitlines()
    assert got[0] == ref[0] and len(got) == len(ref) == 1 + 32 + 39
    diff = [(i, a, b) for i, (a, b) in enumerate(zip(got, ref)) if a != b]
    assert not diff, diff[:3]


@pytest.mark.parametrize("gt", ["C", "B"])
def test_eval_gt_region_methods_on_a_hand_point_pair(tmp_path, monkeypatch, capsys, gt):
    """``ctxmatch eval --gt C`` (and B) on a non-planar pair whose ground truth is hand points (EpipolarGT).

    The embedded non-planar pairs carry dense flow, so a custom folder is built: the images of
    nonplanar/cards and 24 correspondences sampled from its flow as the ``x1 y1 x2 y2`` hand points.
    C adds the centre-distance rule to B's overlap error (Appendix "Ground truth estimation methods"),
    both through the hand-point map, and the paper notes C finds fewer correct matches than D.
    """
    import shutil

    from ctxmatch_lib.cli import main
    from ctxmatch_lib.datasets import load_dataset

    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    src = {p.pair_id: p for p in load_dataset("embedded-nonplanar")}["nonplanar/cards"]
    folder = tmp_path / "hand"
    folder.mkdir()
    shutil.copy(src.image1, folder / "a.png")
    shutil.copy(src.image2, folder / "b.png")
    flow = src.gt.flow12
    rows, cols = np.nonzero(~np.isnan(flow[..., 0]))
    pick = np.random.default_rng(0).choice(len(rows), 24, replace=False)
    r, c = rows[pick], cols[pick]
    np.savetxt(folder / "pts.txt", np.c_[c, r, c + flow[r, c, 0], r + flow[r, c, 1]])
    (folder / "pairs.csv").write_text("pair_id,image1,image2,kind,gt\ncards,a.png,b.png,nonplanar,pts.txt\n")
    assert type(load_dataset(folder)[0].gt).__name__ == "EpipolarGT"

    common = ["eval", "--dataset", str(folder), "--blob", "paper-best", "--filters", "dtm", "--max-keypoints", "300",
              "--cache-dir", str(tmp_path / "cache"), "--no-progress"]
    out = {}
    for g in (gt, "D"):
        assert main([*common, "--gt", g, "--out", str(tmp_path / f"{g}.parquet")]) == 0
        out[g] = pd.read_parquet(tmp_path / f"{g}.parquet")
    capsys.readouterr()
    df, d = out[gt], out["D"]
    assert (df.gt_method == gt).all() and (d.gt_method == "D").all()
    assert (df.error == "").all() and set(df.kind) == {"nonplanar"}
    assert set(df.method) >= {"blob", "dtm"}
    assert (df.n_gt > 0).all()
    assert df.n_candidates.iloc[0] == d.n_candidates.iloc[0]  # the same candidates, labelled two ways
    if gt == "C":
        assert df.n_gt.iloc[0] <= d.n_gt.iloc[0]


def test_gt_threshold_is_refused_with_the_region_methods(tmp_path, capsys):
    """B and C have fixed thresholds: a --gt-threshold would only change the cache key, not a number."""
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.evaluation import plan_units

    for cmd in ("eval", "sweep"):
        rc = main([cmd, "--dataset", "embedded", "--gt", "C", "--gt-threshold", "10",
                   "--out", str(tmp_path / f"{cmd}.parquet")])
        assert rc == 2 and "--gt-threshold applies to --gt D and A only" in capsys.readouterr().err
    with pytest.raises(ValueError, match="gt_threshold applies to methods D and A only"):
        plan_units([], gt_method="B", gt_threshold=7.0)


_COUNTED: list[int] = []


@register_filter("test-counting")
def _counting_filter(kpts1, kpts2, matches, scores, **kw):
    _COUNTED.append(len(matches))
    return np.arange(len(matches)) % 2 == 0


def test_run_filter_times_after_a_warm_up_call():
    # The first call of a filter in a process runs it once untimed (kernels compile there), then the timed
    # call; later calls run it once. The output is the filter's.
    from ctxmatch_lib.evaluation.steps import run_filter

    z = np.zeros(3)
    f = Features(kpts=np.zeros((3, 2)), shapes=np.tile(np.eye(2), (3, 1, 1)), desc=np.zeros((3, 4), np.float32),
                 scales=z + 1, angles=z, responses=z)
    m = np.array([[0, 0], [1, 1], [2, 2]])
    _COUNTED.clear()
    keep, t = run_filter("test-counting", f, f, m, z, image_size1=(10, 10), image_size2=(10, 10))
    assert _COUNTED == [3, 3] and t >= 0
    np.testing.assert_array_equal(keep, [True, False, True])
    run_filter("test-counting", f, f, m, z, image_size1=(10, 10), image_size2=(10, 10))
    assert _COUNTED == [3, 3, 3]


def test_cli_eval_ranks_a_filter_given_by_its_import_path(tiny_dataset, tmp_path, monkeypatch, capsys):
    # A filter defined outside the package, named by module:function: its rows carry the path, it sees the
    # same candidates as the others (keep-all: the blob's numbers), and editing it recomputes its rows only.
    import sys

    module = tmp_path / "userfilters_eval.py"
    module.write_text("import numpy as np\n\n\ndef keep(kpts1, kpts2, matches, scores, *, image_size1, image_size2, "
                      "shapes1=None, shapes2=None):\n    return np.ones(len(matches), bool)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    argv = ["--dataset", str(tiny_dataset), "--filters", "th,userfilters_eval:keep", "--model", "none",
            "--out", str(out), "--max-keypoints", "600", "--no-progress"]
    try:
        assert _cli(argv) == 0
        df = pd.read_parquet(out).set_index(["pair_id", "method"])
        assert set(df.index.get_level_values("method")) == {"blob", "th", "userfilters_eval:keep"}
        for col in ("precision", "recall", "output", "correct"):
            assert (df.xs("userfilters_eval:keep", level="method")[col] == df.xs("blob", level="method")[col]).all()
        assert "userfilters_eval:keep" in capsys.readouterr().out
        # The filter's code is part of its rows' key: keep none now.
        module.write_text(module.read_text().replace("np.ones", "np.zeros"))
        sys.modules.pop("userfilters_eval", None)
        from ctxmatch_lib.filters import FILTERS

        FILTERS._by_path.pop("userfilters_eval:keep", None)
        assert _cli(argv) == 0
        df2 = pd.read_parquet(out).set_index(["pair_id", "method"])
        assert (df2.xs("userfilters_eval:keep", level="method").output == 0).all()
        same = [c for c in df.columns if not c.endswith("time_s")]
        assert df2.xs("th", level="method")[same].equals(df.xs("th", level="method")[same])
    finally:
        sys.modules.pop("userfilters_eval", None)


def test_cli_eval_runs_poselib_beside_magsac(tiny_dataset, tmp_path, monkeypatch, capsys):
    # The second estimator on the same methods' outputs: a row per (method, model), each with its accuracy.
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    assert _cli(["--dataset", str(tiny_dataset), "--filters", "th", "--model", "magsac,poselib", "--out", str(out),
                 "--max-keypoints", "600", "--no-progress"]) == 0
    df = pd.read_parquet(out)
    assert set(df.model) == {"magsac", "poselib"} and len(df) == 2 * 2 * 2
    planar = df[df.kind == "planar"].set_index(["method", "model"])
    assert (planar.corner_error < 2.0).all() and (planar.model_inliers > 50).all()
    text = capsys.readouterr().out
    assert "poselib" in text and "auc_1px_pct" in text
