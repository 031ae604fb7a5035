"""Relative pose of calibrated pairs: the pose error as SuperGlue's compute_pose_error,
pose recovery from E or F with the intrinsics, and the ``essential`` model step."""

import numpy as np
import pytest

from ctxmatch_lib.geometry import (
    MODEL_STEPS,
    POSE_FAILURE_DEG,
    ROBUST_STEPS,
    USAC_PRESETS,
    apply_model_step,
    check_intrinsics,
    epipolar_distances,
    essential_from_fundamental,
    fundamental_from_essential,
    model_errors,
    normalise_by_intrinsics,
    pose_error,
    pose_from_model,
    recover_relative_pose,
    relative_pose_error,
    usac_settings,
)
from ctxmatch_lib.geometry_metrics import pose_auc

#: The thresholds of the pose AUC that SuperGlue, LoFTR and fb82/MiHo report (degrees).
AUC_DEG = (5.0, 10.0, 20.0)

K1 = np.array([[800.0, 0.0, 320.0], [0.0, 780.0, 240.0], [0.0, 0.0, 1.0]])
K2 = np.array([[650.0, 0.0, 300.0], [0.0, 660.0, 250.0], [0.0, 0.0, 1.0]])


def rotation(axis, degrees):
    """Rodrigues' rotation by ``degrees`` about ``axis``."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = np.radians(degrees)
    return np.eye(3) + np.sin(th) * A + (1 - np.cos(th)) * A @ A


def skew(t):
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def project(X, K):
    x = X @ K.T
    return x[:, :2] / x[:, 2:]


def scene(n=60, seed=0, R=None, t=(0.8, 0.1, 0.2)):
    """``n`` points 4-8 units in front of camera 1, seen by camera 2 at ``X2 = R X1 + t``."""
    rng = np.random.default_rng(seed)
    R = rotation([0.2, 1.0, 0.1], 12.0) if R is None else R
    t = np.asarray(t, float)
    X1 = rng.uniform([-2, -1.5, 4], [2, 1.5, 8], (n, 3))
    return project(X1, K1), project(X1 @ R.T + t, K2), R, t


# --------------------------------------------------------------------------------------- intrinsics


def test_normalise_by_intrinsics_hand_computed():
    K = [[500.0, 0, 320], [0, 250, 240], [0, 0, 1]]
    out = normalise_by_intrinsics([[320.0, 240.0], [820.0, 490.0], [70.0, 115.0]], K)
    np.testing.assert_allclose(out, [[0, 0], [1, 1], [-0.5, -0.5]], atol=1e-15)
    assert normalise_by_intrinsics(np.empty((0, 2)), K).shape == (0, 2)


def test_normalise_by_intrinsics_inverts_the_projection_with_skew_and_scaled_k():
    K = np.array([[700.0, 3.0, 310.0], [0, 690.0, 255.0], [0, 0, 1.0]])
    X = np.random.default_rng(1).uniform([-1, -1, 2], [1, 1, 5], (10, 3))
    np.testing.assert_allclose(normalise_by_intrinsics(project(X, K), 2.0 * K), X[:, :2] / X[:, 2:], atol=1e-12)


@pytest.mark.parametrize("K, match", [
    (None, "K1 is required"),
    (np.eye(2), r"K1 must be a \(3, 3\)"),
    ([[0.0, 0, 1], [0, 5, 1], [0, 0, 1]], "K1 has a zero focal"),
    ([[5.0, 0, 1], [0, 0, 1], [0, 0, 1]], "K1 has a zero focal"),
    ([[5.0, 0, 1], [0, 5, 1], [0, 0, np.nan]], "K1 contains NaN"),
    ([[5.0, 0, 1], [0, 5, 1], [1, 0, 1]], "K1 must be upper triangular"),
])
def test_check_intrinsics_names_the_matrix(K, match):
    with pytest.raises(ValueError, match=match):
        check_intrinsics(K, "K1")


def test_essential_and_fundamental_are_inverse_up_to_scale():
    p1, p2, R, t = scene()
    E = skew(t) @ R
    F = fundamental_from_essential(E, K1, K2)
    assert np.linalg.norm(F) == pytest.approx(1.0)
    d2, d1 = epipolar_distances(F, p1, p2)
    assert max(d1.max(), d2.max()) < 1e-9
    E2 = essential_from_fundamental(F, K1, K2)
    np.testing.assert_allclose(E2 / np.linalg.norm(E2), E / np.linalg.norm(E), atol=1e-12)


# ------------------------------------------------------------------------------------------ pose error


def test_pose_error_of_the_truth_is_zero():
    R, t = rotation([1, 2, 3], 30.0), np.array([0.3, -0.2, 1.0])
    err_R, err_t = relative_pose_error(R, 5.0 * t, R, t)
    assert err_R == pytest.approx(0.0, abs=1e-12) and err_t == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("degrees", [0.001, 1.0, 10.0, 90.0, 179.0])
@pytest.mark.parametrize("axis", [[0, 0, 1], [1, -2, 0.5]])
def test_rotation_error_is_the_perturbation_angle(axis, degrees):
    R_gt = rotation([0.3, 1, 0], 25.0)
    t = np.array([1.0, 0, 0])
    for R_est in (rotation(axis, degrees) @ R_gt, R_gt @ rotation(axis, degrees)):
        err_R, err_t = relative_pose_error(R_est, t, R_gt, t)
        assert err_R == pytest.approx(degrees, abs=1e-9) and err_t == 0.0


def test_rotation_error_is_symmetric_and_ignores_a_common_rotation():
    rng = np.random.default_rng(3)
    for _ in range(20):
        A, B, C = (rotation(rng.normal(size=3), rng.uniform(0, 180)) for _ in range(3))
        e = relative_pose_error(A, [1, 0, 0], B, [0, 0, 1])[0]
        assert relative_pose_error(B, [1, 0, 0], A, [0, 0, 1])[0] == pytest.approx(e, abs=1e-9)
        assert relative_pose_error(C @ A, [1, 0, 0], C @ B, [0, 0, 1])[0] == pytest.approx(e, abs=1e-9)


@pytest.mark.parametrize("t_est, expected", [
    ([1.0, 0, 0], 0.0),
    ([-3.0, 0, 0], 0.0),  # sign ambiguity of E: a flipped t is no error
    ([0, 1.0, 0], 90.0),
    ([1.0, 1.0, 0], 45.0),
    ([-1.0, 1.0, 0], 45.0),  # 135 degrees apart, folded to 45
    ([np.cos(np.radians(100)), np.sin(np.radians(100)), 0], 80.0),
])
def test_translation_error_folds_the_sign(t_est, expected):
    err_R, err_t = relative_pose_error(np.eye(3), t_est, np.eye(3), [2.0, 0, 0])
    assert err_R == 0.0 and err_t == pytest.approx(expected, abs=1e-12)


def test_pose_error_is_the_larger_angle():
    R_est = rotation([0, 0, 1], 3.0)
    t_est = np.array([np.cos(np.radians(7)), np.sin(np.radians(7)), 0])
    assert pose_error(R_est, t_est, np.eye(3), [1, 0, 0]) == pytest.approx(7.0, abs=1e-9)
    assert pose_error(rotation([0, 0, 1], 12.0), t_est, np.eye(3), [1, 0, 0]) == pytest.approx(12.0, abs=1e-9)


def test_missing_or_broken_estimate_is_a_failure_at_180():
    t_gt = [0, 0, 1.0]
    assert relative_pose_error(None, None, np.eye(3), t_gt) == (POSE_FAILURE_DEG, POSE_FAILURE_DEG)
    assert relative_pose_error(np.eye(3), None, np.eye(3), t_gt) == (180.0, 180.0)
    assert relative_pose_error(np.full((3, 3), np.nan), [0, 0, 1], np.eye(3), t_gt) == (180.0, 180.0)
    assert relative_pose_error(np.eye(3), [0, 0, 0], np.eye(3), t_gt) == (0.0, 180.0)  # no direction
    assert pose_error(None, None, np.eye(3), t_gt) == 180.0


def test_pose_error_rejects_malformed_ground_truth():
    with pytest.raises(ValueError, match="t_gt is zero"):
        relative_pose_error(np.eye(3), [1, 0, 0], np.eye(3), [0, 0, 0])
    with pytest.raises(ValueError, match="R_gt must be a"):
        relative_pose_error(np.eye(3), [1, 0, 0], np.eye(2), [0, 0, 1])
    with pytest.raises(ValueError, match="R_est must have shape"):
        relative_pose_error(np.eye(2), [1, 0, 0], np.eye(3), [0, 0, 1])


def test_failures_at_180_give_the_auc_of_failures_at_inf():
    errors = [0.5, 3.0, 7.0, 12.0]
    ours = pose_auc(errors + [POSE_FAILURE_DEG, POSE_FAILURE_DEG], AUC_DEG)
    np.testing.assert_array_equal(ours, pose_auc(errors + [np.inf, np.inf], AUC_DEG))


# ----------------------------------------------------------------------------------------- pose recovery


def test_recover_pose_from_the_true_essential_matrix_is_exact():
    p1, p2, R, t = scene()
    R_est, t_est, n = recover_relative_pose(skew(t) @ R, p1, p2, K1, K2)
    assert n == len(p1)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t / np.linalg.norm(t), atol=1e-9)
    assert pose_error(R_est, t_est, R, t) < 1e-6


def test_recover_pose_ignores_the_scale_and_sign_of_e():
    p1, p2, R, t = scene(seed=2)
    for s in (1e-3, -1.0, 250.0):
        R_est, t_est, _ = recover_relative_pose(s * skew(t) @ R, p1, p2, K1, K2)
        assert pose_error(R_est, t_est, R, t) < 1e-6


def test_recover_pose_keeps_far_points():
    # Depths of 200-800 baselines: OpenCV's default distanceThresh (50) would leave no point to vote.
    R, t = rotation([0, 1, 0], 2.0), np.array([0.01, 0.0, 0.0])
    X1 = np.random.default_rng(4).uniform([-1, -1, 2], [1, 1, 8], (40, 3))
    p1, p2 = project(X1, K1), project(X1 @ R.T + t, K2)
    R_est, t_est, n = recover_relative_pose(skew(t) @ R, p1, p2, K1, K2)
    assert n == 40 and pose_error(R_est, t_est, R, t) < 1e-6


def test_recover_pose_is_invariant_to_the_order_of_the_points():
    p1, p2, R, t = scene(seed=5)
    E = skew(t) @ R + np.random.default_rng(0).normal(0, 1e-3, (3, 3))  # a noisy E: the vote is not unanimous
    perm = np.random.default_rng(1).permutation(len(p1))
    a, b = recover_relative_pose(E, p1, p2, K1, K2), recover_relative_pose(E, p1[perm], p2[perm], K1, K2)
    np.testing.assert_allclose(a[0], b[0], atol=1e-12)
    np.testing.assert_allclose(a[1], b[1], atol=1e-12)
    assert a[2] == b[2]


@pytest.mark.parametrize("n", [0, 1, 4])
def test_recover_pose_from_too_few_points_is_none(n):
    p1, p2, R, t = scene()
    assert recover_relative_pose(skew(t) @ R, p1[:n], p2[:n], K1, K2) is None


def test_recover_pose_from_a_degenerate_e_is_none():
    p1, p2, R, t = scene()
    assert recover_relative_pose(np.zeros((3, 3)), p1, p2, K1, K2) is None
    assert recover_relative_pose(np.outer([1.0, 2, 3], [0.5, 0, 1]), p1, p2, K1, K2) is None  # rank 1


def test_recover_pose_rejects_malformed_input():
    p1, p2, R, t = scene()
    with pytest.raises(ValueError, match="pts2 must have 60 rows"):
        recover_relative_pose(skew(t) @ R, p1, p2[:10], K1, K2)
    with pytest.raises(ValueError, match="K2 has a zero focal"):
        recover_relative_pose(skew(t) @ R, p1, p2, K1, np.diag([0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"E must be a \(3, 3\)"):
        recover_relative_pose(np.eye(4), p1, p2, K1, K2)


def test_pose_from_model_by_f_and_by_e():
    p1, p2, R, t = scene(seed=6)
    E = skew(t) @ R
    F = 3.0 * fundamental_from_essential(E, K1, K2)
    for model, kind in ((F, "F"), (E, "E")):
        R_est, t_est = pose_from_model(model, kind, p1, p2, K1, K2)
        assert pose_error(R_est, t_est, R, t) < 1e-6
    assert pose_from_model(None, "F", p1, p2, K1, K2) is None
    assert pose_from_model(F, "F", p1[:3], p2[:3], K1, K2) is None
    with pytest.raises(ValueError, match="kind must be 'F' or 'E'"):
        pose_from_model(np.eye(3), "H", p1, p2, K1, K2)


def test_pose_from_model_of_a_noisy_f_fit():
    # The F route of MiHo's AUC^F: F from noisy pixels by the model step, then E = K2^T F K1.
    p1, p2, R, t = scene(n=200, seed=7)
    p2 = p2 + np.random.default_rng(0).normal(0, 0.3, p2.shape)
    m = np.c_[np.arange(200), np.arange(200)]
    fit = apply_model_step("magsac", p1, p2, m, kind="F", rng=0)
    R_est, t_est = pose_from_model(fit.model, fit.kind, p1[m[fit.sample, 0]], p2[m[fit.sample, 1]], K1, K2)
    assert pose_error(R_est, t_est, R, t) < 2.0


# -------------------------------------------------------------------------------------- essential step


def planted(n=300, outliers=100, noise=0.3, seed=0):
    p1, p2, R, t = scene(n=n, seed=seed)
    rng = np.random.default_rng(seed + 100)
    p2 = p2 + rng.normal(0, noise, p2.shape)
    p2[:outliers] = rng.uniform([0, 0], [640, 480], (outliers, 2))
    return p1, p2, np.c_[np.arange(n), np.arange(n)], R, t


def test_essential_is_a_seeded_robust_step():
    assert "essential" in MODEL_STEPS and "essential" in ROBUST_STEPS
    # fb82/MiHo's MAGSAC settings, as the magsac step's.
    assert USAC_PRESETS["essential"] == USAC_PRESETS["magsac"] == usac_settings("essential")


def test_essential_step_recovers_a_planted_pose():
    p1, p2, m, R, t = planted()
    fits = [apply_model_step("essential", p1, p2, m, kind="F", rng=3, K1=K1, K2=K2) for _ in range(2)]
    fit = fits[0]
    np.testing.assert_array_equal(fit.model, fits[1].model)
    np.testing.assert_array_equal(fit.sample, fits[1].sample)
    assert fit.kind == "E" and fit.model.shape == (3, 3)
    # USAC's inliers are the planted correspondences (the first 100 are random points).
    assert (fit.sample >= 100).mean() > 0.97 and len(fit.sample) > 170
    # The errors are epipolar distances in pixels to F = K2^-T E K1^-1, the same as model_errors gives.
    np.testing.assert_allclose(fit.errors, model_errors(fit.model, "E", p1, p2, K1=K1, K2=K2))
    assert np.median(fit.errors[100:]) < 1.0
    np.testing.assert_array_equal(fit.keep, fit.errors <= 15.0)
    R_est, t_est = pose_from_model(fit.model, fit.kind, p1[fit.sample], p2[fit.sample], K1, K2)
    assert pose_error(R_est, t_est, R, t) < 5.0  # 0.3 px noise: the direction of t is the weak part


def test_essential_step_on_noise_free_matches_is_exact():
    p1, p2, m, R, t = planted(noise=0.0)
    fit = apply_model_step("essential", p1, p2, m, kind="F", rng=0, K1=K1, K2=K2)
    # Every planted match is an inlier; a random point may land within 1 px of its epipolar line.
    assert set(range(100, 300)) <= set(fit.sample.tolist()) and len(fit.sample) <= 203
    R_est, t_est = pose_from_model(fit.model, fit.kind, p1[fit.sample], p2[fit.sample], K1, K2)
    assert pose_error(R_est, t_est, R, t) < 1e-3


def test_essential_step_threshold_is_in_pixels():
    # A tighter USAC threshold keeps fewer of the noisy inliers.
    p1, p2, m, _, _ = planted(noise=1.0)
    loose = apply_model_step("essential", p1, p2, m, kind="F", rng=0, K1=K1, K2=K2, estimator={"threshold": 3.0})
    tight = apply_model_step("essential", p1, p2, m, kind="F", rng=0, K1=K1, K2=K2, estimator={"threshold": 0.3})
    assert len(tight.sample) < len(loose.sample)


@pytest.mark.parametrize("n", [0, 4])
def test_essential_step_on_too_few_matches_fails_cleanly(n):
    p1, p2, m, _, _ = planted()
    fit = apply_model_step("essential", p1, p2, m[:n], kind="F", rng=0, K1=K1, K2=K2)
    assert fit.model is None and fit.kind == "E" and fit.keep.shape == (n,) and not fit.keep.any()
    assert np.isinf(fit.errors).all() and len(fit.sample) == 0


def test_essential_step_names_missing_or_bad_intrinsics():
    p1, p2, m, _, _ = planted()
    with pytest.raises(ValueError, match="K1 is required"):
        apply_model_step("essential", p1, p2, m, kind="F", rng=0)
    with pytest.raises(ValueError, match="K2 has a zero focal"):
        apply_model_step("essential", p1, p2, m, kind="F", rng=0, K1=K1, K2=np.diag([0.0, 0.0, 1.0]))


def test_model_errors_of_e_need_intrinsics():
    p1, p2, R, t = scene()
    with pytest.raises(ValueError, match="K1 is required"):
        model_errors(skew(t) @ R, "E", p1, p2)
    assert model_errors(skew(t) @ R, "E", p1, p2, K1=K1, K2=K2).max() < 1e-9


def test_other_steps_reject_kind_e():
    p1, p2, m, _, _ = planted()
    for name in ("1sac", "magsac"):
        with pytest.raises(ValueError, match="kind must be 'H' or 'F'"):
            apply_model_step(name, p1, p2, m, kind="E")
