"""Tests for DTM (Sec. 4): hand-built case, planted outliers, invariants, degenerate geometry, boundary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from ctxmatch_lib.dtm import (
    BOUNDARY_METHODS,
    alpha_shape,
    collapse_vertices,
    dtm,
    dtm_boundary,
    matlab_boundary_alpha,
)
from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import apply_homography, planted_homography_matches

SIZE = (640, 480)


def _run(k1, k2, matches=None, scores=None, size=SIZE, **kw):
    k1, k2 = np.asarray(k1, float), np.asarray(k2, float)
    if matches is None:
        matches = np.stack([np.arange(len(k1))] * 2, axis=1)
    return dtm(k1, k2, matches, scores, image_size1=size, image_size2=size, **kw)


# --- hand-built case ---------------------------------------------------------------------------------

def _hexagon_case():
    """Centre c (match 0) and hexagon h0..h5 (matches 1-6, radius 20, h_k at 60k degrees, y down) move
    by t = (10, 5). Outliers: o1 (7) sits inside the hexagon in I1 but far away in I2; o2 (8) far away in
    I1 but inside the hexagon in I2; o3 (9) just right of h0 in I1 and below h2/h3 in I2."""
    ang = np.deg2rad(np.arange(0, 360, 60))
    c = np.array([500.0, 500.0])
    hexa = c + 20 * np.c_[np.cos(ang), np.sin(ang)]
    t = np.array([10.0, 5.0])
    k1 = np.vstack([c, hexa, [[505, 497], [150, 850], [545, 500]]])
    k2 = np.vstack([c + t, hexa + t, [[900, 150], [505, 512], [480, 545]]])
    scores = np.r_[np.arange(7) * 0.1, 0.8, 0.9, 1.0]  # rank = match index
    return k1, k2, scores


def test_hand_built_case_exact():
    """Worked by hand from the steps (image 1000 x 1000, so s = 100 keeps B far from the points).

    Iteration 1, ranks 0..9 by score. Neighbours (other matches in A_v) in I1 / I2:
    c: {h1,h2,h3,h4,o1} / {h0,h1,h3,h4,h5,o2} -> cluster {h1,h3,h4}; discards h0,h2,h5,o1,o2.
    h1 (next alive): {c,h0,h2,o1,o3} / {c,h0,h2,o2,o3} -> cluster {c,h0,h2,o3}.
    h3: {c,h2,h4} / {c,h2,h4,o2,o3} -> cluster {c,h2,h4}; discards o3 from M' (not from clusters).
    h4: {c,h3,h5,o1} / {c,h3,h5} -> cluster {c,h3,h5}. Nothing else is alive: T = (c, h1, h3, h4).
    M^1 = union of clusters = all inliers + o3; o1 and o2 are removed at iteration 1.
    Iteration 2 changes nothing (every hexagon match supports its fan neighbours, o3 stays in h1's
    cluster), so ī = 2. DTM2 level 1: o1's I1 keypoint lies in the fan triangle (c, h4, h5) whose partners
    in I2 are far from (900, 150); o2's I1 keypoint lies in a boundary triangle and the translations of
    the base matches map its I2 keypoint near the hexagon, not there: neither is re-added.
    """
    k1, k2, scores = _hexagon_case()
    res = _run(k1, k2, scores=scores, size=(1000, 1000), trace=True)
    np.testing.assert_array_equal(res.keep, [1, 1, 1, 1, 1, 1, 1, 0, 0, 1])
    np.testing.assert_array_equal(res.removed_at, [0, 0, 0, 0, 0, 0, 0, 1, 1, 0])
    np.testing.assert_array_equal(res.readded_at, np.zeros(10))
    it1 = res.trace.iterations[0]
    np.testing.assert_array_equal(it1.rank, np.arange(10))
    np.testing.assert_array_equal(it1.contraction, [0, 2, 4, 5])
    clusters = [set(it1.cluster_members[a:b].tolist()) for a, b in zip(it1.cluster_ptr[:-1], it1.cluster_ptr[1:])]
    assert clusters == [{2, 4, 5}, {0, 1, 3, 9}, {0, 3, 5}, {0, 4, 6}]
    assert len(res.trace.iterations) == 2
    lv = res.trace.levels[0]
    assert lv.level == 1 and lv.candidates.tolist() == [7, 8] and lv.added.tolist() == []


# --- planted outliers --------------------------------------------------------------------------------

def _pr(keep, is_inlier):
    return is_inlier[keep].mean(), keep[is_inlier].mean()


def test_planted_outliers_precision_recall():
    rows = []
    for seed in range(5):
        p = planted_homography_matches(1500, 0.4, noise=0.5, image_size=SIZE, rng=seed)
        res = _run(p.kpts1, p.kpts2, p.matches, p.scores)
        p1, r1 = _pr(res.removed_at == 0, p.is_inlier)
        p2, r2 = _pr(res.keep, p.is_inlier)
        assert r2 >= r1, f"seed {seed}: DTM2 recall {r2:.3f} < DTM1 recall {r1:.3f}"
        rows.append((p1, r1, p2, r2))
    p1, r1, p2, r2 = np.mean(rows, axis=0)
    assert p2 >= 0.97, f"mean precision {p2:.3f}"
    assert r2 >= 0.90, f"mean recall {r2:.3f}"


def test_two_independent_motions_survive():
    rng = np.random.default_rng(1)
    w, h = SIZE
    H_left = np.array([[1.0, 0.05, 20.0], [-0.05, 1.0, 10.0], [0.0, 0.0, 1.0]])
    H_right = np.array([[0.9, -0.1, -40.0], [0.1, 0.9, 60.0], [0.0, 0.0, 1.0]])
    left = rng.uniform([10, 10], [w / 2 - 10, h - 10], (400, 2))
    right = rng.uniform([w / 2 + 10, 10], [w - 10, h - 70], (400, 2))  # H_right moves y down by up to 60
    out1, out2 = rng.uniform([0, 0], [w - 1, h - 1], (2, 600, 2))
    k1 = np.vstack([left, right, out1])
    k2 = np.vstack([apply_homography(H_left, left), apply_homography(H_right, right), out2])
    k2[:800] += rng.normal(scale=0.5, size=(800, 2))
    k2 = np.clip(k2, 0, [w - 1, h - 1])  # the few inliers moved off the image stay on its edge
    keep = _run(k1, k2, scores=rng.uniform(size=1400)).keep
    assert keep[:400].mean() > 0.7 and keep[400:800].mean() > 0.7
    assert keep[800:].mean() < 0.05


# --- invariants --------------------------------------------------------------------------------------

@pytest.mark.parametrize("with_scores", [True, False])
def test_independent_of_match_order(with_scores):
    p = planted_homography_matches(400, 0.5, rng=3)
    scores = p.scores if with_scores else None
    ref = _run(p.kpts1, p.kpts2, p.matches, scores)
    perm = np.random.default_rng(0).permutation(len(p.matches))
    res = _run(p.kpts1, p.kpts2, p.matches[perm], None if scores is None else scores[perm])
    np.testing.assert_array_equal(res.keep, ref.keep[perm])
    np.testing.assert_array_equal(res.removed_at, ref.removed_at[perm])
    np.testing.assert_array_equal(res.readded_at, ref.readded_at[perm])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(0, 60), stages=st.sampled_from([1, 2]))
def test_result_invariants(seed, n, stages):
    rng = np.random.default_rng(seed)
    k1 = np.round(rng.uniform(0, 99, (n, 2)) * 2) / 2  # many collapsed and collinear points
    k2 = np.clip(k1 + rng.normal(scale=5, size=(n, 2)), 0, 99)
    res = _run(k1, k2, scores=rng.integers(0, 3, n).astype(float), size=(100, 100), stages=stages)
    assert res.keep.shape == res.removed_at.shape == res.readded_at.shape == (n,)
    assert res.keep.dtype == bool
    readded = res.readded_at > 0
    np.testing.assert_array_equal(res.removed_at[readded], res.readded_at[readded])  # level i re-adds iteration i
    np.testing.assert_array_equal(res.keep, (res.removed_at == 0) | readded)
    if stages == 1:
        assert not readded.any()


def test_trace_is_consistent():
    p = planted_homography_matches(300, 0.5, rng=5)
    res = _run(p.kpts1, p.kpts2, p.matches, p.scores, trace=True)
    tr = res.trace
    prev = np.arange(300)
    for it in tr.iterations:
        np.testing.assert_array_equal(it.active, prev)
        assert set(it.contraction) <= set(it.active)
        np.testing.assert_array_equal(np.unique(it.cluster_members), it.kept)
        assert it.tri1.n_vertices == len(np.unique(it.vertex1)) and len(it.boundary1.points) > 0
        np.testing.assert_array_equal(it.tri1.boundary_points, it.boundary1.points)
        np.testing.assert_array_equal(np.flatnonzero(res.removed_at == it.iteration), it.removed)
        prev = it.kept
    assert len(tr.iterations[-1].removed) == 0
    for lv in tr.levels:
        np.testing.assert_array_equal(np.flatnonzero(res.readded_at == lv.level), lv.added)
        np.testing.assert_array_equal(np.flatnonzero(res.removed_at == lv.level), lv.candidates)


@pytest.mark.parametrize("boundary", BOUNDARY_METHODS)
def test_boundary_methods_run_and_filter(boundary):
    p = planted_homography_matches(600, 0.5, rng=2)
    keep = _run(p.kpts1, p.kpts2, p.matches, p.scores, boundary=boundary).keep
    precision, recall = _pr(keep, p.is_inlier)
    assert precision > 0.9 and recall > 0.6


def test_registry_adapter():
    p = planted_homography_matches(300, 0.5, rng=0)
    kw = dict(image_size1=SIZE, image_size2=SIZE)
    keep = FILTERS["dtm"](p.kpts1, p.kpts2, p.matches, p.scores, shapes1=None, shapes2=None, **kw)
    np.testing.assert_array_equal(keep, dtm(p.kpts1, p.kpts2, p.matches, p.scores, **kw).keep)
    keep1 = FILTERS["dtm"](p.kpts1, p.kpts2, p.matches, p.scores, stages=1, **kw)
    assert keep1.sum() <= keep.sum()


# --- degenerate inputs -------------------------------------------------------------------------------

def test_empty():
    res = _run(np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.int64), trace=True)
    assert res.keep.shape == (0,) and res.keep.dtype == bool and res.removed_at.shape == (0,)


@pytest.mark.parametrize(
    "k1, k2, expected",
    [
        ([[10, 10]], [[20, 20]], [False]),  # nothing supports a lone match
        ([[10, 10], [50, 60]], [[20, 20], [70, 90]], [True, True]),
        ([[10, 10], [50, 60], [90, 10]], [[20, 20], [70, 90], [100, 30]], [True] * 3),
        # matches collapsed onto one vertex pair do not support each other (as in the author's port)
        ([[10, 10], [10.2, 10.1], [9.9, 10.3]], [[20, 20], [20.1, 19.8], [20, 20]], [False] * 3),
        (np.c_[np.linspace(0, 600, 10), np.linspace(0, 300, 10)],
         np.c_[np.linspace(5, 605, 10), np.linspace(3, 303, 10)], [True] * 10),  # collinear
    ],
    ids=["one", "two", "three", "one-vertex", "collinear"],
)
def test_degenerate_geometry(k1, k2, expected):
    for stages in (1, 2):
        res = _run(k1, k2, stages=stages, trace=True)
        np.testing.assert_array_equal(res.keep, expected)


def test_duplicates_and_many_to_many():
    k1 = np.array([[100, 50], [600, 400], [300, 200], [320, 260], [300, 200], [310, 240]], float)
    k2 = np.array([[110, 60], [610, 420], [300, 210], [330, 250], [305, 215]], float)
    matches = np.array([[0, 0], [1, 1], [2, 2], [3, 3], [4, 2], [2, 4], [5, 4], [2, 2]])
    res = _run(k1, k2, matches)
    assert res.keep.shape == (8,)
    assert res.keep[2] == res.keep[7]  # duplicate rows share their fate


@pytest.mark.parametrize("which", ["kpts1", "kpts2"])
def test_keypoints_outside_the_image_are_an_error(which):
    k = np.array([[10.0, 10.0], [300.0, 200.0], [600.0, 470.0]])
    m = np.stack([np.arange(3)] * 2, axis=1)
    with pytest.raises(ValueError, match=rf"{which} has keypoints outside.*\(width, height\)"):
        dtm(k, k, m, image_size1=(480, 640) if which == "kpts1" else SIZE,
            image_size2=(480, 640) if which == "kpts2" else SIZE)
    # half a pixel of slack: pixel centres span [0, w - 1], the pixels themselves [-0.5, w - 0.5]
    edge = np.array([[-0.5, -0.5], [639.5, 479.5], [300.0, 200.0]])
    assert dtm(edge, edge, m, image_size1=SIZE, image_size2=SIZE).keep.shape == (3,)


def test_bad_arguments_name_themselves():
    k = np.zeros((3, 2))
    m = np.zeros((3, 2), np.int64)
    with pytest.raises(ValueError, match="kpts1"):
        dtm(np.zeros((3, 3, 1)), k, m, image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="matches"):
        dtm(k, k, [[0, 5]], image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="scores"):
        dtm(k, k, m, [1.0], image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="image_size2"):
        dtm(k, k, m, image_size1=SIZE, image_size2=(0, 4))
    with pytest.raises(ValueError, match="boundary"):
        dtm(k, k, m, image_size1=SIZE, image_size2=SIZE, boundary="hull")
    with pytest.raises(ValueError, match="stages"):
        dtm(k, k, m, image_size1=SIZE, image_size2=SIZE, stages=3)
    for bad in (-1.0, np.inf, "1"):
        with pytest.raises(ValueError, match="whole_set_tol"):
            dtm(k, k, m, image_size1=SIZE, image_size2=SIZE, whole_set_tol=bad)


# --- boundary ----------------------------------------------------------------------------------------

def _grid(n=11, step=20.0, origin=100.0):
    g = origin + step * np.arange(n)
    return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)


def test_alpha_boundary_of_grid_is_outer_square():
    xy = _grid()
    b = dtm_boundary(xy, SIZE)
    on_edge = xy[np.unique(b.shape_edges)]
    assert len(b.shape_edges) == 40
    assert np.all((on_edge == 100).any(axis=1) | (on_edge == 300).any(axis=1))
    assert len(on_edge) == 40  # every outer grid point, no inner one


@pytest.mark.parametrize("method", ["alpha", "convex"])
@pytest.mark.parametrize("seed", [0, 1])
def test_boundary_points_keep_clear_of_vertices(method, seed):
    rng = np.random.default_rng(seed)
    pts = [_grid(), collapse_vertices(rng.uniform([0, 0], SIZE, (800, 2)))[0],
           collapse_vertices(rng.normal([320, 240], [80, 30], (300, 2)))[0]]
    for xy in pts:
        b = dtm_boundary(xy, SIZE, method)
        d, _ = cKDTree(xy).query(b.points)
        assert d.min() >= 0.9 * b.s
        assert len(b.points) >= 3


@pytest.mark.parametrize("xy", [np.empty((0, 2)), [[5.0, 5.0]], [[0, 0], [10, 10]], [[0, 0], [10, 10], [20, 20]]])
def test_boundary_degenerate_vertex_sets(xy):
    xy = np.asarray(xy, float).reshape(-1, 2)
    b = dtm_boundary(xy, (100, 100))
    if len(xy):
        assert len(b.points) >= 3 and cKDTree(xy).query(b.points)[0].min() >= 0.9 * b.s
    else:
        assert b.points.shape == (0, 2)


def test_canvas_and_corners():
    c = dtm_boundary(np.zeros((0, 2)), (640, 480), "corners").points
    np.testing.assert_array_equal(c, [[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]])
    b = dtm_boundary(np.zeros((0, 2)), (640, 480), "canvas")
    seg = np.diff(np.vstack([b.points, b.points[:1]]), axis=0)
    assert np.hypot(*seg.T).max() <= b.s + 1e-9


def test_matlab_alpha_extremes():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (200, 2))
    hull = alpha_shape(xy, 0.0)
    assert hull.alpha == hull.radii.max() and hull.inside.all()
    tight = alpha_shape(xy, 1.0)
    mid = alpha_shape(xy, 0.5)
    assert tight.alpha <= mid.alpha <= hull.alpha
    # The tightest single region still encloses every point.
    assert np.isin(np.arange(200), tight.simplices[tight.inside]).all()
    a = matlab_boundary_alpha(tight.radii, tight.simplices, np.full_like(tight.simplices, -1), 200, 1.0)
    assert a >= tight.alpha  # without adjacency no single region exists below the hull alpha


# --- triangulation kernel ----------------------------------------------------------------------------

def _edge_set(simplices):
    e = np.sort(np.concatenate([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [2, 0]]]), axis=1)
    return set(map(tuple, e.tolist()))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fast_delaunay_kernel_matches_qhull(seed):
    """The Subdiv2D path is a Delaunay triangulation of the same points as Qhull's: same triangle count,
    every triangle has an empty circumcircle, and the edge sets differ only across cocircular ties."""
    from scipy.spatial import Delaunay

    from ctxmatch_lib.dtm.triangulation import _subdiv2d_simplices, delaunay_or_none

    rng = np.random.default_rng(seed)
    v = collapse_vertices(rng.uniform([0, 0], SIZE, (1500, 2)))[0]
    b = dtm_boundary(v, SIZE).points
    for pts in (v, np.vstack([v, b])):
        fast = _subdiv2d_simplices(pts)
        ref = Delaunay(pts).simplices
        assert fast is not None and len(fast) == len(ref)
        assert np.array_equal(np.unique(fast), np.arange(len(pts)))
        a, bb, c = (pts[fast[:, k]] for k in range(3))
        d = 2 * (a[:, 0] * (bb[:, 1] - c[:, 1]) + bb[:, 0] * (c[:, 1] - a[:, 1]) + c[:, 0] * (a[:, 1] - bb[:, 1]))
        sq = [(x ** 2).sum(1) for x in (a, bb, c)]
        ux = (sq[0] * (bb[:, 1] - c[:, 1]) + sq[1] * (c[:, 1] - a[:, 1]) + sq[2] * (a[:, 1] - bb[:, 1])) / d
        uy = (sq[0] * (c[:, 0] - bb[:, 0]) + sq[1] * (a[:, 0] - c[:, 0]) + sq[2] * (bb[:, 0] - a[:, 0])) / d
        r = np.hypot(a[:, 0] - ux, a[:, 1] - uy)
        nearest = cKDTree(pts).query(np.c_[ux, uy])[0]
        assert np.all(nearest >= r * (1 - 1e-9))  # empty circumcircles
        diff = _edge_set(fast) ^ _edge_set(ref)
        assert len(diff) <= 0.01 * len(_edge_set(ref))  # cocircular ties only
        mesh = delaunay_or_none(pts)
        np.testing.assert_array_equal(mesh.simplices, fast)
        nb = mesh.neighbors
        t = np.flatnonzero((nb >= 0).all(axis=1))[0]
        for k in range(3):  # the neighbour across edge k shares the two other vertices
            assert len(set(fast[t]) & set(fast[nb[t, k]])) == 2 and fast[t, k] not in fast[nb[t, k]]


@pytest.mark.parametrize("pts", [[[0, 0], [1, 1]], [[0, 0], [10, 10], [20, 20]], [[0, 0], [10, 0], [0, 10]],
                                 [[0.1, 0.0], [10, 0], [0, 10], [0.1, 0.0]]],
                         ids=["two", "collinear", "triangle", "duplicate-non-float32"])
def test_delaunay_kernel_degenerate(pts):
    from ctxmatch_lib.dtm.triangulation import delaunay_or_none, delaunay_simplices

    pts = np.asarray(pts, float)
    s = delaunay_simplices(pts)
    expected = {2: 0, 3: 0 if np.linalg.matrix_rank(pts[1:] - pts[0]) < 2 else 1, 4: 1}[len(pts)]
    assert s.shape == (expected, 3)
    assert (delaunay_or_none(pts) is None) == (expected == 0)


def test_find_simplex_locates_every_point():
    """The walk returns a triangle holding the query, and -1 only when no triangle holds it."""
    from ctxmatch_lib.dtm.triangulation import points_in_triangles, triangulate

    rng = np.random.default_rng(4)
    v = collapse_vertices(rng.uniform([100, 100], [500, 400], (800, 2)))[0]
    tri = triangulate(v, dtm_boundary(v, SIZE).points)
    q = np.vstack([rng.uniform(-60, 700, (2000, 2)), v[:50], np.round(rng.uniform(0, 640, (300, 2)))])
    f = tri.find_simplex(q)
    p, s = tri.points, tri.simplices
    ok = f >= 0
    assert points_in_triangles(q[ok], p[s[f[ok], 0]], p[s[f[ok], 1]], p[s[f[ok], 2]]).all()
    for i in np.flatnonzero(~ok):
        hit = points_in_triangles(np.repeat(q[i : i + 1], len(s), 0), p[s[:, 0]], p[s[:, 1]], p[s[:, 2]])
        assert not hit.any()


@pytest.mark.parametrize("seed", range(9))
def test_matlab_alpha_matches_definition(seed):
    """The alpha radius equals the one computed literally from its definition: count the regions (edge-
    connected sets of triangles with circumradius <= a) at every spectrum value a, take the first value at
    or above the one enclosing every point that gives a single region, then MATLAB's index into the rest.
    Clusters make the first enclosing shape split into several regions, so the union-find walk of the
    kernel has regions to merge."""
    import math

    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from ctxmatch_lib.dtm.triangulation import DelaunayMesh

    rng = np.random.default_rng(seed)
    # clusters make the first enclosing shape split into several regions, uniform points usually not
    xy = np.vstack([rng.normal(c, 4.0, (25, 2)) for c in rng.uniform(0, 100, (1 + seed % 3, 2))])
    for shrink in (0.0, 0.5, 1.0):
        shape = alpha_shape(xy, shrink)
        r, s = shape.radii, shape.simplices
        spectrum = np.unique(r)
        nb = DelaunayMesh(xy, s).neighbors
        covered = [min(r[np.any(s == p, axis=1)]) for p in np.unique(s)]
        start = int(np.searchsorted(spectrum, max(covered)))
        critical = len(spectrum) - 1
        for c in range(start, len(spectrum)):
            on = r <= spectrum[c]
            t = np.repeat(np.arange(len(s)), 3)
            u = nb.reshape(-1)
            e = (u >= 0) & on[t] & on[np.maximum(u, 0)]
            g = coo_matrix((np.ones(e.sum()), (t[e], u[e])), shape=(len(s), len(s)))
            _, lab = connected_components(g, directed=False)
            if len(np.unique(lab[on])) == 1:
                critical = c
                break
        n = len(spectrum) - critical
        expected = spectrum[critical + max(math.ceil((1 - shrink) * n), 1) - 1]
        assert shape.alpha == expected


def test_incremental_delaunay_insertion_equals_from_scratch():
    """Inserting B into the triangulation of V gives the triangles of V ∪ B triangulated in one go; points
    it cannot take (duplicates, outside its rectangle, not float32) fall back to Qhull with the same result
    up to cocircular ties."""
    from scipy.spatial import ConvexHull

    from ctxmatch_lib.dtm.triangulation import IncrementalDelaunay, delaunay_simplices

    rng = np.random.default_rng(7)
    v = collapse_vertices(rng.uniform([0, 0], SIZE, (600, 2)))[0]
    b = dtm_boundary(v, SIZE).points
    inc = IncrementalDelaunay(v, pad=100.0)
    first = inc.simplices()
    np.testing.assert_array_equal(first, delaunay_simplices(v))
    inc.add(b)
    np.testing.assert_array_equal(inc.points, np.vstack([v, b]))
    np.testing.assert_array_equal(inc.simplices(), delaunay_simplices(np.vstack([v, b])))
    for extra, n_new in (([[1e5, 1e5]], 1), ([[100.1, 200.3]], 1), (v[:1], 0)):  # far, not float32, duplicate
        inc2 = IncrementalDelaunay(v, pad=100.0)
        inc2.add(np.asarray(extra, float))
        s = inc2.simplices()
        pts = inc2.points
        assert len(np.unique(s)) == len(v) + n_new
        a, bb, c = (pts[s[:, k]] for k in range(3))
        area = np.abs((bb[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (bb[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        np.testing.assert_allclose(area.sum() / 2, ConvexHull(pts).volume, rtol=1e-9)
        assert inc2._sub is None or n_new == 0  # the fallback ran


def test_subdiv2d_collinear_points_give_no_triangles_unless_duplicated():
    """Collinear points have no triangles; with a duplicate among them the Subdiv2D path declines (Qhull)."""
    from ctxmatch_lib.dtm.triangulation import _subdiv2d_simplices

    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]])
    assert _subdiv2d_simplices(line).shape == (0, 3)
    assert _subdiv2d_simplices(np.vstack([line, line[1:2]])) is None


def test_subdiv2d_duplicates_fall_back_to_qhull():
    from ctxmatch_lib.dtm.triangulation import _subdiv2d_simplices, delaunay_simplices

    pts = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [10.0, 0.0]])
    assert _subdiv2d_simplices(pts) is None
    assert len(delaunay_simplices(pts)) == 2


def test_circumradii_match_the_circumcircle():
    """Circumradii equal the distance from each triangle's circumcentre (solved directly) to its vertices;
    a degenerate triangle gets inf."""
    from ctxmatch_lib.dtm.boundary import _circumradii

    rng = np.random.default_rng(0)
    pts = np.vstack([np.round(rng.random((60, 2)) * 500), [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]])
    tri = np.vstack([rng.choice(60, size=(40, 3), replace=True), [[60, 61, 62], [3, 3, 4]]])
    r = _circumradii(pts, tri)
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    ok = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])) > 0
    assert np.isinf(r[~ok]).all() and (~ok[-2:]).all()
    for k in np.flatnonzero(ok):
        m = 2 * np.array([b[k] - a[k], c[k] - a[k]])
        centre = np.linalg.solve(m, [b[k] @ b[k] - a[k] @ a[k], c[k] @ c[k] - a[k] @ a[k]])
        np.testing.assert_allclose(r[k], np.linalg.norm(pts[tri[k]] - centre, axis=1), rtol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unique_rows_and_sort_helpers_match_numpy(seed):
    """unique_rows equals np.unique on integer, quarter-pixel, -0.0, float32 and non-float32 rows; the int16 radix
    argsort equals the stable argsort; the int32 path of unique_ints equals np.unique."""
    from ctxmatch_lib.dtm.triangulation import stable_argsort_small, unique_ints, unique_rows

    rng = np.random.default_rng(seed)
    ints = rng.integers(-50, 50, (400, 2)).astype(np.float64)
    halves = rng.integers(-200, 200, (400, 2)) / 4.0
    with_nz = ints.copy()
    with_nz[:3] = -0.0
    f32 = (rng.standard_normal((300, 2)) * 100).astype(np.float32).astype(np.float64)  # boundary-like points
    f32 = np.vstack([f32, f32[:50], [[-0.0, 1.5], [0.0, 1.5], [-1e-30, 0.0]]])
    f32 = f32.astype(np.float32).astype(np.float64)  # -1e-30: a tiny negative float32 next to -0.0 and 0.0
    for pts in (ints, halves, np.vstack([ints, halves]), with_nz, f32, ints + 0.1, ints[:1]):
        u, inv = unique_rows(pts)
        ref_u, ref_inv = np.unique(pts, axis=0, return_inverse=True)
        np.testing.assert_array_equal(u, ref_u)
        np.testing.assert_array_equal(inv, ref_inv.reshape(-1))
    keys = rng.integers(0, 300, 5000)
    np.testing.assert_array_equal(stable_argsort_small(keys, 300), np.argsort(keys, kind="stable"))
    big = rng.integers(0, 2**40, 1000)
    for x in (keys, big, keys[:10]):
        np.testing.assert_array_equal(unique_ints(x), np.unique(x))


# --- the rules taken from the author's port where the paper is silent --------------------------------

def test_matches_on_one_vertex_do_not_support_each_other():
    """Rule 1 (``A_v`` without ``v``): two matches whose image-1 keypoints collapse onto one vertex are not
    neighbours in image 1, but their image-2 vertices are adjacent, so each lies in the other's symmetric
    difference: the first pick discards the second and its own cluster (the intersection) is empty. Both are
    removed; counting co-collapsed matches as neighbours would have kept both."""
    k1 = np.array([[100.0, 100.0], [100.2, 99.9]])
    k2 = np.array([[120.0, 110.0], [160.0, 170.0]])
    res = _run(k1, k2, scores=np.array([0.1, 0.2]), trace=True)
    it = res.trace.iterations[0]
    np.testing.assert_array_equal(it.contraction, [0])
    assert len(it.cluster_members) == 0
    np.testing.assert_array_equal(res.keep, [False, False])


def test_dtm2_boundary_triangles_use_the_neighbours_of_the_nearest_vertex():
    """Rule 2 (DTM2 near the boundary): base matches v0 (moving by (100, 0)), v1 and v2 (not moving);
    boundary square far away. Both candidates sit left of v0, in a triangle W with boundary vertices whose
    nearest keypoint vertex is v0. The translations tried are those of v0's neighbours v1 and v2 (zero), not
    v0's own: the candidate that moves like v0 lands right of v0, outside W, and fails; the one that does not
    move stays in W and passes."""
    from ctxmatch_lib.dtm.core import _transfer_test
    from ctxmatch_lib.dtm.triangulation import triangulate

    src = np.array([[300.0, 300.0], [340.0, 260.0], [340.0, 340.0]])
    dst = src + [[100.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
    square = np.array([[100.0, 100.0], [500.0, 100.0], [500.0, 500.0], [100.0, 500.0]])
    tri = triangulate(src, square)
    q_src = np.array([[250.0, 301.0], [250.0, 301.0]])
    q_dst = q_src + [[100.0, 0.0], [0.0, 0.0]]
    w = tri.simplices[tri.find_simplex(q_src[:1])[0]]
    assert 1 <= (w < 3).sum() <= 2 and 0 in w  # W touches the boundary, v0 is its nearest keypoint vertex
    ok = _transfer_test(tri, q_src, q_dst, src, dst, np.arange(3))
    np.testing.assert_array_equal(ok, [False, True])


@pytest.mark.parametrize("k", [4, 5, 8, 12, 30])
def test_small_sets_in_agreement_are_kept_with_the_keypoint_boundary(k):
    """Sets related by one similarity (identical keypoints, or rotated and scaled about the centre) are kept
    whole with the port's adaptive frame boundary by DTM alone (the whole-set rule off); see the alpha-shape
    limit in :func:`dtm`'s Notes."""
    rng = np.random.default_rng(k)
    for trial in range(4):
        p = rng.uniform([128, 96], [512, 384], (k, 2))
        a, s = rng.uniform(-0.3, 0.3), rng.uniform(0.85, 1.15)
        rot = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        q = p if trial == 0 else (p - [320, 240]) @ rot.T + [320, 240]
        assert _run(p, q, boundary="keypoints", whole_set_tol=None).keep.all()


# --- small sets: the whole-set rule ------------------------------------------------------------------

def test_issue_case_five_identical_matches_are_kept():
    """DTM alone keeps 3 of these 5 identical matches (the alpha boundary falls
    between vertices further apart than about 2 s); one homography (the identity) explains all 5."""
    k = np.random.default_rng(0).random((5, 2)) * 400 + 50
    m = np.c_[np.arange(5), np.arange(5)]
    alone = dtm(k, k, m, None, image_size1=(500, 500), image_size2=(500, 500), whole_set_tol=None)
    res = dtm(k, k, m, None, image_size1=(500, 500), image_size2=(500, 500))
    assert alone.keep.sum() == 3 and not alone.whole_set
    assert res.keep.all() and res.whole_set
    np.testing.assert_array_equal(res.removed_at, alone.removed_at)  # DTM's own record is untouched


def _related(k, kind, rng):
    """``k`` matches in the middle of a 640 x 480 image, related by one motion (redrawn until both stay on
    the image)."""
    while True:
        p = rng.uniform([128, 96], [512, 384], (k, 2))
        if kind == "identity":
            return p, p.copy()
        a, s = rng.uniform(-0.5, 0.5), rng.uniform(0.7, 1.3)
        h = np.eye(3)
        h[:2, :2] = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        h[:2, 2] = [320, 240] - h[:2, :2] @ [320, 240]
        if kind == "homography":
            h[2, :2] = rng.uniform(-3e-4, 3e-4, 2)
        q = apply_homography(h, p)
        if (q >= 0).all() and (q < [639, 479]).all():
            return p, q


@pytest.mark.parametrize("boundary", ["alpha", "keypoints"])
@pytest.mark.parametrize("kind", ["identity", "similarity", "homography"])
@pytest.mark.parametrize("k", [4, 5, 8, 12, 30])
def test_small_sets_in_agreement_are_kept(k, kind, boundary):
    """Any K >= 4 matches related by one similarity or homography are all kept, with either boundary."""
    rng = np.random.default_rng(k)
    for _ in range(4):
        p, q = _related(k, kind, rng)
        assert _run(p, q, boundary=boundary).keep.all()


@pytest.mark.parametrize("k", [5, 8, 30])
def test_whole_set_rule_sees_one_outlier(k):
    """K - 1 matches related by a similarity plus one random match: no homography explains them all, so
    the rule stays out and DTM alone decides."""
    from ctxmatch_lib.dtm.core import _one_homography

    rng = np.random.default_rng(k)
    for _ in range(4):
        p, q = _related(k, "similarity", rng)
        assert _one_homography(p, q, 1.0)
        q[-1] = rng.uniform([0, 0], [639, 479])
        assert not _one_homography(p, q, 1.0)
        res = _run(p, q)
        np.testing.assert_array_equal(res.keep, _run(p, q, whole_set_tol=None).keep)
        assert not res.whole_set


def test_whole_set_rule_needs_a_unique_proper_homography():
    """Collapsed, collinear or mirrored sets: the rule stays out. Four matches on one vertex pair are related
    by a translation, but DTM sees one vertex per image (it removes them: nothing outside the vertex supports
    them); three of four on a line leave no unique homography; a mirror is no view of a plane."""
    from ctxmatch_lib.dtm.core import _one_homography

    rng = np.random.default_rng(1)
    one = np.array([[100.0, 100.0], [100.3, 99.8], [99.7, 100.1], [100.1, 100.4]])  # no three collinear
    res = _run(one, one + 20)
    assert not res.whole_set and not res.keep.any()
    assert _one_homography(one, one + 20, 1.0)  # the homography alone would keep them
    line = np.array([[100.0, 100.0], [200.0, 150.0], [300.0, 200.0], [250.0, 400.0]])
    assert not _one_homography(line, line + 20, 1.0)  # three collinear of four: no unique homography
    p = rng.uniform([128, 96], [512, 384], (8, 2))
    mirrored = p * [-1, 1] + [640, 0]  # an exact affine map, but it mirrors
    assert not _one_homography(p, mirrored, 1.0)
    res = _run(p, mirrored)
    assert not res.keep.all() and not res.whole_set


def test_whole_set_tolerance_is_in_pixels():
    """One of 8 identical matches moved by 0.5 px: the least-squares homography leaves under 0.5 px
    everywhere, so a 1 px tolerance keeps the set whole and a 0.01 px one does not."""
    from ctxmatch_lib.dtm.core import _one_homography

    p = np.random.default_rng(2).uniform([128, 96], [512, 384], (8, 2))
    q = p.copy()
    q[3, 0] += 0.5
    assert _one_homography(p, q, 1.0)
    assert not _one_homography(p, q, 0.01)
    assert _one_homography(p, p, 0.0 + 1e-6)


def test_whole_set_rule_with_a_shared_keypoint():
    """Many-to-many: a keypoint matched twice. Partners within ``2 tol`` of each other leave the rule
    possible (here it fires); partners further apart rule it out before any fit, as the triangle inequality
    says, and DTM alone decides."""
    from ctxmatch_lib.dtm.core import _shared_keypoint_spread

    k = np.random.default_rng(0).random((5, 2)) * 400 + 50
    m = np.c_[np.r_[np.arange(5), 0], np.arange(6)]
    size = dict(image_size1=(500, 500), image_size2=(500, 500))
    near = np.vstack([k, k[0] + [0.3, 0.0]])
    res = dtm(k, near, m, None, **size)
    assert res.whole_set and res.keep.all()
    far = np.vstack([k, k[0] + [30.0, 0.0]])
    res = dtm(k, far, m, None, **size)
    np.testing.assert_array_equal(res.keep, dtm(k, far, m, None, whole_set_tol=None, **size).keep)
    assert not res.whole_set and not res.keep.all()
    canon = np.array([0, 2, 3, 4, 5, 1])  # matches sharing image-1 keypoint 0 are consecutive
    p1, p2 = k[m[:, 0]], far[m[:, 1]]
    assert _shared_keypoint_spread(p1, p2, canon, 1.0) and not _shared_keypoint_spread(p1, p2, canon, 15.0)
    assert not _shared_keypoint_spread(p1, near[m[:, 1]], canon, 1.0)


@pytest.mark.parametrize("grid", [False, True])
def test_triangle_neighbors_match_qhull(grid):
    """The compiled triangle adjacency equals Qhull's ``neighbors`` (the triangle across the edge opposite
    each vertex, -1 on the hull), on random points and on a grid full of cocircular ties."""
    from scipy.spatial import Delaunay

    from ctxmatch_lib.dtm._kernels import triangle_neighbors_kernel

    rng = np.random.default_rng(3)
    xy = (np.stack(np.meshgrid(np.arange(15.0), np.arange(11.0)), -1).reshape(-1, 2) if grid
          else rng.random((400, 2)) * 100)
    tri = Delaunay(xy)
    np.testing.assert_array_equal(triangle_neighbors_kernel(tri.simplices.astype(np.int64), len(xy)), tri.neighbors)


def test_point_location_walk_hands_long_walks_to_the_exhaustive_test():
    """With a step budget of one triangle, the walk resolves exactly the queries inside their start
    triangle and flags the others as still walking; the exhaustive test then finds them all."""
    from ctxmatch_lib.dtm._kernels import locate_kernel
    from ctxmatch_lib.dtm.triangulation import points_in_triangles, triangulate

    rng = np.random.default_rng(4)
    tri = triangulate(np.round(rng.random((200, 2)) * 400), np.array([[-50.0, -50], [450, -50], [450, 450], [-50, 450]]))
    q = rng.random((300, 2)) * 400
    p, s = tri.points, tri.simplices.astype(np.int64)
    nearest = np.argmin(((q[:, None] - p[None]) ** 2).sum(-1), axis=1)
    out, unresolved = locate_kernel(p, s, tri.delaunay.neighbors, q, nearest, 1)
    start = np.array([np.flatnonzero((s == v).any(axis=1))[0] for v in nearest])
    in_start = points_in_triangles(q, p[s[start, 0]], p[s[start, 1]], p[s[start, 2]])
    np.testing.assert_array_equal(out >= 0, in_start)
    np.testing.assert_array_equal(out[in_start], start[in_start])
    assert unresolved[~in_start].all() and not unresolved[in_start].any()
    full = tri.find_simplex(q)
    assert (full >= 0).all()
    assert points_in_triangles(q, p[s[full, 0]], p[s[full, 1]], p[s[full, 2]]).all()


def test_compiled_kernels_cache_in_the_user_cache_directory(tmp_path):
    """Compiled DTM kernels are cached under ``$CTXMATCH_CACHE/numba``, not next to the package."""
    import os
    import subprocess
    import sys

    import ctxmatch_lib

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CTXMATCH_CACHE"] = str(tmp_path)
    code = ("import numpy as np; from ctxmatch_lib.dtm._kernels import circumradii_kernel; "
            "print(circumradii_kernel(np.array([[0.0, 0], [2, 0], [0, 2]]), np.array([[0, 1, 2]]))[0])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert float(out.stdout) == pytest.approx(np.sqrt(2))
    cached = list((tmp_path / "numba").rglob("*circumradii_kernel*"))
    assert any(f.suffix == ".nbi" for f in cached)
    package = os.path.dirname(ctxmatch_lib.__file__)
    assert not [f for _, _, files in os.walk(package) for f in files if f.endswith((".nbi", ".nbc"))]


def test_two_checkouts_share_compiled_kernels_and_an_edit_compiles_anew(tmp_path):
    """Two copies of the package at different paths load each other's machine code (numba's own locators
    would file them apart by absolute path); an edit in a module that feeds kernels, not the kernel's own
    file, is a miss (numba's own stamp covers only the kernel's file)."""
    import os
    import shutil
    import subprocess
    import sys

    import ctxmatch_lib

    src = Path(ctxmatch_lib.__file__).parent
    for name in ("a", "b", "c"):
        shutil.copytree(src, tmp_path / name / "ctxmatch_lib", ignore=shutil.ignore_patterns("__pycache__"))
    fed = tmp_path / "c" / "ctxmatch_lib" / "dtm" / "_point_kernels.py"
    fed.write_text(fed.read_text() + "\n_EDITED_CONSTANT = 1\n")
    code = ("import numpy as np; from ctxmatch_lib.dtm._kernels import circumradii_kernel as k; "
            "k(np.array([[0.0, 0], [2, 0], [0, 2]]), np.array([[0, 1, 2]])); "
            "print(sum(k.stats.cache_hits.values()), sum(k.stats.cache_misses.values()))")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CTXMATCH_CACHE"] = str(tmp_path / "cache")

    def hits_misses(name):
        out = subprocess.run([sys.executable, "-c", code], env=dict(env, PYTHONPATH=str(tmp_path / name)),
                             cwd=tmp_path, capture_output=True, text=True, check=True)
        return tuple(map(int, out.stdout.split()))

    assert hits_misses("a") == (0, 1)
    assert hits_misses("b") == (1, 0)
    assert hits_misses("c") == (0, 1)
    assert len(list((tmp_path / "cache" / "numba").glob("ctxmatch_lib-*"))) == 2


def test_neighbourhood_pairs_match_their_definition():
    """DTM1 step 3 from the compiled kernel equals the pairs listed literally: for each match m (in order),
    each vertex adjacent to m's vertex in image 1 (not the vertex itself, in neighbour order), each match
    on it (increasing); flagged when the two matches' image-2 vertices are distinct and adjacent."""
    from ctxmatch_lib.dtm.core import _neighbourhood_pairs
    from ctxmatch_lib.dtm.triangulation import collapse_vertices, triangulate

    rng = np.random.default_rng(5)
    k1 = np.round(rng.random((80, 2)) * 60)  # coarse: many matches share a vertex
    k2 = np.where(rng.random((80, 1)) < 0.7, k1 + 3, np.round(rng.random((80, 2)) * 60))
    v1, vl = collapse_vertices(k1)
    v2, vr = collapse_vertices(k2)
    t1, t2 = triangulate(v1, np.array([[-20.0, -20], [80, -20], [80, 80], [-20, 80]])), triangulate(v2, None)
    rows, others, both = _neighbourhood_pairs(t1, t2, vl, vr)

    def adjacent(t, v):
        return [int(u) for u in t.indices[t.indptr[v] : t.indptr[v + 1]] if u != v]

    expected = [(m, o, vr[m] != vr[o] and int(vr[o]) in adjacent(t2, vr[m]))
                for m in range(len(k1)) for u in adjacent(t1, vl[m]) for o in np.flatnonzero(vl == u)]
    assert len(expected) > 200
    assert list(zip(rows.tolist(), others.tolist(), both.tolist())) == [(m, int(o), bool(b)) for m, o, b in expected]


# --- compiled stand-ins of the boundary construction: same output as what they replaced ---------


def _shapely_rings(points, edges):
    import shapely

    lines = shapely.linestrings(np.stack([points[edges[:, 0]], points[edges[:, 1]]], axis=1))
    return [shapely.get_coordinates(shapely.get_exterior_ring(p))
            for p in shapely.get_parts(shapely.polygonize(lines))]


@pytest.mark.parametrize("seed", range(6))
def test_contour_rings_are_geos_rings(seed):
    """The traced ring of a simple boundary cycle is GEOS's polygonize ring (start, direction, coordinates),
    for alpha-shape edges in their kernel order and for the same edges shuffled and flipped; several rings go
    to GEOS."""
    from ctxmatch_lib.dtm._point_kernels import single_ring_kernel
    from ctxmatch_lib.dtm.boundary import _rings_from_edges

    rng = np.random.default_rng(seed)
    pts = np.unique(np.round(rng.uniform(0, 400, (int(rng.integers(20, 400)), 2))), axis=0)
    shape = alpha_shape(pts)
    cases = [shape.edges]
    e = shape.edges[rng.permutation(len(shape.edges))]
    flip = rng.random(len(e)) < 0.5
    e[flip] = e[flip][:, ::-1]
    cases.append(e)
    for edges in cases:
        ours, geos = _rings_from_edges(pts, edges), _shapely_rings(pts, edges)
        assert len(ours) == len(geos)
        for a, b in zip(ours, geos):
            np.testing.assert_array_equal(a, b)
    # Two disjoint squares: not one cycle, the kernel declines and GEOS answers.
    sq = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    two = np.vstack([sq, sq + 100])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4]])
    assert len(single_ring_kernel(edges, 8)) == 0
    got = _rings_from_edges(two, edges)
    assert len(got) == 2 and all(np.array_equal(a, b) for a, b in zip(got, _shapely_rings(two, edges)))


@pytest.mark.parametrize("seed", range(4))
def test_ring_samples_are_geos_interpolation(seed):
    """Boundary samples equal shapely's line_interpolate_point at n equal steps, bit for bit."""
    import math

    import shapely

    from ctxmatch_lib.dtm.boundary import _sample_rings

    rng = np.random.default_rng(seed)
    pts = np.unique(np.round(rng.uniform(0, 640, (200, 2))), axis=0) + rng.uniform(-0.5, 0.5, 2)
    ring = _shapely_rings(pts, alpha_shape(pts).edges)
    ring.append(np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [0.0, 0.0]]))  # repeated points
    for s in (7.0, 48.0, 1e4):
        expected = []
        for r in ring:
            line = shapely.linestrings(r)
            length = float(shapely.length(line))
            n = max(math.ceil(length / s - 1e-9), 3)
            expected.append(shapely.get_coordinates(shapely.line_interpolate_point(line, np.arange(n) * (length / n))))
        np.testing.assert_array_equal(_sample_rings(ring, s), np.vstack(expected))


def test_nearest_vertex_search_matches_the_kd_tree():
    """Distances bit for bit those of cKDTree; indices too except where a tie is reported (then the tree
    decides)."""
    from ctxmatch_lib.dtm._point_kernels import nearest_kernel
    from ctxmatch_lib.dtm.boundary import _nearest

    rng = np.random.default_rng(3)
    v = np.unique(np.round(rng.uniform(0, 640, (700, 2))), axis=0)
    b = rng.uniform(-60, 700, (150, 2)).astype(np.float32).astype(np.float64)
    d_ref, j_ref = cKDTree(v).query(b)
    d, j, tie = nearest_kernel(b, v)
    np.testing.assert_array_equal(d, d_ref)
    assert not tie
    np.testing.assert_array_equal(j, j_ref)
    # A sample halfway between two vertices is a tie: _nearest returns the tree's answer.
    v2 = np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 40.0]])
    q = np.array([[5.0, 0.0]])
    assert nearest_kernel(q, v2)[2]
    np.testing.assert_array_equal(_nearest(q, v2)[1], cKDTree(v2, balanced_tree=False, compact_nodes=False).query(q)[1])


def test_key_rows_kernel_statuses():
    from ctxmatch_lib.dtm._point_kernels import key_rows_kernel

    rng = np.random.default_rng(0)
    keys = np.unique(rng.integers(-2**62, 2**62, 500))
    rng.shuffle(keys)
    q = np.r_[keys, rng.choice(keys, 1000)]
    rows, status = key_rows_kernel(keys, q)
    assert status == 0
    np.testing.assert_array_equal(keys[rows], q)
    assert key_rows_kernel(np.r_[keys, keys[:1]], q)[1] == 1  # duplicate key
    assert key_rows_kernel(keys, np.r_[q, np.setdiff1d([7, 8, 9], keys)[:1]])[1] == 2  # a query is no key
    assert key_rows_kernel(keys, q[1:len(keys)])[1] == 3  # keys[0] is nobody's


@pytest.mark.parametrize("seed", range(3))
def test_vertex_csr_matches_sorted_edge_keys(seed):
    from ctxmatch_lib.dtm._kernels import vertex_csr_kernel
    from ctxmatch_lib.dtm.triangulation import delaunay_simplices

    rng = np.random.default_rng(seed)
    pts = np.unique(np.round(rng.uniform(0, 300, (400, 2))), axis=0)
    s = delaunay_simplices(pts)
    n = len(pts) - 25  # the last points play the boundary: left out of the CSR
    a = np.concatenate([s[:, 0], s[:, 1], s[:, 2], s[:, 1], s[:, 2], s[:, 0], np.arange(n)])
    b = np.concatenate([s[:, 1], s[:, 2], s[:, 0], s[:, 0], s[:, 1], s[:, 2], np.arange(n)])
    both = (a < n) & (b < n)
    key = np.unique(a[both] * n + b[both])
    indptr, indices = vertex_csr_kernel(np.ascontiguousarray(s, np.int64), n)
    np.testing.assert_array_equal(indptr, np.r_[0, np.cumsum(np.bincount(key // n, minlength=n))])
    np.testing.assert_array_equal(indices, key % n)


@pytest.mark.parametrize("kind", ["uniform", "grid", "line", "clustered"])
def test_grid_nearest_matches_the_exhaustive_search(kind):
    """The grid search gives the exhaustive kernel's distances and tie flag bit for bit, and its indices
    wherever no tie is reported, also for queries far outside the points' box."""
    from ctxmatch_lib.dtm._point_kernels import grid_nearest_kernel, nearest_kernel

    rng = np.random.default_rng(7)
    for _ in range(40):
        n = int(rng.integers(1, 300))
        if kind == "uniform":
            p = rng.uniform(0, 640, (n, 2))
        elif kind == "grid":
            p = np.floor(rng.uniform(0, 30, (n, 2)))
        elif kind == "line":
            p = np.c_[rng.uniform(0, 640, n), np.full(n, 3.0)]
        else:
            p = np.full((n, 2), 5.0) + (rng.uniform(size=(n, 2)) < 0.1)
        q = np.floor(rng.uniform(-300, 900, (50, 2))) * 0.5
        d0, j0, tie0 = nearest_kernel(q, p)
        d1, j1, tie1 = grid_nearest_kernel(q, p)
        np.testing.assert_array_equal(d1, d0)
        assert tie1 == tie0
        if not tie0:
            np.testing.assert_array_equal(j1, j0)
    d, j, tie = grid_nearest_kernel(np.zeros((3, 2)), np.empty((0, 2)))
    assert np.isinf(d).all() and (j == -1).all() and not tie


def test_triangle_neighbors_pair_twin_edges():
    """Each interior edge joins its two triangles, hull edges have none (also with the triangles shuffled);
    a third copy of an edge, which no valid mesh has, stays unpaired."""
    from scipy.spatial import Delaunay

    from ctxmatch_lib.dtm._kernels import triangle_neighbors_kernel
    from ctxmatch_lib.dtm.triangulation import delaunay_simplices

    rng = np.random.default_rng(1)
    pts = np.unique(np.round(rng.uniform(0, 200, (300, 2))), axis=0)
    s = delaunay_simplices(pts)[rng.permutation(len(delaunay_simplices(pts)))]
    nb = triangle_neighbors_kernel(np.ascontiguousarray(s), len(pts))
    ref = Delaunay(pts)
    assert (nb < 0).sum() == len(ref.convex_hull)
    for t, k in zip(*np.nonzero(nb >= 0)):
        u = nb[t, k]
        edge = set(s[t]) - {s[t, k]}
        assert edge <= set(s[u]) and t in nb[u]
    tri = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    nb3 = triangle_neighbors_kernel(tri, 5)
    assert nb3[0, 2] == 1 and nb3[1, 2] == 0 and nb3[2, 2] == -1


@pytest.mark.parametrize("kind", ["integer", "float32", "float64"])
def test_unique_rows_is_numpys(kind):
    from ctxmatch_lib.dtm.triangulation import unique_rows

    rng = np.random.default_rng(2)
    p = rng.uniform(-40, 40, (500, 2))
    p = {"integer": np.floor(p), "float32": p.astype(np.float32).astype(np.float64), "float64": p}[kind]
    p = np.vstack([p, p[:200]])
    u, inv = unique_rows(p)
    u_ref, inv_ref = np.unique(p, axis=0, return_inverse=True)
    np.testing.assert_array_equal(u, u_ref)
    np.testing.assert_array_equal(inv, inv_ref.reshape(-1))


def test_dtm_builds_each_vertex_set_once():
    """A run's setup remembers each image's boundary and triangulation per vertex set: asked again, it returns
    the same objects, equal to a fresh construction."""
    from ctxmatch_lib.dtm.core import _Setup
    from ctxmatch_lib.dtm.triangulation import collapse_vertices

    p = planted_homography_matches(300, 0.5, rng=4)
    v1 = collapse_vertices(p.kpts1[p.matches[:, 0]])[0]
    v2 = collapse_vertices(p.kpts2[p.matches[:, 1]])[0]
    setup = _Setup(p.image_size, p.image_size, "alpha", 0.5, None, None)
    first = setup.triangulations(v1, v2)
    again = setup.triangulations(v1.copy(), v2)
    assert all(a is b for a, b in zip(first, again))
    fresh = _Setup(p.image_size, p.image_size, "alpha", 0.5, None, None).triangulations(v1, v2)
    for a, b in zip(first[2:], fresh[2:]):
        np.testing.assert_array_equal(a.simplices, b.simplices)
        np.testing.assert_array_equal(a.indices, b.indices)
    np.testing.assert_array_equal(first[0].points, fresh[0].points)
    swapped = setup.triangulations(v2, v1)  # image 1 gets v2: built for image 1, not taken from image 2's entry
    assert swapped[2] is not first[3] and len(setup.built) == 4


def test_inside_ring_is_geos_when_certain():
    """The compiled crossing-number test answers as GEOS's contains_xy whenever it says it is certain, and is
    uncertain for points on the ring (vertices, edge midpoints)."""
    import shapely

    from ctxmatch_lib.dtm._point_kernels import inside_ring_kernel
    from ctxmatch_lib.dtm._samples import _rings_from_edges
    from ctxmatch_lib.dtm.boundary import alpha_shape

    rng = np.random.default_rng(0)
    checked = 0
    for trial in range(60):
        v = np.unique(np.floor(rng.uniform(0, 200 if trial % 2 else 40, (int(rng.integers(5, 300)), 2))), axis=0)
        shape = alpha_shape(v)
        rings = _rings_from_edges(v, shape.edges) if shape is not None else []
        if len(rings) != 1:
            continue
        ring = np.ascontiguousarray(rings[0])
        q = rng.uniform(-10, 210, (200, 2)).astype(np.float32).astype(np.float64)
        inside, certain = inside_ring_kernel(ring, q)
        if certain:
            np.testing.assert_array_equal(inside, shapely.contains_xy(shapely.Polygon(ring), q[:, 0], q[:, 1]))
            checked += 1
        assert not inside_ring_kernel(ring, ring[:1])[1]
        assert not inside_ring_kernel(ring, (ring[:1] + ring[1:2]) / 2)[1]
    assert checked > 20
