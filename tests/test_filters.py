"""Tests of the peer spatial filters behind ``FILTERS`` (th, GMS, LPM, GLPM, VFC, LLT, AdaLAM, RFM-SCAN, PFM, LMR)."""

from __future__ import annotations

import random

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import apply_homography, planted_homography_matches
from filter_cases import SIZE, grid_translation, identity_matches, many_to_many_case, run_filter

PEERS = ["th", "gms", "lpm", "glpm", "vfc", "llt", "adalam", "rfm_scan", "pfm", "lmr"]
SPATIAL = [name for name in PEERS if name != "th"]
# PGM, BM and SCV have their own, stricter cases in test_filters_graph.py; the checks that are the same for
# every filter run here for them too.
GRAPH = ["pgm", "bm", "scv"]

# th only sees the scores: with the planted informative scores (inliers in [0, 0.7], outliers in
# [0.3, 1]) its precision is 0.4 / (0.4 + 0.6 * 5 / 7) ~ 0.48 by construction.
MIN_PRECISION = {"th": 0.45}
DEFAULT_MIN_PRECISION = 0.8


def test_registry_lists_every_peer():
    for name in PEERS:
        assert name in FILTERS
        assert callable(FILTERS[name])


@pytest.mark.parametrize("name", PEERS)
@pytest.mark.parametrize("seed", [0, 1])
def test_planted_homography_precision(name, seed):
    pm = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, informative_scores=True, rng=seed)
    keep = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores)
    tp = int((keep & pm.is_inlier).sum())
    precision = tp / max(int(keep.sum()), 1)
    recall = tp / int(pm.is_inlier.sum())
    print(f"{name}: precision {precision:.3f} recall {recall:.3f} kept {int(keep.sum())}")
    assert precision >= MIN_PRECISION.get(name, DEFAULT_MIN_PRECISION) > 0.4
    assert recall > 0.15


@pytest.mark.parametrize("name", SPATIAL)
def test_planted_without_scores(name):
    # Spatial filters must work on geometry alone (scores=None: all equal).
    pm = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, rng=3)
    keep = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, None)
    precision = (keep & pm.is_inlier).sum() / max(keep.sum(), 1)
    assert precision >= DEFAULT_MIN_PRECISION


@pytest.mark.parametrize("name", PEERS)
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_tiny_inputs_return_a_mask(name, k):
    rng = np.random.default_rng(k)
    kpts = rng.uniform(0, 100, size=(k, 2))
    run_filter(name, kpts, kpts + 1.0, identity_matches(k), rng.uniform(size=k))
    run_filter(name, kpts, kpts + 1.0, np.empty((0, 2), np.int64) if k == 0 else identity_matches(k), None)


@pytest.mark.parametrize("name", PEERS + GRAPH)
def test_empty_keypoints(name):
    keep = run_filter(name, np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.int64), None)
    assert keep.shape == (0,)


@pytest.mark.parametrize("name", PEERS)
def test_collinear_keypoints(name):
    t = np.linspace(0, 500, 60)
    kpts1 = np.c_[t, 0.5 * t + 10]
    kpts2 = kpts1 + (5.0, 2.0)
    run_filter(name, kpts1, kpts2, identity_matches(60), np.linspace(0, 1, 60))


@pytest.mark.parametrize("name", PEERS)
def test_duplicate_keypoints(name):
    kpts = np.tile([[100.0, 100.0]], (20, 1))
    run_filter(name, kpts, kpts, identity_matches(20), None)


@pytest.mark.parametrize("name", SPATIAL)
def test_identical_images_keep_most(name):
    rng = np.random.default_rng(5)
    kpts = rng.uniform([0, 0], [639, 479], size=(400, 2))
    keep = run_filter(name, kpts, kpts.copy(), identity_matches(400), rng.uniform(size=400) * 0.5)
    if name != "gms":  # 400 matches over a 20 x 20 grid are below GMS's statistical threshold
        assert keep.mean() > 0.9


@pytest.mark.parametrize("name", PEERS)
def test_many_to_many_input(name):
    keep, truth = many_to_many_case(name)
    assert (keep & truth).sum() / max(keep.sum(), 1) > (0.55 if name == "th" else 0.9)


# ----- one tiny exact case per filter -----------------------------------------------------------------


def test_th_exact():
    k = np.zeros((4, 2))
    keep = run_filter("th", k, k, identity_matches(4), [0.1, 0.8, 0.81, 1.0])
    np.testing.assert_array_equal(keep, [True, True, False, False])
    np.testing.assert_array_equal(run_filter("th", k, k, identity_matches(4), None), [True] * 4)
    np.testing.assert_array_equal(run_filter("th", k, k, identity_matches(4), [0.1, 0.3, 0.5, 0.7], threshold=0.4),
                                  [True, True, False, False])


def test_gms_exact_dense_cluster():
    # 300 matches filling the 3 x 3 cells (32 x 24 px each) of a patch, translated by exactly (3, 2) cells:
    # every cell pair is far above 6 sqrt(n); a match from the patch to elsewhere is not the winning pair.
    rng = np.random.default_rng(0)
    x = rng.uniform([192, 144], [287, 215], size=(300, 2))
    y = x + (96.0, 48.0)
    x = np.vstack([x, [250.0, 180.0]])
    y = np.vstack([y, [30.0, 400.0]])
    keep = run_filter("gms", x, y, identity_matches(301))
    assert keep[:300].all() and not keep[300]


def test_gms_rotation_kernels_find_a_rotated_cluster():
    rng = np.random.default_rng(1)
    x = rng.uniform(160, 480, size=(2000, 2))
    c = np.array([320.0, 240.0])
    R = np.array([[0.0, -1.0], [1.0, 0.0]])  # 90 degrees
    y = (x - c) @ R.T + c
    upright = run_filter("gms", x, y, identity_matches(2000))
    rotated = run_filter("gms", x, y, identity_matches(2000), with_rotation=True)
    assert rotated.mean() > 0.8 and rotated.sum() > upright.sum()


@pytest.mark.parametrize("name", ["lpm", "glpm", "vfc", "llt", "adalam", "rfm_scan", "pfm", "lmr"])
def test_translation_grid_exact(name):
    # A rigid translation preserves every neighbourhood, motion and local affinity; the lone match
    # sent to the corner is inconsistent with all of them.
    x, y = grid_translation()
    keep = run_filter(name, x, y, identity_matches(len(x)), np.full(len(x), 0.1))
    assert not keep[0]
    assert keep[1:].all()


def test_glpm_uses_scores_for_the_guide():
    # Only the confident matches guide: with every score above the strict ratio, GLPM falls back to the
    # whole set and still finds the translation.
    x, y = grid_translation()
    keep = run_filter("glpm", x, y, identity_matches(len(x)), np.full(len(x), 0.9))
    assert not keep[0] and keep[1:].all()


def _similarity_shapes(n, scale, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.tile(scale * np.array([[c, -s], [s, c]]), (n, 1, 1))


def test_adalam_shapes_reject_inconsistent_orientation():
    # Same geometry, but the image-2 shapes of half the grid are rotated by 90 degrees: those matches
    # leave the neighbourhoods of the consistent seeds, and the consistent half survives.
    x, y = grid_translation(n_side=10, step=15.0)
    n = len(x)
    A1 = _similarity_shapes(n, 2.0, 0.0)
    A2 = _similarity_shapes(n, 2.0, 0.0)
    flipped = np.arange(n) % 2 == 1
    A2[flipped] = _similarity_shapes(int(flipped.sum()), 2.0, np.pi / 2)
    scores = np.where(flipped, 0.5, 0.1)
    keep = run_filter("adalam", x, y, identity_matches(n), scores, shapes1=A1, shapes2=A2)
    assert keep[~flipped][1:].all()
    assert not keep[flipped].any()
    # Without shapes the geometry alone accepts them all.
    keep = run_filter("adalam", x, y, identity_matches(n), scores)
    assert keep[1:].all()


def _planted_with_shapes(seed):
    """Planted case with image-2 shapes from the homography's Jacobian at inliers, random at outliers."""
    pm = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, informative_scores=True, rng=seed)
    n = len(pm.kpts1)
    A1 = _similarity_shapes(n, 3.0, 0.0)
    eps = 1e-3
    J = np.stack([(apply_homography(pm.H, pm.kpts1 + d) - apply_homography(pm.H, pm.kpts1 - d)) / (2 * eps)
                  for d in ([eps, 0.0], [0.0, eps])], -1)
    A2 = J @ A1
    rng = np.random.default_rng(seed)
    out = ~pm.is_inlier
    A2[out] = [_similarity_shapes(1, 3.0 * rng.uniform(0.5, 2), rng.uniform(-np.pi, np.pi))[0]
               for _ in range(int(out.sum()))]
    return pm, A1, A2


def test_adalam_planted_with_shapes():
    pm, A1, A2 = _planted_with_shapes(2)
    keep = run_filter("adalam", pm.kpts1, pm.kpts2, pm.matches, pm.scores, shapes1=A1, shapes2=A2)
    precision = (keep & pm.is_inlier).sum() / keep.sum()
    recall = (keep & pm.is_inlier).sum() / pm.is_inlier.sum()
    assert precision > 0.95 and recall > 0.8


# ----- determinism and argument checks --------------------------------------------------------------


@pytest.mark.parametrize("name", PEERS + GRAPH)
def test_deterministic(name):
    pm = planted_homography_matches(600, 0.4, noise=0.5, image_size=SIZE, rng=11)
    a = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores)
    b = run_filter(name, pm.kpts1.copy(), pm.kpts2.copy(), pm.matches.copy(), pm.scores.copy())
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["vfc", "llt", "adalam", "rfm_scan"])
def test_seeded_filters_accept_rng(name):
    pm = planted_homography_matches(600, 0.4, noise=0.5, image_size=SIZE, rng=12)
    a = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, None, rng=3)
    b = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, None, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", PEERS + GRAPH)
def test_bad_arguments_name_the_argument(name):
    k = np.zeros((3, 2))
    m = identity_matches(3)
    f = FILTERS[name]
    with pytest.raises(ValueError, match="matches"):
        f(k, k, [[0, 5]], None, image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="scores"):
        f(k, k, m, [0.1, 0.2], image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="image_size2"):
        f(k, k, m, None, image_size1=SIZE, image_size2=(0, 10))
    with pytest.raises(ValueError, match="kpts1"):
        f(np.zeros((3, 3, 1)), k, m, None, image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="shapes1"):
        f(k, k, m, None, image_size1=SIZE, image_size2=SIZE, shapes1=np.zeros((3, 2)),
          shapes2=np.zeros((3, 2, 2)))


def test_th_applies_the_nnr_threshold_on_the_scale_of_d_plus_scores():
    from ctxmatch_lib.filters import FILTERS

    k = np.zeros((3, 2))
    m = [[0, 0], [1, 1], [2, 2]]
    r = np.array([0.7, 0.8, 0.9])  # NNR ratios
    common = dict(image_size1=(8, 8), image_size2=(8, 8))
    plain = FILTERS["th"](k, k, m, r, ratio="D>=", **common)
    plus = FILTERS["th"](k, k, m, r / (1 + r), ratio="D+", **common)
    assert plain.tolist() == plus.tolist() == [True, True, False]
    with pytest.raises(ValueError, match="ratio"):
        FILTERS["th"](k, k, m, r, ratio="D", **common)


# ----- RFM-SCAN: the tree search gives the dense computation's mask ---------------------------------------


def _rfm_scan_dense(x, y, size, gamma=10.0, pct=0.05, mu=(0.1, 0.08), rng=0):
    """RFM-SCAN with the full K x K distance matrix (the definition the k-d tree search must reproduce)."""
    n = len(x)
    n_noise = int(np.floor(min(0.05 * n, 20) + 0.5))  # MATLAB's round
    draw = random.Random(rng).random  # Octave's rand after rand('state', rng), as the authors' demo
    u = np.array([draw() for _ in range(4 * n_noise)]).reshape(2, 2, n_noise)  # rand(n, 2) column by column
    x, y = np.vstack([x, u[0].T * x.max(0)]), np.vstack([y, u[1].T * y.max(0)])
    f = np.hstack([x, y, y - x])
    span = f.max(0) - f.min(0)
    f = ((f - f.min(0)) / np.where(span > 0, span, 1.0)).astype(np.float32)
    min_pts = int(min(max(round(len(f) * pct), 3), 30))

    def pair(a):
        dx = f[:, None, a] - f[None, :, a]
        dy = f[:, None, a + 1] - f[None, :, a + 1]
        return np.sqrt(dx * dx + dy * dy)

    d1, d2, dv = pair(0), pair(2), pair(4)
    D = d1 + d2 + (1.0 + np.float32(gamma) * np.exp(-np.minimum(d1, d2))) * dv

    def clustered(Dm, m):
        kth = np.partition(Dm, min_pts - 1, axis=1)[:, min_pts - 1]
        eps = kth.min() + np.float32(m) * (kth.max() - kth.min())
        core = kth <= eps
        return core | (Dm[core] <= eps).any(0)

    first = clustered(D, mu[0])
    ci = np.zeros(len(f), bool)
    ci[:n] = first[:n]
    return clustered(D * np.where(ci, 1.0, 100.0).astype(np.float32)[None, :], mu[1])[:n]


@pytest.mark.parametrize("n, ratio, seed", [(600, 0.4, 0), (1200, 0.1, 1), (900, 0.9, 2), (40, 0.5, 3)])
def test_rfm_scan_equals_dense_definition(n, ratio, seed):
    pm = planted_homography_matches(n, ratio, noise=0.5, image_size=SIZE, rng=seed)
    keep = run_filter("rfm_scan", pm.kpts1, pm.kpts2, pm.matches, None)
    np.testing.assert_array_equal(keep, _rfm_scan_dense(pm.kpts1, pm.kpts2, SIZE))


# ----- PFM --------------------------------------------------------------------------------------------------


def test_pfm_min_cut_is_the_exact_minimum():
    # E(l) = sum u_i l_i - sum w_ij l_i l_j over 6 nodes: the cut's labels equal brute force over 2^6.
    from itertools import product

    from ctxmatch_lib.filters.pfm import _min_cut

    u = np.array([1.5, 1.5, 1.5, -0.2, 2.0, 0.7])
    e = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [3, 4], [4, 5], [0, 5]])
    w = np.array([1.0, 0.9, 0.8, 0.1, 0.3, 2.5, 0.05])
    labels = _min_cut(6, u, e, w)

    def energy(lab):
        lab = np.asarray(lab, float)
        return u @ lab - (w * lab[e[:, 0]] * lab[e[:, 1]]).sum()

    best = min(product([0, 1], repeat=6), key=energy)
    np.testing.assert_array_equal(labels, np.array(best, bool))
    # The triangle 0-1-2 costs 4.5 and earns only 2.7; 3-4-5 cost 2.5 and earn 2.8 (0.3 + 2.5).
    np.testing.assert_array_equal(labels, [False, False, False, True, True, True])


def test_pfm_local_affines_from_shapes_and_fitted():
    from ctxmatch_lib.filters.pfm import local_affines

    rng = np.random.default_rng(0)
    x = rng.uniform(0, 200, size=(50, 2))
    L = np.array([[1.2, -0.3], [0.4, 0.9]])
    y = x @ L.T + (5.0, 7.0)
    A1 = np.tile(np.diag([2.0, 3.0]), (50, 1, 1))
    np.testing.assert_allclose(local_affines(x, y, A1, L @ A1), np.tile(L, (50, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(local_affines(x, y), np.tile(L, (50, 1, 1)), atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_pfm_planted_with_shapes(seed):
    pm, A1, A2 = _planted_with_shapes(seed)
    keep = run_filter("pfm", pm.kpts1, pm.kpts2, pm.matches, pm.scores, shapes1=A1, shapes2=A2)
    precision = (keep & pm.is_inlier).sum() / keep.sum()
    recall = (keep & pm.is_inlier).sum() / pm.is_inlier.sum()
    assert precision > 0.95 and recall > 0.8


def test_pfm_needs_both_shapes():
    x, y = grid_translation()
    with pytest.raises(ValueError, match="shapes1 and shapes2"):
        run_filter("pfm", x, y, identity_matches(len(x)), None, shapes1=_similarity_shapes(len(x), 1.0, 0.0))


def test_pfm_progressive_rounds_recover_from_empty_seeds():
    # The best-scored tenth is pure outliers: the seed graph keeps nothing, the next rounds start afresh.
    pm = planted_homography_matches(600, 0.5, noise=0.5, image_size=SIZE, rng=4)
    scores = np.where(pm.is_inlier, 0.5, 0.6)
    scores[np.flatnonzero(~pm.is_inlier)[:60]] = 0.0
    keep = run_filter("pfm", pm.kpts1, pm.kpts2, pm.matches, scores)
    assert (keep & pm.is_inlier).sum() / keep.sum() > 0.95 and keep[pm.is_inlier].mean() > 0.5


# ----- LMR --------------------------------------------------------------------------------------------------


def test_lmr_features_exact():
    from ctxmatch_lib.filters.lmr import SCALES, lmr_features

    # Five matches moved by one translation: every neighbour is shared and every motion agrees; at scale k
    # only min(k, 4) neighbours exist, so both features are 4 / k. The sixth match's motion is opposite.
    x = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 5.0]])
    f = lmr_features(x, x + (3.0, 4.0))
    expected = np.repeat([min(k, 4) / k for k in SCALES], 2)
    np.testing.assert_allclose(f, np.tile(expected, (5, 1)), rtol=0, atol=1e-15)
    y = x + (3.0, 4.0)
    y[4] = x[4] - (3.0, 4.0)  # same neighbours (the centre), motion reversed: similarity -1
    f = lmr_features(x, y)
    np.testing.assert_allclose(f[4, 0::2], [min(k, 4) / k for k in SCALES], atol=1e-15)
    np.testing.assert_allclose(f[4, 1::2], [-min(k, 4) / k for k in SCALES], atol=1e-15)
    assert f.shape == (5, 2 * len(SCALES))


def test_lmr_exported_trees_predict_as_scikit_learn():
    from ctxmatch_lib.filters import lmr

    rng = np.random.default_rng(1)
    x, y, inl = lmr.synthetic_pair(rng)
    F = lmr.lmr_features(x, y)
    clf = lmr.training._fit(F, inl, 0, 15, 3, 0.2)
    np.testing.assert_allclose(lmr.LMRModel(lmr.model._export(clf, 1)).proba(1, F), clf.predict_proba(F)[:, 1],
                               rtol=0, atol=1e-12)


TINY_LMR = dict(n_pairs=4, max_samples_per_pair=150, n_estimators=8)


def test_lmr_training_is_repeatable(tmp_path):
    from ctxmatch_lib.filters.lmr import LMRModel, lmr_filter, train_lmr

    a = train_lmr(seed=3, **TINY_LMR, path=tmp_path / "a.npz")
    b = train_lmr(seed=3, **TINY_LMR)
    assert a.arrays.keys() == b.arrays.keys()
    for key in a.arrays:
        np.testing.assert_array_equal(a.arrays[key], b.arrays[key], err_msg=key)
    c = train_lmr(seed=4, **TINY_LMR)
    assert any(a.arrays[k].shape != c.arrays[k].shape or not np.array_equal(a.arrays[k], c.arrays[k])
               for k in a.arrays)
    loaded = LMRModel.load(tmp_path / "a.npz")
    x, y = grid_translation()
    np.testing.assert_array_equal(lmr_filter(x, y, identity_matches(len(x)), image_size1=SIZE, image_size2=SIZE, model=a),
                                  lmr_filter(x, y, identity_matches(len(x)), image_size1=SIZE, image_size2=SIZE,
                                             model=loaded))


def test_lmr_shipped_model_is_installed():
    from ctxmatch_lib.filters.lmr import MODEL_PATH, LMRModel

    assert MODEL_PATH.is_file()
    model = LMRModel.load()
    assert {"1_offsets", "2_offsets", "1_threshold", "2_value"} <= set(model.arrays)


@pytest.mark.slow
def test_lmr_shipped_model_equals_default_training():
    # The shipped model is train_lmr(**LMR_TRAIN_DEFAULTS) (about 10-30 s).
    from ctxmatch_lib.filters.lmr import LMR_TRAIN_DEFAULTS, LMRModel, train_lmr

    shipped = LMRModel.load()
    fresh = train_lmr(**LMR_TRAIN_DEFAULTS)
    assert shipped.arrays.keys() == fresh.arrays.keys()
    for key in fresh.arrays:
        np.testing.assert_array_equal(shipped.arrays[key], fresh.arrays[key], err_msg=key)
