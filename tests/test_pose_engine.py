"""The relative pose in the evaluation rows of calibrated pairs, and the downscaled calibrated pairs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib.datasets.base import Pair, PoseGT
from ctxmatch_lib.datasets.downscaled import downscale_image, downscale_intrinsics, downscale_pairs
from ctxmatch_lib.evaluation.rows import GEOMETRY_COLUMNS, frame
from ctxmatch_lib.evaluation.steps import POSE_COLUMNS, model_accuracy
from ctxmatch_lib.geometry import ModelFit, POSE_FAILURE_DEG, apply_model_step
from ctxmatch_lib.geometry_metrics import geometry_table

K = np.array([[800.0, 0.0, 319.5], [0.0, 800.0, 239.5], [0.0, 0.0, 1.0]])


def _rotation(deg: float, axis=(0.0, 1.0, 0.0)) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.deg2rad(deg) * np.asarray(axis, np.float64))[0]


def _scene(n=200, seed=0):
    """Points of a 3-D scene seen by two calibrated cameras: pixels in both, and the pose ``X2 = R X1 + t``."""
    rng = np.random.default_rng(seed)
    X = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(4, 8, n)]
    R, t = _rotation(10.0), np.array([-1.0, 0.1, 0.2])
    x1 = (K @ X.T).T
    x2 = (K @ (X @ R.T + t).T).T
    return x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:], R, t


def _pair(R, t, tmp_path=None, **gt):
    return Pair("synthetic/0-1", tmp_path or "a.png", tmp_path or "b.png", (640, 480), (640, 480), "calibrated",
                PoseGT(K, K, R, t, **gt), "synthetic")


@pytest.mark.parametrize("step", ["magsac", "essential", "poselib", "poselib_essential"])
def test_model_accuracy_recovers_the_pose(step):
    p1, p2, R, t = _scene()
    matches = np.c_[np.arange(len(p1)), np.arange(len(p1))]
    fit = apply_model_step(step, p1, p2, matches, np.arange(len(p1), dtype=float), kind="F", threshold=1.0, rng=0,
                           **({"K1": K, "K2": K} if "essential" in step else {}))
    out = model_accuracy(step, fit, _pair(R, t), None, (p1, p2))
    assert set(POSE_COLUMNS) <= set(out) and set(out) <= set(GEOMETRY_COLUMNS)
    assert out["pose_err"] == max(out["pose_err_R"], out["pose_err_t"])
    assert out["pose_err_R"] < 0.1 and out["pose_err_t"] < 0.5  # noise-free points
    assert np.isnan(out["corner_error"]) and np.isnan(out["epi_share_mean"])


def test_model_accuracy_without_a_model_is_a_failure():
    _, _, R, t = _scene()
    empty = ModelFit(np.zeros(0, bool), None, "F", np.empty(0, np.int64), np.zeros(0))
    out = model_accuracy("magsac", empty, _pair(R, t), None, (np.empty((0, 2)), np.empty((0, 2))))
    assert out["pose_err"] == out["pose_err_R"] == out["pose_err_t"] == POSE_FAILURE_DEG
    assert out["model_inliers"] == 0
    none = model_accuracy("none", None, _pair(R, t), None)
    assert all(np.isnan(none[c]) for c in POSE_COLUMNS)


def test_geometry_table_pose_auc():
    from ctxmatch_lib.evaluation.rows import INT_COLUMNS

    rows = frame([{"dataset": "d", "pair_id": f"p{i}", "kind": "calibrated", "method": "dtm", "model": "magsac",
                   "error": "", "time_s": 0.1, "model_time_s": 0.1, "model_inliers": 10.0, "pose_err": e,
                   "pose_err_R": e, "pose_err_t": e, "blob": "b", "features": "f", **dict.fromkeys(INT_COLUMNS, 0)}
                  for i, e in enumerate([1.0, 4.0, 15.0, 180.0])])
    t = geometry_table(rows, by=("kind", "method", "model"))
    row = t.loc[("calibrated", "dtm", "magsac")]
    # pose_auc of [1, 4, 15, 180] at 5 degrees: (4 - 1) * (1/4 + 2/4) / 2 + (5 - 4) * 2/4 + 1 * 1/4 / 2 = 1.75
    assert row["auc_5deg_pct"] == pytest.approx(100 * 1.75 / 5)
    assert row["pairs"] == 4 and np.isnan(row["auc_5px_pct"])
    assert isinstance(t, pd.DataFrame)


def test_downscale_image_is_the_rounded_block_mean():
    img = np.array([[0, 1, 255, 255, 7], [2, 2, 255, 254, 7], [9, 9, 9, 9, 9]], np.uint8)
    assert downscale_image(img, 2).tolist() == [[1, 255]]
    assert downscale_image(img, 1).tolist() == img.tolist()
    with pytest.raises(ValueError, match="factor"):
        downscale_image(img, 0)
    with pytest.raises(ValueError, match="img"):
        downscale_image(img.astype(np.float32), 2)


def test_downscaled_intrinsics_keep_the_pixel_convention():
    # A 2x2 block of pixel centres (0, 0) .. (1, 1) becomes the one pixel centred at (0, 0).
    X = np.array([0.3, -0.2, 5.0])
    x = K @ X
    x = x[:2] / x[2]
    y = downscale_intrinsics(K, 2) @ X
    assert np.allclose(y[:2] / y[2], (x + 0.5) / 2 - 0.5)


def test_downscale_pairs(tmp_path):
    import cv2

    _, _, R, t = _scene()
    rng = np.random.default_rng(1)
    paths = []
    for name in ("a", "b"):
        path = tmp_path / f"{name}.png"
        cv2.imwrite(str(path), rng.integers(0, 256, (480, 640), dtype=np.uint8))
        paths.append(path)
    pair = dataclasses.replace(_pair(R, t, threshold_scale=0.625), image1=paths[0], image2=paths[1])
    (half,) = downscale_pairs([pair], 2, folder=tmp_path / "half")
    assert half.image_size1 == (320, 240) and half.dataset == "synthetic-half" and half.pair_id == pair.pair_id
    assert cv2.imread(str(half.image1), cv2.IMREAD_UNCHANGED).shape == (240, 320)
    assert half.gt.threshold_scale == pytest.approx(320 / 1024)
    assert np.allclose(half.gt.R, R) and np.allclose(half.gt.K1, downscale_intrinsics(K, 2))
    (again,) = downscale_pairs([pair], 2, folder=tmp_path / "half")  # the copies are reused
    assert again.image1 == half.image1
    with pytest.raises(ValueError, match="PoseGT"):
        downscale_pairs([dataclasses.replace(pair, gt=None)], 2)
