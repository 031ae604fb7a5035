"""Tests of MOP and MOP+MiHo (``ctxmatch_lib.filters.mop``): a planted grid with one outlier, two planted planes
with uniform outliers, determinism, degenerate inputs, parameter errors, many-to-many matches and the
independence from the order of the rows (and of the scores), the authors' float32 stopping count."""

from __future__ import annotations

import numpy as np
import pytest

from ctxmatch_lib.filters.mop import PlanarClusters, mop_clusters, mop_miho_clusters
from ctxmatch_lib.filters.mop.homography import best_rotation, fit_homographies, fit_minimal, supports
from ctxmatch_lib.filters.mop import ransac
from ctxmatch_lib.filters.mop.params import MIHO_DEFAULTS, MOP_DEFAULTS

SIZE = (1000, 800)
FILTERS = [mop_clusters, mop_miho_clusters]
# Two planes far apart in image 1, mapped by clearly different homographies.
H_A = np.array([[1.05, 0.08, 40.0], [-0.06, 0.98, 25.0], [1e-4, -5e-5, 1.0]])
H_B = np.array([[0.85, -0.2, 260.0], [0.15, 1.1, -60.0], [-2e-4, 1e-4, 1.0]])


def _apply(H, p):
    q = np.c_[p, np.ones(len(p))] @ H.T
    return q[:, :2] / q[:, 2:]


def _call(f, x, y, m=None, scores=None, **kw):
    m = np.c_[np.arange(len(x)), np.arange(len(x))] if m is None else m
    out = f(x, y, m, scores, image_size1=SIZE, image_size2=SIZE, **kw)
    assert isinstance(out, PlanarClusters)
    k, p = len(m), len(out.homographies)
    assert out.keep.dtype == bool and out.keep.shape == (k,)
    assert out.labels.dtype == np.int64 and out.labels.shape == (k,)
    np.testing.assert_array_equal(out.keep, out.labels >= 0)
    assert out.homographies.shape == (p, 3, 3) and out.labels.max(initial=-1) < p
    if f is mop_clusters:
        assert out.middle1 is None and out.middle2 is None
    else:
        assert out.middle1.shape == out.middle2.shape == (p, 3, 3)
    return out


def two_planes(n_per_plane=300, n_out=200, noise=0.5, seed=0):
    """``(x, y, truth)``: two planted planes (``truth`` 0 and 1) and uniform outliers (``truth`` -1), shuffled."""
    rng = np.random.default_rng(seed)
    xa = np.c_[rng.uniform(20, 430, n_per_plane), rng.uniform(20, 780, n_per_plane)]
    xb = np.c_[rng.uniform(570, 980, n_per_plane), rng.uniform(20, 780, n_per_plane)]
    x = np.vstack([xa, xb, rng.uniform(0, 1, (n_out, 2)) * SIZE])
    y = np.vstack([_apply(H_A, xa), _apply(H_B, xb), rng.uniform(0, 1, (n_out, 2)) * SIZE])
    y[: 2 * n_per_plane] += rng.normal(0, noise, (2 * n_per_plane, 2))
    truth = np.r_[np.zeros(n_per_plane, int), np.ones(n_per_plane, int), np.full(n_out, -1)]
    p = rng.permutation(len(x))
    return x[p], y[p], truth[p]


@pytest.fixture(scope="module")
def planted():
    return two_planes()


@pytest.fixture(scope="module", params=FILTERS, ids=["mop", "mop_miho"])
def planted_run(request, planted):
    x, y, truth = planted
    return request.param, _call(request.param, x, y)


# --- a tiny hand-built case ------------------------------------------------------------------------------------

@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_grid_under_a_homography_drops_its_one_outlier(f):
    g = np.stack(np.meshgrid(np.arange(7) * 60.0 + 100, np.arange(7) * 60.0 + 80), -1).reshape(-1, 2)
    y = _apply(H_A, g)
    y[0] = (900.0, 700.0)
    out = _call(f, g, y)
    assert not out.keep[0] and out.keep[1:].all()
    assert len(out.homographies) == 1
    # MiHo's middle points (p1 + H p1) / 2 are not exactly a homography of p1 under a perspective H.
    np.testing.assert_allclose(_apply(out.homographies[0], g[1:]), y[1:], atol=1e-6 if f is mop_clusters else 1e-2)


def test_translated_grid_of_the_registry():
    # The registry's grid: 8 x 8 points 20 px apart, translated, point 0 replaced by an outlier.
    g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    y = g + (7.0, -3.0)
    y[0] = (300.0, 200.0)
    m = np.c_[np.arange(64), np.arange(64)]
    kw = dict(image_size1=(400, 300), image_size2=(400, 300))
    kept = lambda out: (bool(out.keep[0]), int(out.keep[1:].sum()))  # noqa: E731
    assert kept(mop_clusters(g, y, m, **kw)) == (False, 63)
    # Noise-free rigid motion gives MiHo's rotation vote no inlier pair: the outlier's pairs pick the half
    # turn, which collapses the middle points. With a little noise, or without the vote, it finds the plane.
    assert kept(mop_miho_clusters(g, y, m, **kw)) == (False, 0)
    assert kept(mop_miho_clusters(g, y, m, rotations=1, **kw)) == (False, 63)
    noisy = y + np.random.default_rng(0).normal(0, 0.3, y.shape)
    assert kept(mop_miho_clusters(g, noisy, m, **kw)) == (False, 63)


# --- planted planes with outliers ------------------------------------------------------------------------------

def test_planted_inliers_kept_outliers_rejected(planted_run, planted):
    f, out = planted_run
    truth = planted[2]
    assert out.keep[truth >= 0].mean() >= 0.97
    # MiHo tests its threshold on the middle plane: about twice MOP's in image 2, so more chance outliers pass.
    assert out.keep[truth < 0].mean() <= (0.05 if f is mop_clusters else 0.1)


def test_planted_labels_separate_the_planes(planted_run, planted):
    _, out = planted_run
    x, y, truth = planted
    major = []
    for k, H in ((0, H_A), (1, H_B)):
        lab = out.labels[(truth == k) & out.keep]
        top = np.bincount(lab).argmax()
        assert (lab == top).mean() >= 0.9
        major.append(top)
        # the plane's homography is the planted one on its points
        pts = x[truth == k]
        assert np.median(np.linalg.norm(_apply(out.homographies[top], pts) - _apply(H, pts), axis=1)) < 1.0
    assert major[0] != major[1]


def test_miho_middle_homographies_compose_to_the_plane(planted):
    x, y, _ = planted
    out = _call(mop_miho_clusters, x, y)
    for H12, M1, M2 in zip(out.homographies, out.middle1, out.middle2):
        composed = np.linalg.inv(M2) @ M1
        np.testing.assert_allclose(composed / composed[2, 2], H12, rtol=1e-6, atol=1e-8)


# --- determinism, order, scores --------------------------------------------------------------------------------

@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_deterministic_for_a_seed(f):
    x, y, _ = two_planes(150, 100, seed=3)
    a, b = _call(f, x, y, seed=5), _call(f, x, y, seed=5)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.homographies, b.homographies)


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_row_order_keypoint_order_and_scores_do_not_matter(f):
    x, y, _ = two_planes(150, 100, seed=4)
    n = len(x)
    base = _call(f, x, y, scores=np.linspace(0, 1, n))
    rng = np.random.default_rng(0)
    p1, p2, rows = rng.permutation(n), rng.permutation(n), rng.permutation(n)
    # keypoints stored in another order, matches listed in another order, other scores
    inv1, inv2 = np.argsort(p1), np.argsort(p2)
    m = np.c_[inv1, inv2][rows]
    out = f(x[p1], y[p2], m, rng.uniform(size=n), image_size1=SIZE, image_size2=SIZE)
    np.testing.assert_array_equal(out.labels, base.labels[rows])
    np.testing.assert_array_equal(out.homographies, base.homographies)


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_many_to_many_matches(f):
    # Every image-1 keypoint matched to its true image-2 keypoint and to a random one.
    x, y, truth = two_planes(200, 0, seed=6)
    rng = np.random.default_rng(6)
    n = len(x)
    wrong = np.c_[np.arange(n), rng.permutation(n)]
    m = np.vstack([np.c_[np.arange(n), np.arange(n)], wrong])
    out = _call(f, x, y, m)
    assert out.keep[:n].mean() >= 0.97
    assert out.keep[n:][wrong[:, 0] != wrong[:, 1]].mean() <= (0.05 if f is mop_clusters else 0.1)


# --- degenerate inputs -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
@pytest.mark.parametrize("k", [0, 1, 2, 3, 4, 5, 7])
def test_few_matches_reject_everything(f, k):
    rng = np.random.default_rng(k)
    x = rng.uniform(0, 500, (k, 2))
    out = _call(f, x, x + 3.0)
    assert not out.keep.any() and len(out.homographies) == 0


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_collinear_and_coincident_matches_reject_everything(f):
    t = np.linspace(0, 900, 60)
    line = np.c_[t, 0.5 * t + 20]
    assert not _call(f, line, line * 0.9 + 5).keep.any()
    same = np.tile([[300.0, 200.0]], (40, 1))
    assert not _call(f, same, same + 7).keep.any()
    # one location repeated in many rows (many-to-many) is as degenerate
    k1, k2 = np.array([[300.0, 200.0]]), np.array([[310.0, 190.0]])
    out = f(k1, k2, np.zeros((30, 2), int), None, image_size1=SIZE, image_size2=SIZE)
    assert not out.keep.any()


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_duplicated_rows_share_their_decision(f):
    x, y, _ = two_planes(150, 100, seed=8)
    m = np.c_[np.arange(len(x)), np.arange(len(x))]
    out = _call(f, x, y, np.vstack([m, m[:50]]))
    np.testing.assert_array_equal(out.labels[-50:], out.labels[:50])


# --- parameters ------------------------------------------------------------------------------------------------

def test_defaults_are_the_authors():
    assert (MOP_DEFAULTS.strict_threshold, MOP_DEFAULTS.loose_threshold) == (7.0, 15.0)
    assert (MOP_DEFAULTS.max_iterations, MOP_DEFAULTS.min_iterations, MOP_DEFAULTS.confidence) == (2000, 50, 0.9)
    assert (MOP_DEFAULTS.min_plane_size, MOP_DEFAULTS.min_new_inliers) == (12, 6)
    assert (MIHO_DEFAULTS.min_plane_size, MIHO_DEFAULTS.min_new_inliers, MIHO_DEFAULTS.rotations) == (8, 4, 4)
    assert MOP_DEFAULTS.reject_reflections and MIHO_DEFAULTS.reject_reflections


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_unknown_and_bad_parameters(f):
    x = np.random.default_rng(0).uniform(0, 500, (20, 2))
    with pytest.raises(ValueError, match="unknown parameter.*'th_in'.*strict_threshold"):
        _call(f, x, x, th_in=5)
    with pytest.raises(ValueError, match="max_iterations"):
        _call(f, x, x, max_iterations=0)
    with pytest.raises(ValueError, match="confidence"):
        _call(f, x, x, confidence=1.0)
    with pytest.raises(ValueError, match="must not exceed"):
        _call(f, x, x, strict_threshold=20.0)


def test_rotations_belong_to_miho_only():
    x = np.random.default_rng(0).uniform(0, 500, (20, 2))
    with pytest.raises(ValueError, match="unknown parameter.*rotations"):
        _call(mop_clusters, x, x, rotations=4)
    _call(mop_miho_clusters, x, x, rotations=1)


@pytest.mark.parametrize("f", FILTERS, ids=["mop", "mop_miho"])
def test_overrides_take_effect(f):
    x, y, _ = two_planes(150, 100, seed=9)
    assert not _call(f, x, y, min_plane_size=1000).keep.any()  # no plane is that large
    default = _call(f, x, y).keep.sum()
    tight = _call(f, x, y, assign_threshold=0.5, loose_threshold=0.5, strict_threshold=0.5).keep.sum()
    assert 0 < tight < default  # half-pixel thresholds cut into the 0.5 px noise


# --- the primitives --------------------------------------------------------------------------------------------

def test_minimal_fit_agrees_with_the_dlt():
    rng = np.random.default_rng(0)
    src, dst = rng.uniform(0, 1000, (200, 4, 2)), rng.uniform(0, 1000, (200, 4, 2))
    H1, s1 = fit_homographies(src, dst)
    H2, s2 = fit_minimal(src, dst)
    np.testing.assert_allclose(s1, s2, atol=1e-10)
    unit = lambda H: H / np.linalg.norm(H, axis=(1, 2))[:, None, None] * np.sign(H[:, 2:, 2:])  # noqa: E731
    good = s1 > 0.05
    np.testing.assert_allclose(unit(H1)[good], unit(H2)[good], atol=1e-9)


def test_supports_is_the_thresholded_symmetric_error():
    rng = np.random.default_rng(1)
    p = rng.uniform(0, 800, (400, 2))
    q = _apply(H_A, p) + rng.normal(0, 6, (400, 2))
    H = np.stack([H_A, H_B, -H_A])[:, None]  # -H_A: same map, the sign is taken from the sample
    sample = np.array([[0, 1, 2, 3]] * 3)
    got = supports(H, ((p, q),), sample, 10.0**2)
    fwd = np.sum((_apply(H_A, p) - q) ** 2, axis=1)
    bwd = np.sum((_apply(np.linalg.inv(H_A), q) - p) ** 2, axis=1)
    want = np.maximum(fwd, bwd) < 100.0
    np.testing.assert_array_equal(got[0], want)
    np.testing.assert_array_equal(got[2], want)
    assert got[1].sum() < 5


@pytest.mark.parametrize("quarter", [0, 1, 2, 3])
def test_best_rotation_finds_the_quarter_turn(quarter):
    rng = np.random.default_rng(quarter)
    p1 = rng.uniform(0, 800, (300, 2))
    a = -quarter * np.pi / 2  # image 2 is image 1 turned back by the quarter MiHo must undo
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    p2 = p1 @ R.T + rng.normal(0, 1, (300, 2))
    got = best_rotation(p1, p2, 4)
    b = quarter * np.pi / 2
    np.testing.assert_allclose(got[:2, :2], np.round([[np.cos(b), -np.sin(b)], [np.sin(b), np.cos(b)]]))


# --- the stopping rule -----------------------------------------------------------------------------------------

def test_stopping_count_is_the_authors_float32():
    """``log(1 - p) / log(1 - w^4)`` as the authors' float32 ``steps``: -inf once ``1 - w^4`` rounds to 1 in
    float32 (``w`` below about 1.31 %), the float64 count otherwise (the float32 rounding of ``1 - w^4`` aside)."""
    n = 100_000
    assert ransac._iterations_needed(1312, n, 0.9) == -np.inf  # w^4 = 2.963e-8 < 2^-25
    assert ransac._iterations_needed(1320, n, 0.9) == pytest.approx(3.8e7, rel=0.03)  # 1 - 2^-24: the next float
    for count in (5_000, 20_000, 50_000):
        w4 = (count / n) ** 4
        assert ransac._iterations_needed(count, n, 0.9) == pytest.approx(np.log(0.1) / np.log1p(-w4), rel=5e-3)
    assert ransac._iterations_needed(n, n, 0.9) == 0.0
    assert ransac._iterations_needed(3, n, 0.9) == -np.inf


def test_a_search_among_outliers_stops_past_min_iterations(monkeypatch):
    """With the best set below ~1.3 % of the pool the authors' count is -inf: the search ends with the first batch
    past ``min_iterations`` (here batches of 100000 // 3000 = 33 hypotheses: 66), not at ``max_iterations``."""
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 1, (3000, 2)) * SIZE, rng.uniform(0, 1, (3000, 2)) * SIZE
    seen = []
    inner = ransac._hypotheses

    def spy(rng_, views, its, *args):
        seen.append(its.max())
        return inner(rng_, views, its, *args)

    monkeypatch.setattr(ransac, "CHUNK_ELEMENTS", 1)  # one batch per chunk: the hypotheses drawn are those used
    monkeypatch.setattr(ransac, "_hypotheses", spy)
    fit = ransac.fit_plane(ransac.Views(x, y, False), np.zeros((3000, 0), bool), rng, MOP_DEFAULTS)
    assert fit.H is not None and fit.loose.sum() < 30
    assert max(seen) == 65
