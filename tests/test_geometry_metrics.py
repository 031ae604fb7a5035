"""The accuracy of an estimated model: corner error, epipolar consistency, AUC over pairs, and the
engine rows that carry them; the OpenCV matchers and the USAC presets."""

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib.datasets.base import EpipolarGT, FlowGT, HomographyGT
from ctxmatch_lib.geometry import USAC_PRESETS, apply_homography, apply_model_step, usac_settings
from ctxmatch_lib.geometry_metrics import (
    EPIPOLAR_THRESHOLDS_PX,
    epipolar_consistency,
    geometry_table,
    gt_correspondences,
    homography_corner_error,
    image_corners,
    pose_auc,
    symmetric_epipolar_distance,
    time_to_geometry,
)
from ctxmatch_lib.opencv_matchers import opencv_mnn_matches, opencv_ratio_matches

#: A horizontal translation between the cameras: the epipolar lines are the rows, y' = y.
F_SHIFT = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


# ------------------------------------------------------------------------------------------ corner error


def test_corner_error_of_a_translation_is_its_length():
    shift = np.array([[1.0, 0, 3], [0, 1, 4], [0, 0, 1]])
    assert homography_corner_error(shift, np.eye(3), (640, 480)) == 5.0
    assert homography_corner_error(np.eye(3), np.eye(3), (640, 480)) == 0.0


def test_corner_error_of_a_scaling_hand_computed():
    # Corners of a 4 x 2 image: (-0.5, -0.5), (3.5, -0.5), (3.5, 1.5), (-0.5, 1.5); doubling moves each by itself.
    expected = np.mean([np.hypot(0.5, 0.5), np.hypot(3.5, 0.5), np.hypot(3.5, 1.5), np.hypot(0.5, 1.5)])
    assert homography_corner_error(np.diag([2.0, 2.0, 1.0]), np.eye(3), (4, 2)) == pytest.approx(expected, rel=1e-15)
    # Invariant to the scale of either matrix.
    assert homography_corner_error(3 * np.diag([2.0, 2.0, 1.0]), -np.eye(3), (4, 2)) == pytest.approx(expected)


def test_corner_error_matches_the_corner_origin_convention():
    """glue-factory's definition (corners (0, 0), (W, 0), (W, H), (0, H), origin at the image corner) on the
    same homographies written in that convention gives the same value."""
    rng = np.random.default_rng(3)
    size = (640, 480)
    H = np.eye(3) + rng.normal(0, [[1e-2, 1e-2, 3], [1e-2, 1e-2, 3], [1e-5, 1e-5, 0]])
    H_gt = np.eye(3) + rng.normal(0, [[1e-2, 1e-2, 3], [1e-2, 1e-2, 3], [1e-5, 1e-5, 0]])
    T = np.array([[1.0, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # centre-of-pixel origin -> corner origin
    corners = np.array([[0.0, 0], [size[0], 0], size, [0, size[1]]])
    Hc, Hc_gt = T @ H @ np.linalg.inv(T), T @ H_gt @ np.linalg.inv(T)
    glue = np.linalg.norm(apply_homography(Hc, corners) - apply_homography(Hc_gt, corners), axis=1).mean()
    assert homography_corner_error(H, H_gt, size) == pytest.approx(glue, rel=1e-12)


def test_corner_error_without_a_model_or_at_infinity():
    assert homography_corner_error(None, np.eye(3), (640, 480)) == np.inf
    to_infinity = np.array([[1.0, 0, 0], [0, 1, 0], [1, 0, 0.5]])  # the corner x = -0.5 goes to w = 0
    assert homography_corner_error(to_infinity, np.eye(3), (640, 480)) == np.inf


@pytest.mark.parametrize("call, name", [
    (lambda: homography_corner_error(np.eye(3), np.eye(2), (4, 2)), "H_gt"),
    (lambda: homography_corner_error(np.eye(2), np.eye(3), (4, 2)), "H "),
    (lambda: homography_corner_error(np.eye(3), np.eye(3), (4, 0)), "image_size"),
    (lambda: image_corners((4, 2, 1)), "image_size"),
])
def test_corner_error_bad_input_names_the_argument(call, name):
    with pytest.raises(ValueError, match=name):
        call()


# ------------------------------------------------------------------------------------ epipolar consistency


def test_symmetric_epipolar_distance_hand_computed():
    # Both point-to-line distances equal |y2 - y1| under F_SHIFT: the symmetric distance is sqrt(2) |dy|.
    pts1 = np.array([[0.0, 0.0], [5.0, 2.0], [1.0, 1.0]])
    pts2 = np.array([[3.0, 0.0], [1.0, 5.0], [9.0, 0.0]])
    np.testing.assert_allclose(symmetric_epipolar_distance(F_SHIFT, pts1, pts2), np.sqrt(2) * np.array([0, 3, 1]),
                               rtol=1e-15, atol=0)
    # The scale of F does not matter.
    np.testing.assert_allclose(symmetric_epipolar_distance(-7 * F_SHIFT, pts1, pts2),
                               symmetric_epipolar_distance(F_SHIFT, pts1, pts2), rtol=1e-15)


def test_epipolar_consistency_hand_computed():
    dy = np.array([0.0, 0.5, 1.0, 2.0, 20.0])  # symmetric distances 0, 0.71, 1.41, 2.83, 28.3
    pts1 = np.c_[np.arange(5.0), np.zeros(5)]
    pts2 = np.c_[np.arange(5.0) + 4, dy]
    share = epipolar_consistency(F_SHIFT, pts1, pts2)
    expected = np.r_[0.4, 0.6, np.full(17, 0.8)]
    np.testing.assert_array_equal(share, expected)
    assert share.mean() == pytest.approx(14.6 / 19)
    assert list(EPIPOLAR_THRESHOLDS_PX) == list(range(1, 20))
    # At exactly the threshold a correspondence counts as consistent.
    assert epipolar_consistency(F_SHIFT, [[0.0, 0.0]], [[0.0, 1.0]], thresholds=[np.sqrt(2)])[0] == 1.0


def test_epipolar_consistency_without_model_or_points():
    np.testing.assert_array_equal(epipolar_consistency(None, [[0.0, 0.0]], [[1.0, 1.0]]), np.zeros(19))
    assert np.isnan(epipolar_consistency(F_SHIFT, np.empty((0, 2)), np.empty((0, 2)))).all()
    with pytest.raises(ValueError, match="pts2"):
        epipolar_consistency(F_SHIFT, [[0.0, 0.0]], [[1.0, 1.0], [2.0, 2.0]])


def test_gt_correspondences_per_ground_truth():
    hand1, hand2 = np.array([[1.0, 2.0], [3, 4], [5, 6]]), np.array([[1.5, 2.0], [3.5, 4], [5.5, 6]])
    pts = gt_correspondences(EpipolarGT(F_SHIFT, hand1, hand2))
    np.testing.assert_array_equal(pts[0], hand1)
    np.testing.assert_array_equal(pts[1], hand2)
    assert gt_correspondences(HomographyGT(np.eye(3))) is None
    flow = np.zeros((3, 4, 2))
    flow[..., 0] = 2.0
    flow[0, 1] = np.nan  # unknown pixel (row 0, column 1)
    p1, p2 = gt_correspondences(FlowGT(flow))
    assert len(p1) == 11 and [1.0, 0.0] not in p1.tolist()
    np.testing.assert_array_equal(p1[:2], [[0.0, 0.0], [2.0, 0.0]])  # row-major, x = column, y = row
    np.testing.assert_array_equal(p2, p1 + [2.0, 0.0])
    q1, _ = gt_correspondences(FlowGT(flow), max_points=2)
    np.testing.assert_array_equal(q1, [[0.0, 0.0], [3.0, 2.0]])  # evenly spaced: the first and the last
    with pytest.raises(ValueError, match="max_points"):
        gt_correspondences(FlowGT(flow), max_points=0)


# --------------------------------------------------------------------------------------------------- AUC


def test_pose_auc_hand_computed():
    # Sorted errors 0, 1, 2, inf over 4 pairs. Up to 1: the recall is 1/4 from 0 on: area 1/4.
    # Up to 2: 1/4 on [0, 1], then 1/4 -> 2/4 linearly on [1, 2]: area 1/4 + 3/8 = 5/8, over 2: 5/16.
    np.testing.assert_allclose(pose_auc([0.0, 2.0, np.inf, 1.0], [1.0, 2.0]), [0.25, 0.4375], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(pose_auc([0.0, 0.0], [1.0, 5.0]), [1.0, 1.0])
    np.testing.assert_array_equal(pose_auc([np.inf, np.nan], [1.0]), [0.0])  # failures stay in the denominator
    assert pose_auc([1.0], [1.0])[0] == 0.0  # an error equal to the threshold counts from above
    assert np.isnan(pose_auc([], [1.0, 3.0])).all()


def test_pose_auc_failures_lower_it_in_proportion():
    errors = np.array([0.3, 1.2, 2.5, 0.7])
    base = pose_auc(errors, [1.0, 3.0, 5.0])
    with_failures = pose_auc(np.r_[errors, np.inf, np.inf, np.inf, np.inf], [1.0, 3.0, 5.0])
    np.testing.assert_allclose(with_failures, base / 2, rtol=1e-15)


def test_pose_auc_bad_input():
    with pytest.raises(ValueError, match="thresholds"):
        pose_auc([1.0], [0.0])
    with pytest.raises(ValueError, match="errors"):
        pose_auc([-1.0], [1.0])


# --------------------------------------------------------------------------------------- tables over rows


def _rows():
    base = dict(dataset="d", features="f", blob="b", error="", epi_share_mean=np.nan, model_inliers=10.0)
    return pd.DataFrame([
        dict(base, pair_id="p1", kind="planar", method="blob", model="none", time_s=1.0, model_time_s=0.0,
             corner_error=np.nan, model_inliers=np.nan),
        dict(base, pair_id="p1", kind="planar", method="blob", model="magsac", time_s=1.0, model_time_s=0.5,
             corner_error=0.0),
        dict(base, pair_id="p1", kind="planar", method="dtm", model="magsac", time_s=0.25, model_time_s=0.125,
             corner_error=np.inf, model_inliers=0.0),
        dict(base, pair_id="p1", kind="planar", method="opencv_ratio", model="magsac", time_s=0.5,
             model_time_s=0.25, corner_error=2.0),
        dict(base, pair_id="p2", kind="nonplanar", method="dtm", model="magsac", time_s=0.25, model_time_s=0.25,
             corner_error=np.nan, epi_share_mean=0.5),
        dict(base, pair_id="p2", kind="nonplanar", method="blob", model="magsac", time_s=2.0, model_time_s=1.0,
             corner_error=np.nan, epi_share_mean=0.25),
    ])


def test_time_to_geometry_adds_the_blob_time_to_filters_only():
    t = time_to_geometry(_rows())
    assert np.isnan(t[0])
    np.testing.assert_array_equal(t[1:], [1.5, 1.0 + 0.25 + 0.125, 0.75, 2.0 + 0.25 + 0.25, 3.0])


def test_geometry_table_hand_computed():
    t = geometry_table(_rows(), by=("kind", "method", "model"))
    assert t.loc[("planar", "blob", "magsac"), "auc_1px_pct"] == 100.0
    assert t.loc[("planar", "dtm", "magsac"), "auc_10px_pct"] == 0.0
    assert t.loc[("planar", "dtm", "magsac"), "no_model"] == 1
    # One pair at 2 px: the recall rises linearly from (0, 0) to (2, 1), then stays: (1 + 8) / 10.
    assert t.loc[("planar", "opencv_ratio", "magsac"), "auc_10px_pct"] == pytest.approx(90.0)
    assert t.loc[("nonplanar", "dtm", "magsac"), "epi_share_mean_pct"] == 50.0
    assert np.isnan(t.loc[("nonplanar", "dtm", "magsac"), "auc_1px_pct"])
    assert t.loc[("nonplanar", "blob", "magsac"), "geometry_time_s"] == 3.0
    assert t.loc[("planar", "blob", "magsac"), "geometry_time_median_s"] == 1.5
    assert ("planar", "blob", "none") not in t.index


# ----------------------------------------------------------------------------------- matchers and USAC


def test_opencv_matchers_hand_built():
    d1 = np.array([[0.0, 0.0], [5.0, 5.0]])
    d2 = np.array([[0.0, 0.1], [5.0, 4.0], [5.0, 5.9]])
    m, s = opencv_ratio_matches(d1, d2)
    np.testing.assert_array_equal(m, [[0, 0]])
    assert s[0] == pytest.approx(0.1 / np.hypot(5.0, 4.0), rel=1e-6)
    m, s = opencv_mnn_matches(d1, d2)
    np.testing.assert_array_equal(m, [[0, 0], [1, 2]])
    np.testing.assert_allclose(s, [0.1, 0.9], rtol=1e-6)
    assert opencv_ratio_matches(d1, d2[:1])[0].shape == (0, 2)  # no second neighbour
    assert opencv_mnn_matches(np.empty((0, 2)), d2)[0].shape == (0, 2)
    with pytest.raises(ValueError, match="same dimension"):
        opencv_mnn_matches(d1, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="ratio"):
        opencv_ratio_matches(d1, d2, ratio=0)


def test_usac_presets_and_overrides():
    assert USAC_PRESETS["magsac"] == usac_settings("magsac")
    s = usac_settings("magsac")
    assert (s.sampler, s.threshold, s.confidence, s.max_iters) == ("uniform", 1.0, 0.9999, 100_000)
    assert usac_settings("prosac", {"threshold": 2}).threshold == 2.0
    for bad, match in (({"thresh": 1}, "threshold, confidence"), ({"threshold": -1}, "threshold"),
                       ({"confidence": 1.0}, "confidence"), ({"max_iters": 0}, "max_iters")):
        with pytest.raises(ValueError, match=match):
            usac_settings("ransac", bad)
    with pytest.raises(ValueError, match="USAC"):
        usac_settings("1sac")


def test_magsac_step_is_seeded_and_recovers_a_planted_homography():
    rng = np.random.default_rng(0)
    p1 = rng.uniform(0, 600, (300, 2))
    H = np.array([[1.1, 0.05, 10], [0.02, 0.95, -5], [1e-4, 2e-5, 1]])
    p2 = apply_homography(H, p1) + rng.normal(0, 0.3, (300, 2))
    p2[:150] = rng.uniform(0, 600, (150, 2))  # half outliers
    m = np.c_[np.arange(300), np.arange(300)]
    fits = [apply_model_step("magsac", p1, p2, m, kind="H", rng=7) for _ in range(2)]
    np.testing.assert_array_equal(fits[0].model, fits[1].model)
    assert homography_corner_error(fits[0].model, H, (600, 600)) < 1.0
    # USAC's inliers are the planted correspondences (the first 150 are random points).
    assert (fits[0].sample >= 150).mean() > 0.95 and len(fits[0].sample) > 120


# ------------------------------------------------------------------------------------------- the engine


@pytest.fixture(scope="module")
def geometry_rows(tmp_path_factory):
    from ctxmatch_lib.evaluation import run_sweep

    return run_sweep("embedded", blobs="paper-best", filters=("dtm",), models=("none", "1sac", "magsac"),
                     matchers=("opencv_ratio", "opencv_mnn"), pairs=["planar/poster/1-3", "nonplanar/star",
                                                                      "depth/motorcycle"],
                     max_keypoints=400, cache_dir=tmp_path_factory.mktemp("cache"), progress=False)


def test_engine_rows_carry_the_geometry_columns(geometry_rows):
    from ctxmatch_lib.evaluation.rows import GEOMETRY_COLUMNS, SWEEP_COLUMNS

    df = geometry_rows
    assert set(GEOMETRY_COLUMNS) <= set(SWEEP_COLUMNS) and list(df.columns) == list(SWEEP_COLUMNS)
    assert (df["error"] == "").all()
    assert set(df["method"]) == {"blob", "dtm", "opencv_ratio", "opencv_mnn"}
    assert len(df) == 3 * 4 * 3
    none, fitted = df[df["model"] == "none"], df[df["model"] != "none"]
    assert none[list(GEOMETRY_COLUMNS)].isna().all().all()
    planar, other = fitted[fitted["kind"] == "planar"], fitted[fitted["kind"] != "planar"]
    assert (planar["corner_error"] >= 0).all() and planar["epi_share_mean"].isna().all()
    assert other["corner_error"].isna().all()
    shares = other[["epi_share_mean", "epi_share_1", "epi_share_3", "epi_share_5", "epi_share_10"]]
    assert ((shares >= 0) & (shares <= 1)).all().all()
    assert (other["epi_share_1"] <= other["epi_share_10"]).all()
    assert (fitted["model_inliers"] >= 0).all()
    # The OpenCV rows have match-level numbers from the same ground truth.
    opencv = df[df["method"].str.startswith("opencv_")]
    assert opencv["precision"].between(0, 1).all() and (opencv["output"] > 0).all()


def test_engine_geometry_reruns_identically(geometry_rows):
    from ctxmatch_lib.evaluation import run_sweep

    again = run_sweep("embedded", blobs="paper-best", filters=("dtm",), models=("none", "1sac", "magsac"),
                      matchers=("opencv_ratio", "opencv_mnn"), pairs=["planar/poster/1-3", "nonplanar/star",
                                                                       "depth/motorcycle"],
                      max_keypoints=400, cache_dir=False, progress=False)
    cols = ["corner_error", "epi_share_mean", "model_inliers", "precision", "output"]
    pd.testing.assert_frame_equal(again[cols], geometry_rows[cols])


def test_engine_estimator_settings_are_checked_and_keyed():
    from ctxmatch_lib.evaluation import plan_units
    from ctxmatch_lib.evaluation.plan import keyed
    from ctxmatch_lib.datasets import load_dataset

    pair = load_dataset("embedded")[0]
    a = keyed(plan_units([pair], blobs="paper-best", models=("magsac",)))[0]
    b = keyed(plan_units([pair], blobs="paper-best", models=("magsac",), estimator={"threshold": 0.5}))[0]
    c = keyed(plan_units([pair], blobs="paper-best", models=("magsac",), matchers=("opencv_ratio",)))[0]
    assert len({a.key, b.key, c.key}) == 3 and b.estimator == (("threshold", 0.5),)
    with pytest.raises(ValueError, match="threshold"):
        plan_units([pair], models=("magsac",), estimator={"threshold": 0})
    with pytest.raises(ValueError, match="unknown matcher"):
        plan_units([pair], matchers=("flann",))


def test_cli_eval_prints_the_geometry_table(tmp_path, monkeypatch, capsys):
    from ctxmatch_lib.cli import main

    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "r.parquet"
    assert main(["eval", "--pairs", "planar/poster/1-2,nonplanar/cat", "--model", "magsac", "--matchers",
                 "opencv_ratio", "--max-keypoints", "300", "--estimator-threshold", "2", "--no-progress",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "auc_1px_pct" in text and "epi_share_mean_pct" in text
    df = pd.read_parquet(out)
    assert set(df["method"]) == {"blob", "dtm", "opencv_ratio"}
    assert df.loc[df["kind"] == "planar", "corner_error"].notna().all()
    assert main(["eval", "--estimator-confidence", "1", "--out", str(out)]) == 2
    assert "--estimator-confidence" in capsys.readouterr().err
