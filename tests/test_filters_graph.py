"""Tests of the graph and motion-model filters behind ``FILTERS``: PGM, BM and SCV."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.filters.pgm import _affinity, greedy_assignment, rrwm
from ctxmatch_lib.testing import planted_homography_matches
from filter_cases import SIZE, grid_translation, identity_matches, many_to_many_case, run_filter

NAMES = ["pgm", "bm", "scv"]


def _precision_recall(keep, truth):
    tp = int((keep & truth).sum())
    return tp / max(int(keep.sum()), 1), tp / max(int(truth.sum()), 1)


def test_registry_lists_the_three():
    for name in NAMES:
        assert name in FILTERS
        assert callable(FILTERS[name])


# ----- exact small cases ------------------------------------------------------------------------------


def test_rrwm_and_greedy_exact():
    # Candidates (0,0), (1,1), (0,1), (1,0): the first two are a consistent pair (affinity 1), the last
    # two a weaker one (0.5); every other pair conflicts. RRWM ranks the strong pair first and the
    # one-to-one discretisation takes exactly it.
    m = np.array([[0, 0], [1, 1], [0, 1], [1, 0]])
    W = sp.csr_matrix(np.array([[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0.5], [0, 0, 0.5, 0]]))
    x = rrwm(W, m[:, 0], m[:, 1])
    assert x.sum() == pytest.approx(1.0)
    assert x[0] == pytest.approx(x[1]) and x[2] == pytest.approx(x[3])
    assert x[0] > x[2] > 0
    np.testing.assert_array_equal(greedy_assignment(x, m), [True, True, False, False])
    # No edge at all: nothing to walk on, every score is zero and nothing is assigned.
    assert not rrwm(sp.csr_matrix((4, 4)), m[:, 0], m[:, 1]).any()
    assert not greedy_assignment(np.zeros(4), m).any()


def test_pgm_exact_with_shapes():
    # With affine shapes the affinity is the mutual projection error: zero inside a translated grid, and
    # hundreds of pixels between the grid and the match sent to the corner, which is left without support.
    x, y = grid_translation()
    S = np.tile(np.eye(2) * 3.0, (len(x), 1, 1))
    keep = run_filter("pgm", x, y, identity_matches(len(x)), shapes1=S, shapes2=S)
    assert not keep[0] and keep[1:].all()
    # A rotated image-2 shape on one match breaks its local transformation: on a 60-pixel grid its
    # projections miss its neighbours by 85 pixels, a mutual error of 42 of the 50 allowed, and the
    # little affinity left (0.15 per neighbour) is below the support of two.
    x, y = grid_translation(step=60.0)
    S2 = S.copy()
    S2[10] = 3.0 * np.array([[0.0, -1.0], [1.0, 0.0]])
    keep = run_filter("pgm", x, y, identity_matches(len(x)), shapes1=S, shapes2=S2)
    assert not keep[0] and not keep[10]
    assert keep[1:10].all() and keep[11:].all()


def test_pgm_affinity_is_sparse_knn():
    pm = planted_homography_matches(3000, 0.4, image_size=SIZE, rng=0)
    k = 10
    W = _affinity(pm.kpts1, pm.kpts2, None, pm.matches, k, 50.0, 0.5)
    assert sp.issparse(W) and W.shape == (3000, 3000)
    # At most the union of the k-NN lists of both images, symmetrised.
    assert W.nnz <= 4 * k * 3000
    assert (W != W.T).nnz == 0
    assert W.diagonal().max() == 0


def test_bm_exact_two_motions():
    # Two halves of a grid move in opposite directions (a motion discontinuity): the bilateral domain keeps
    # them apart, so both are kept; a match with the average motion, (0, 0), agrees with neither.
    g = np.stack(np.meshgrid(np.arange(12) * 20.0, np.arange(10) * 20.0), -1).reshape(-1, 2) + 100.0
    left = g[:, 0] < g[:, 0].mean()
    y = g + np.where(left[:, None], [60.0, 0.0], [-60.0, 0.0])
    x = np.vstack([g, [[150.0, 150.0]]])
    y = np.vstack([y, [[150.0, 150.0]]])
    keep = run_filter("bm", x, y, identity_matches(len(x)))
    assert keep[:-1].all() and not keep[-1]


def test_scv_exact():
    x, y = grid_translation()
    keep = run_filter("scv", x, y, identity_matches(len(x)))
    assert not keep[0] and keep[1:].all()
    # Five matches: every region is capped at the 4 others, whose chance level 4 / 4 reaches p1, so the
    # only step is uninformative and nothing is accepted.
    keep = run_filter("scv", x[1:6], y[1:6], identity_matches(5))
    assert not keep.any()


@pytest.mark.parametrize("name", ["bm", "scv"])
def test_translation_grid_exact(name):
    x, y = grid_translation()
    keep = run_filter(name, x, y, identity_matches(len(x)), np.full(len(x), 0.1))
    assert not keep[0]
    assert keep[1:].all()


# ----- planted outliers -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("seed", [0, 1])
def test_planted_homography_precision(name, seed):
    pm = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, informative_scores=True, rng=seed)
    keep = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores)
    precision, recall = _precision_recall(keep, pm.is_inlier)
    print(f"{name}: precision {precision:.3f} recall {recall:.3f} kept {int(keep.sum())}")
    assert precision >= 0.8
    assert recall >= 0.8


@pytest.mark.parametrize("name", NAMES)
def test_planted_without_scores(name):
    pm = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, rng=3)
    keep = run_filter(name, pm.kpts1, pm.kpts2, pm.matches, None)
    precision, recall = _precision_recall(keep, pm.is_inlier)
    assert precision >= 0.8 and recall >= 0.8


@pytest.mark.parametrize("name", NAMES)
def test_identical_images_keep_most(name):
    rng = np.random.default_rng(5)
    kpts = rng.uniform([0, 0], [639, 479], size=(400, 2))
    keep = run_filter(name, kpts, kpts.copy(), identity_matches(400))
    assert keep.mean() > 0.9


# ----- degenerate inputs ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_tiny_inputs(name, k):
    rng = np.random.default_rng(k)
    kpts = rng.uniform(0, 100, size=(k, 2))
    keep = run_filter(name, kpts, kpts + 1.0, identity_matches(k), rng.uniform(size=k))
    if k <= 2:  # a match needs the support of at least two others: with two or fewer, nothing is kept
        assert not keep.any()
    run_filter(name, kpts, kpts + 1.0, identity_matches(k), None)


@pytest.mark.parametrize("name", NAMES)
def test_collinear_keypoints(name):
    # A translated line of keypoints is a consistent (if degenerate) configuration.
    t = np.linspace(0, 500, 60)
    kpts1 = np.c_[t, 0.5 * t + 10]
    kpts2 = kpts1 + (5.0, 2.0)
    keep = run_filter(name, kpts1, kpts2, identity_matches(60), np.linspace(0, 1, 60))
    assert keep.mean() > 0.8


@pytest.mark.parametrize("name", NAMES)
def test_duplicate_keypoints(name):
    # Twenty matches between the same two points: no geometry to contradict them, nothing to crash on.
    kpts = np.tile([[100.0, 100.0]], (20, 1))
    run_filter(name, kpts, kpts, identity_matches(20), None)
    # Duplicated matches inside a consistent grid do not disturb the others.
    x, y = grid_translation()
    m = np.vstack([identity_matches(len(x)), identity_matches(len(x))[5:15]])
    keep = run_filter(name, x, y, m)
    assert keep[1:len(x)].mean() > 0.9 and not keep[0]


@pytest.mark.parametrize("name", NAMES)
def test_many_to_many_input(name):
    keep, truth = many_to_many_case(name)
    precision, recall = _precision_recall(keep, truth)
    assert precision > 0.9 and recall > 0.8


def test_pgm_output_is_one_to_one():
    pm = planted_homography_matches(600, 1.0, noise=0.3, image_size=SIZE, rng=8)
    rng = np.random.default_rng(8)
    matches = np.vstack([pm.matches, np.c_[np.arange(600), rng.permutation(600)]])
    # A fixed point of the permutation repeats a row (same score): the same candidate, kept twice or not at all.
    kept = np.unique(matches[run_filter("pgm", pm.kpts1, pm.kpts2, matches)], axis=0)
    assert len(np.unique(kept[:, 0])) == len(kept) == len(np.unique(kept[:, 1]))


# ----- determinism and arguments ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, params, argname",
    [
        ("pgm", {"k": 0}, "k"),
        ("pgm", {"tau": -1.0}, "tau"),
        ("pgm", {"rho": 0.0}, "rho"),
        ("bm", {"sigma_s": 0.0}, "sigma_s"),
        ("bm", {"n_iter": 1.5}, "n_iter"),
        ("scv", {"growth": (8, 4)}, "growth"),
        ("scv", {"p0": 0.5, "p1": 0.25}, "p0"),
        ("scv", {"alpha": 1.5}, "alpha"),
    ],
)
def test_bad_parameters_name_the_parameter(name, params, argname):
    x, y = grid_translation()
    with pytest.raises(ValueError, match=argname):
        run_filter(name, x, y, identity_matches(len(x)), **params)
