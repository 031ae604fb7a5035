"""PoseLib's LO-RANSAC as model steps (``poselib``: H or F; ``poselib_essential``: E with the intrinsics),
beside OpenCV's USAC steps on the same planted data."""

import numpy as np
import pytest

from ctxmatch_lib.geometry import (MODEL_STEPS, ROBUST_STEPS, USAC_PRESETS, apply_model_step, pose_from_model,
                                   relative_pose_error)

K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])


def _scene(n=300, n_out=60, seed=0):
    """Two calibrated views of random points, the first ``n_out`` matches replaced by outliers."""
    rng = np.random.default_rng(seed)
    X = rng.uniform([-1, -1, 4], [1, 1, 8], (n, 3))
    a = 0.1
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([0.5, 0.0, 0.1])
    x1 = X @ K.T
    x2 = (X @ R.T + t) @ K.T
    x1, x2 = x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:]
    x2[:n_out] = rng.uniform(0, 640, (n_out, 2))
    return x1, x2, np.c_[np.arange(n), np.arange(n)], R, t


def _plane(n=200, n_out=40, seed=1):
    rng = np.random.default_rng(seed)
    H = np.array([[0.95, -0.08, 25.0], [0.06, 1.02, -10.0], [1e-4, -5e-5, 1.0]])
    x1 = rng.uniform(0, 600, (n, 2))
    y = np.c_[x1, np.ones(n)] @ H.T
    x2 = y[:, :2] / y[:, 2:]
    x2[:n_out] = rng.uniform(0, 600, (n_out, 2))
    return x1, x2, np.c_[np.arange(n), np.arange(n)], H


def test_the_steps_are_registered_with_magsac_settings():
    assert {"poselib", "poselib_essential"} <= set(MODEL_STEPS) & set(ROBUST_STEPS)
    for step in ("poselib", "poselib_essential"):
        assert USAC_PRESETS[step] == USAC_PRESETS["magsac"]


def test_poselib_fits_h_and_keeps_the_consistent_matches():
    x1, x2, m, H = _plane()
    fit = apply_model_step("poselib", x1, x2, m, kind="H", rng=3)
    assert fit.kind == "H" and fit.model.shape == (3, 3)
    np.testing.assert_allclose(fit.model / fit.model[2, 2], H, rtol=1e-6, atol=1e-6)
    assert fit.keep[40:].all() and not fit.keep[:40].any()
    assert set(fit.sample) == set(range(40, 200))


def test_poselib_f_and_e_recover_the_pose_like_magsac():
    x1, x2, m, R, t = _scene()
    for step in ("magsac", "poselib", "essential", "poselib_essential"):
        fit = apply_model_step(step, x1, x2, m, kind="F", rng=1, K1=K, K2=K)
        assert fit.kind == ("E" if "essential" in step else "F"), step
        assert fit.keep[60:].all() and fit.keep[:60].sum() <= 2, step
        pose = pose_from_model(fit.model, fit.kind, x1[fit.sample], x2[fit.sample], K, K)
        err_R, err_t = relative_pose_error(*pose, R, t)
        assert err_R < 0.1 and err_t < 0.5, (step, err_R, err_t)


def test_poselib_is_seeded():
    x1, x2, m, _, _ = _scene(n_out=150)
    a = apply_model_step("poselib", x1, x2, m, kind="F", rng=5)
    b = apply_model_step("poselib", x1, x2, m, kind="F", rng=5)
    assert np.array_equal(a.model, b.model) and np.array_equal(a.sample, b.sample)


def test_poselib_overrides_and_failures():
    x1, x2, m, _, _ = _scene()
    loose = apply_model_step("poselib", x1, x2, m, kind="F", rng=1, estimator={"threshold": 20.0})
    tight = apply_model_step("poselib", x1, x2, m, kind="F", rng=1)
    assert len(loose.sample) >= len(tight.sample)
    few = apply_model_step("poselib", x1, x2, m[:7], kind="F", rng=1)
    assert few.model is None and not few.keep.any()
    empty = apply_model_step("poselib_essential", x1, x2, m[:0], kind="F", rng=1, K1=K, K2=K)
    assert empty.model is None and empty.keep.shape == (0,)
    with pytest.raises(ValueError, match="K1"):
        apply_model_step("poselib_essential", x1, x2, m, kind="F", rng=1)
    with pytest.raises(ValueError, match="max_iters"):
        apply_model_step("poselib", x1, x2, m, kind="F", estimator={"max_iters": 0})
