"""Model step: normalised DLT, 8-point, top-ranked sample, 1SAC and seeded RANSAC."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ctxmatch_lib.geometry import (
    MIN_SAMPLE,
    apply_homography,
    apply_model_step,
    epipolar_distances,
    fit_fundamental,
    fit_homography,
    homography_transfer_errors,
    model_errors,
    model_kind_for,
    normalise_points,
    one_sac,
    ransac,
    top_ranked_sample,
)
from ctxmatch_lib.testing import planted_homography_matches

H_TRUE = np.array([[0.9, -0.15, 30.0], [0.12, 1.05, -12.0], [2e-4, -1e-4, 1.0]])


def _two_view_scene(n=200, rng=0):
    """Random 3-D points seen by two calibrated cameras; returns pixel points and the true F."""
    rng = np.random.default_rng(rng)
    X = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(4, 9, n)]
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    a = 0.12
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([-1.0, 0.1, 0.2])
    x1 = X @ K.T
    x2 = (X @ R.T + t) @ K.T
    p1, p2 = x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Kinv = np.linalg.inv(K)
    F = Kinv.T @ tx @ R @ Kinv
    return p1, p2, F / np.linalg.norm(F)


# ------------------------------------------------------------------------------------------ fitting


def test_normalise_points_hartley():
    pts = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0], [4.0, 4.0]])
    n, T = normalise_points(pts)
    np.testing.assert_allclose(n.mean(axis=0), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1).mean(), np.sqrt(2))
    np.testing.assert_allclose((np.c_[pts, np.ones(4)] @ T.T)[:, :2], n)


def test_fit_homography_exact_from_four_points():
    p1 = np.array([[10.0, 20.0], [300.0, 25.0], [280.0, 240.0], [15.0, 200.0]])
    H = fit_homography(p1, apply_homography(H_TRUE, p1))
    np.testing.assert_allclose(H, H_TRUE / H_TRUE[2, 2], rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("n", [0, 1, 2, 3])
def test_fit_homography_too_few_points(n):
    p = np.arange(2 * n, dtype=float).reshape(n, 2)
    assert fit_homography(p, p) is None


def test_fit_homography_collinear_is_degenerate():
    p1 = np.c_[np.arange(6.0), 2 * np.arange(6.0)]
    assert fit_homography(p1, p1 + 1) is None


def test_fit_homography_duplicated_points_is_degenerate():
    p1 = np.array([[0.0, 0.0], [0.0, 0.0], [5.0, 5.0], [5.0, 5.0]])
    assert fit_homography(p1, p1) is None


def test_fit_fundamental_two_view_scene():
    p1, p2, F_true = _two_view_scene()
    F = fit_fundamental(p1, p2)
    assert np.linalg.matrix_rank(F, tol=1e-8) == 2
    d2, d1 = epipolar_distances(F, p1, p2)
    assert max(d1.max(), d2.max()) < 1e-6
    assert min(np.linalg.norm(F - F_true), np.linalg.norm(F + F_true)) < 1e-6


def test_fit_fundamental_too_few_points():
    p1, p2, _ = _two_view_scene(7)
    assert fit_fundamental(p1, p2) is None


def test_errors_exact_values():
    H = np.array([[1.0, 0, 3], [0, 1, 4], [0, 0, 1]])
    fwd, bwd = homography_transfer_errors(H, [[0.0, 0.0]], [[0.0, 0.0]])
    np.testing.assert_allclose([fwd[0], bwd[0]], [5.0, 5.0])
    # Pure horizontal translation: epipolar lines are the rows y = const.
    F = np.array([[0.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    d2, d1 = epipolar_distances(F, [[10.0, 5.0]], [[40.0, 8.0]])
    np.testing.assert_allclose([d2[0], d1[0]], [3.0, 3.0])
    np.testing.assert_allclose(model_errors(F, "F", [[10.0, 5.0]], [[40.0, 8.0]]), [3.0])


# ----------------------------------------------------------------------------------------- sampling


def test_top_ranked_sample_counts_duplicates_once():
    # Keypoint 0 of image 1 matched three times: the normalised count only grows with new keypoints.
    m = np.array([[0, 0], [0, 1], [0, 2], [1, 3], [2, 4], [3, 5]])
    s = np.arange(6.0)
    np.testing.assert_array_equal(top_ranked_sample(m, s, size=2), [0, 1, 2, 3])
    np.testing.assert_array_equal(top_ranked_sample(m, s, size=4), [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(top_ranked_sample(m, s, size=10), [0, 1, 2, 3, 4, 5])


def test_top_ranked_sample_follows_scores_and_empty():
    m = np.array([[0, 0], [1, 1], [2, 2]])
    np.testing.assert_array_equal(top_ranked_sample(m, [0.3, 0.1, 0.2], size=2), [1, 2])
    assert top_ranked_sample(np.empty((0, 2), np.int64), None, size=12).shape == (0,)


# --------------------------------------------------------------------------------------------- 1SAC


def test_one_sac_recovers_planted_homography():
    pm = planted_homography_matches(600, 0.5, noise=0.5, informative_scores=True, rng=1)
    # Make the 12 best-ranked matches inliers, the situation 1SAC relies on.
    scores = pm.scores.copy()
    scores[np.flatnonzero(pm.is_inlier)[:12]] = -1.0
    fit = one_sac(pm.kpts1, pm.kpts2, pm.matches, scores, kind="H", threshold=5.0)
    assert len(fit.sample) == 3 * MIN_SAMPLE["H"]
    Hn = fit.model / fit.model[2, 2]
    corners = np.array([[0.0, 0.0], [639.0, 0.0], [639.0, 479.0], [0.0, 479.0]])
    assert np.abs(apply_homography(Hn, corners) - apply_homography(pm.H, corners)).max() < 3.0
    assert fit.keep[pm.is_inlier].mean() > 0.99
    # Uniform outliers can fall near the model by chance; a 5 px band holds very few of them.
    assert fit.keep[~pm.is_inlier].mean() < 0.02


def test_one_sac_fundamental_on_two_view_scene():
    p1, p2, _ = _two_view_scene(150, rng=3)
    rng = np.random.default_rng(4)
    n_out = 50
    q1 = np.vstack([p1, rng.uniform(0, 640, (n_out, 2))])
    q2 = np.vstack([p2, rng.uniform(0, 480, (n_out, 2))])
    m = np.c_[np.arange(len(q1)), np.arange(len(q1))]
    scores = np.r_[np.linspace(0, 1, 150), np.linspace(0.5, 2, n_out)]
    fit = one_sac(q1, q2, m, scores, kind="F", threshold=2.0)
    assert len(fit.sample) == 24
    assert fit.keep[:150].all()
    d2, d1 = epipolar_distances(fit.model, p1, p2)
    assert np.maximum(d1, d2).max() < 1e-6
    assert fit.keep[150:].mean() < 0.2


@pytest.mark.parametrize("kind", ["H", "F"])
def test_one_sac_too_few_matches_keeps_nothing(kind):
    k = MIN_SAMPLE[kind] - 1
    p = np.random.default_rng(0).uniform(0, 100, (k, 2))
    m = np.c_[np.arange(k), np.arange(k)]
    fit = one_sac(p, p, m, kind=kind)
    assert fit.model is None and fit.keep.shape == (k,) and not fit.keep.any()


def test_one_sac_many_to_many_below_q_distinct_keeps_nothing():
    # Six matches, but only three distinct image-1 keypoints: fewer than q = 4 once normalised.
    p1 = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    p2 = np.random.default_rng(0).uniform(0, 50, (6, 2))
    m = np.array([[0, 0], [0, 1], [1, 2], [1, 3], [2, 4], [2, 5]])
    assert not one_sac(p1, p2, m, kind="H").keep.any()


def test_one_sac_empty():
    fit = one_sac(np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.int64), kind="H")
    assert fit.keep.shape == (0,) and fit.model is None


def test_one_sac_bad_input_names_argument():
    with pytest.raises(ValueError, match="kind"):
        one_sac(np.zeros((4, 2)), np.zeros((4, 2)), np.c_[np.arange(4), np.arange(4)], kind="E")
    with pytest.raises(ValueError, match="matches"):
        one_sac(np.zeros((4, 2)), np.zeros((4, 2)), [[0, 9]], kind="H")


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_one_sac_keeps_exact_homography_matches(seed):
    """Invariant: noiseless one-to-one matches of a homography are all kept."""
    rng = np.random.default_rng(seed)
    p1 = rng.uniform(0, 400, (30, 2))
    m = np.c_[np.arange(30), np.arange(30)]
    fit = one_sac(p1, apply_homography(H_TRUE, p1), m, rng.uniform(size=30), kind="H", threshold=1.0)
    assert fit.keep.all()


# ------------------------------------------------------------------------------------------- RANSAC


def test_ransac_seeded_and_recovers_homography():
    pm = planted_homography_matches(400, 0.4, noise=0.5, rng=2)
    a = ransac(pm.kpts1, pm.kpts2, pm.matches, kind="H", threshold=5.0, rng=7)
    b = ransac(pm.kpts1, pm.kpts2, pm.matches, kind="H", threshold=5.0, rng=7)
    np.testing.assert_array_equal(a.keep, b.keep)
    np.testing.assert_allclose(a.model, b.model)
    assert a.keep[pm.is_inlier].mean() > 0.98
    assert a.keep[~pm.is_inlier].mean() < 0.03


def test_ransac_prosac_uses_the_ranking_and_maps_back():
    """PROSAC sees the matches best first; the returned mask and errors follow the caller's order."""
    pm = planted_homography_matches(500, 0.1, noise=0.5, informative_scores=True, rng=3)
    fit = ransac(pm.kpts1, pm.kpts2, pm.matches, pm.scores, kind="H", threshold=5.0, sampler="prosac", rng=1)
    assert fit.keep[pm.is_inlier].mean() > 0.98 and fit.keep[~pm.is_inlier].mean() < 0.03
    np.testing.assert_array_equal(fit.keep, fit.errors <= 5.0)
    np.testing.assert_allclose(fit.errors, model_errors(fit.model, "H", pm.kpts1, pm.kpts2))
    assert set(fit.sample) <= set(np.flatnonzero(fit.keep))
    with pytest.raises(ValueError, match="sampler"):
        ransac(pm.kpts1, pm.kpts2, pm.matches, kind="H", sampler="napsac")


def test_ransac_fundamental_and_too_few():
    p1, p2, _ = _two_view_scene(120, rng=5)
    m = np.c_[np.arange(120), np.arange(120)]
    fit = ransac(p1, p2, m, kind="F", threshold=2.0, rng=0)
    assert fit.keep.all()
    few = ransac(p1[:5], p2[:5], m[:5], kind="F", rng=0)
    assert few.model is None and not few.keep.any()


def test_apply_model_step_dispatch():
    pm = planted_homography_matches(100, 0.8, rng=0)
    none = apply_model_step("none", pm.kpts1, pm.kpts2, pm.matches, pm.scores, kind="H")
    assert none.keep.all()
    assert apply_model_step("1sac", pm.kpts1, pm.kpts2, pm.matches, pm.scores, kind="H").keep.shape == (100,)
    pro = apply_model_step("prosac", pm.kpts1, pm.kpts2, pm.matches, pm.scores, kind="H", threshold=5.0, rng=0)
    assert pro.keep[pm.is_inlier].mean() > 0.98
    with pytest.raises(ValueError, match="unknown model step"):
        apply_model_step("lmeds", pm.kpts1, pm.kpts2, pm.matches, pm.scores, kind="H")
    assert model_kind_for("planar") == "H" and model_kind_for("depth") == "F"
    with pytest.raises(ValueError, match="pair kind"):
        model_kind_for("spherical")


def test_dlt_normal_matrix_equals_design_gram():
    """The 9 x 9 normal matrix built from its block sums equals A^T A of the DLT design matrix (whose rows are
    also checked against the homography they vanish on)."""
    from ctxmatch_lib.geometry import dlt_design, dlt_normal_matrix

    rng = np.random.default_rng(0)
    n1 = rng.normal(size=(40, 2))
    h = np.array([[1.1, 0.2, 0.3], [-0.1, 0.9, -0.2], [0.05, -0.02, 1.0]])
    w = np.c_[n1, np.ones(40)] @ h.T
    n2 = w[:, :2] / w[:, 2:]
    a = dlt_design(n1, n2)
    np.testing.assert_allclose(a @ h.reshape(-1), 0.0, atol=1e-12)
    np.testing.assert_allclose(dlt_normal_matrix(n1, n2), a.T @ a, rtol=1e-12, atol=1e-12)
    m = dlt_normal_matrix(n1, n2 + rng.normal(size=n2.shape))
    np.testing.assert_array_equal(m, m.T)
