"""Filters against their authors' code: the duplicated-outlier case of GMS and AdaLAM, and the helpers of
``benchmarks/bench_filters_ref.py`` (reference runner, Jaccard, precision / recall) on tiny synthetic cases.

The comparison with ``cv2.xfeatures2d.matchGMS`` runs only when ``CTXMATCH_GMS_REF_PYTHON`` names an
interpreter with opencv-contrib-python (it conflicts with the project's OpenCV, so it is never installed here).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import planted_homography_matches
from filter_cases import planted_similarity

SIZE = (640, 480)


def duplicated_outlier(copies: int, *, same_row: bool = False, seed: int = 0):
    """300 correct planted matches plus one wrong match on ``copies`` coincident keypoint copies in both
    images (SIFT's several orientations at one location), or the same row repeated ``copies`` times."""
    pm = planted_homography_matches(300, 1.0, noise=0.3, image_size=SIZE, rng=seed)
    p, q = np.array([[320.0, 240.0]]), np.array([[60.0, 420.0]])  # q is nowhere near H(p)
    n1, n2 = len(pm.kpts1), len(pm.kpts2)
    if same_row:
        k1, k2 = np.vstack([pm.kpts1, p]), np.vstack([pm.kpts2, q])
        extra = np.tile([[n1, n2]], (copies, 1))
    else:
        k1, k2 = np.vstack([pm.kpts1, np.repeat(p, copies, 0)]), np.vstack([pm.kpts2, np.repeat(q, copies, 0)])
        extra = np.c_[n1 + np.arange(copies), n2 + np.arange(copies)]
    return k1, k2, np.vstack([pm.matches, extra]).astype(np.int64)


def gms(k1, k2, m, **kw):
    return FILTERS["gms"](k1, k2, m, None, image_size1=SIZE, image_size2=SIZE, **kw)


@pytest.mark.parametrize("same_row", [False, True])
def test_gms_duplicated_outlier_counts_every_row_as_the_authors_code(same_row):
    # matchGMS (and the authors' GmsMatcher) let every row vote: 8 copies of one wrong match outvote the
    # sparse correct matches of their cell (about 0.75 per cell here) and pass 6 sqrt(n), so all 8 are kept;
    # 1 or 3 copies are rejected. distinct_votes=True counts the copies once and rejects them.
    for copies, kept in ((1, False), (3, False), (8, True)):
        keep = gms(*duplicated_outlier(copies, same_row=same_row))
        assert keep[300:].all() if kept else not keep[300:].any(), copies
        assert keep[:300].sum() > 150
    keep = gms(*duplicated_outlier(8, same_row=same_row), distinct_votes=True)
    assert not keep[300:].any()
    assert keep[:300].sum() > 150


def test_gms_distinct_votes_shares_one_verdict_per_location_pair():
    k1, k2, m = duplicated_outlier(5)
    m = np.vstack([m, m[:40]])  # repeat 40 correct rows too
    keep = gms(k1, k2, m, distinct_votes=True)
    np.testing.assert_array_equal(keep[-40:], keep[:40])
    assert not keep[300:305].any()


@pytest.mark.parametrize("same_row", [False, True])
def test_adalam_duplicated_outlier_rejected_as_kornia(same_row):
    # kornia's AdaLAM (the authors' port) lets residuals equal in half precision share one vote, so copies of
    # a wrong match cannot make their own neighbourhood confident; measured: it rejects the 8 copies and
    # keeps the 300 correct matches, as ours does.
    k1, k2, m = duplicated_outlier(8, same_row=same_row)
    s = np.random.default_rng(0).uniform(0.1, 0.7, len(m))
    s[300:] = 0.2
    sh1, sh2 = np.tile(np.eye(2) * 3.0, (len(k1), 1, 1)), np.tile(np.eye(2) * 3.0, (len(k2), 1, 1))
    keep = FILTERS["adalam"](k1, k2, m, s, image_size1=SIZE, image_size2=SIZE, shapes1=sh1, shapes2=sh2)
    assert not keep[300:].any()
    assert keep[:300].all()


@pytest.mark.skipif(not os.environ.get("CTXMATCH_GMS_REF_PYTHON"),
                    reason="CTXMATCH_GMS_REF_PYTHON (an interpreter with opencv-contrib-python) is not set")
@pytest.mark.parametrize("options", [{}, {"with_scale": True}, {"with_scale": True, "with_rotation": True}])
def test_gms_equals_matchgms(bench, options):
    cases, ours = [], []
    for copies, same_row in ((1, False), (8, False), (8, True)):
        k1, k2, m = duplicated_outlier(copies, same_row=same_row, seed=copies)
        sh1, sh2 = np.tile(np.eye(2), (len(k1), 1, 1)), np.tile(np.eye(2), (len(k2), 1, 1))
        cases.append(dict(kpts1=k1, kpts2=k2, matches=m, scores=np.full(len(m), 0.5), size1=np.array(SIZE),
                          size2=np.array(SIZE), shapes1=sh1, shapes2=sh2, **bench.reference_options("gms", options)))
        ours.append(gms(k1, k2, m, **options))
    for keep, (ref, _) in zip(ours, bench.run_reference("gms", os.environ["CTXMATCH_GMS_REF_PYTHON"], cases)):
        np.testing.assert_array_equal(keep, ref)


# ----- the benchmark's helpers --------------------------------------------------------------------------


def test_jaccard_exact(bench):
    a = np.array([True, True, False, False, True])
    b = np.array([True, False, True, False, True])
    assert bench.jaccard(a, b) == pytest.approx(2 / 4)
    assert bench.jaccard(a, a) == 1.0
    assert bench.jaccard(np.zeros(3, bool), np.zeros(3, bool)) == 1.0
    assert bench.jaccard(np.zeros(0, bool), np.zeros(0, bool)) == 1.0


def test_precision_recall_normalised(bench):
    # Correct candidates: rows 0, 1, 2 (rows 0 and 1 share image-1 keypoint 0); the output keeps rows 0, 1
    # and the wrong row 3. Normalised counts: output correct {0-0, 0-1} -> 1, reference -> 2.
    matches = np.array([[0, 0], [0, 1], [1, 2], [2, 3]])
    labels = np.array([True, True, True, False])
    p, r = bench.precision_recall(matches, labels, np.array([True, True, False, True]))
    assert p == pytest.approx(200 / 3)
    assert r == pytest.approx(50.0)


def test_parse_ref_errors_name_the_flag(bench):
    with pytest.raises(ValueError, match="--ref"):
        bench.parse_ref("gms")
    with pytest.raises(ValueError, match="no reference runner"):
        bench.parse_ref("dtm=/usr/bin/python3")
    with pytest.raises(ValueError, match="kornia"):
        bench.parse_ref("gms=kornia")
    assert bench.parse_ref("adalam=kornia") == ("adalam", sys.executable)


def test_reference_runner_adalam_tiny_case(bench):
    # The runner end to end (npz in, driver process, npz out) with the reference that this environment has.
    pytest.importorskip("kornia")
    g = np.stack(np.meshgrid(np.arange(12) * 25.0 + 40, np.arange(10) * 25.0 + 30), -1).reshape(-1, 2)
    y = g + (7.0, -3.0)
    y[0] = (600.0, 400.0)  # one outlier
    m = np.c_[np.arange(len(g)), np.arange(len(g))]
    rng = np.random.default_rng(0)
    scores = rng.uniform(0.1, 0.7, len(g))
    f = type("F", (), {})
    f1, f2 = f(), f()
    f1.kpts, f2.kpts = g, y
    f1.shapes = f2.shapes = np.tile(np.eye(2) * 3.0, (len(g), 1, 1))
    case = bench.make_case(f1, f2, m, scores, SIZE, SIZE)
    [(keep, cpu)] = bench.run_reference("adalam", sys.executable, [case])
    assert keep.dtype == bool and keep.shape == (len(g),) and cpu >= 0
    assert not keep[0] and keep[1:].mean() > 0.9
    ours = FILTERS["adalam"](g, y, m, scores, image_size1=SIZE, image_size2=SIZE, shapes1=f1.shapes,
                             shapes2=f2.shapes)
    assert bench.jaccard(ours, keep) > 0.9


# ----- LPM, GLPM, VFC against the authors' MATLAB code (GNU Octave) ----------------------------------------


def _brute_lpm_code(x, y, k=6, lambdas=(0.8, 0.5), tau=0.2):
    """LPM as the authors' LPM_cosF.m / demo_LPM_v2.m compute it, brute force, for inputs without ties: per
    query the k + 3 nearest (itself included) among the candidates, the first answer dropped; scale j of
    (k + 2, k, k - 2) takes the answers j .. j + s - 1 of what is left; squared length ratio; s < tau."""
    v = y - x
    d2 = (v**2).sum(1)

    def keep_mask(cand, lam):
        dx = ((x[:, None] - x[cand][None]) ** 2).sum(-1)
        dy = ((y[:, None] - y[cand][None]) ** 2).sum(-1)
        nx = cand[np.argsort(dx, axis=1)[:, :k + 3]][:, 1:]
        ny = cand[np.argsort(dy, axis=1)[:, :k + 3]][:, 1:]
        cost = np.zeros(len(x))
        for j, s in enumerate((k + 2, k, k - 2)):
            for i in range(len(x)):
                common = set(nx[i, j:j + s]) & set(ny[i, j:j + s])
                bad = 0
                for c in common:
                    cos = v[i] @ v[c] / np.sqrt(d2[i] * d2[c])
                    bad += cos * min(d2[i], d2[c]) / max(d2[i], d2[c]) < tau
                cost[i] += (s - len(common) + bad) / s
        return cost / 3 <= lam

    keep = keep_mask(np.arange(len(x)), lambdas[0])
    if keep.sum() >= k + 4:
        keep = keep_mask(np.flatnonzero(keep), lambdas[1])
    return keep


def _planted(n=150, outliers=40, seed=0):
    return planted_similarity(n, outliers, seed)


@pytest.mark.parametrize("seed", [0, 1])
def test_lpm_code_reading_equals_brute_force_of_the_authors_steps(seed):
    x, y, m = _planted(seed=seed)
    keep = FILTERS["lpm"](x, y, m, image_size1=SIZE, image_size2=SIZE)
    np.testing.assert_array_equal(keep, _brute_lpm_code(x, y))
    assert not keep[:40].any() and keep[40:].mean() > 0.9


def test_lpm_readings_differ_and_validate():
    x, y, m = _planted(n=300, outliers=120, seed=3)
    code = FILTERS["lpm"](x, y, m, image_size1=SIZE, image_size2=SIZE)
    ijcv = FILTERS["lpm"](x, y, m, image_size1=SIZE, image_size2=SIZE, reading="ijcv")
    assert code.shape == ijcv.shape == (300,)
    with pytest.raises(ValueError, match="reading"):
        FILTERS["lpm"](x, y, m, image_size1=SIZE, image_size2=SIZE, reading="matlab")


def test_glpm_guide_location_adds_the_candidates_at_a_guide_location():
    # One-to-one input: no other candidate shares an image-1 location, so both guides are the same.
    x, y, m = _planted(n=200, outliers=50, seed=4)
    s = np.where(np.arange(200) % 2 == 0, 0.5, 0.9)
    a = FILTERS["glpm"](x, y, m, s, image_size1=SIZE, image_size2=SIZE)
    b = FILTERS["glpm"](x, y, m, s, image_size1=SIZE, image_size2=SIZE, guide="rows")
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="guide"):
        FILTERS["glpm"](x, y, m, s, image_size1=SIZE, image_size2=SIZE, guide="coordinates")
    # Many-to-many: every image-1 keypoint of a correct match also matched to a wrong image-2 keypoint, the
    # wrong rows outside the small set. With guide="location" they join the guide (as the authors' demo);
    # the correct rows still pass and the wrong ones, sharing no neighbourhood, are still rejected.
    rng = np.random.default_rng(5)
    k2 = np.vstack([y, rng.uniform(0, 600, (200, 2))])
    mm = np.vstack([m, np.c_[np.arange(200), 200 + np.arange(200)]])
    ss = np.r_[s, np.full(200, 0.95)]
    keep = FILTERS["glpm"](x, k2, mm, ss, image_size1=SIZE, image_size2=SIZE)
    assert keep[50:200].mean() > 0.9 and keep[200:].mean() < 0.1


def test_octave_demo_blocks_are_read_between_markers(bench):
    demo = "a = 1;\n%% p\nlambda1 = 0.8; lambda2 = 0.5;\nnumNeigh1 = 6;\ntau1 = 0.2;\ntic;\nb = 2;\nc = 3;\ntoc\nd = 4;"
    params, block = bench.lpm_demo_parts(demo)
    assert "lambda1 = 0.8" in params and "numNeigh1" in params and "tau1" in params
    assert block == "b = 2;\nc = 3;"
    glpm = ("load(fn_match_1_5);\nx = 1;\ntime1 = toc;\nload(fn_match_1);\ny = 2;\np = ffm2(X);\n"
            "ind = find(p == 1);\nload(correct_index);")
    small, whole = bench.glpm_demo_parts(glpm)
    assert small == "x = 1;" and whole == "y = 2;\np = ffm2(X);\nind = find(p == 1);"
    with pytest.raises(ValueError, match="block"):
        bench.demo_block("x = 1;", "tic", "toc")


def test_octave_options_and_keep_parsing(bench):
    assert bench.octave_assignments("lpm", {"k": 5, "lambdas": [0.7, 0.4], "reading": "ijcv"}) == (
        "numNeigh1 = 5.0;\nnumNeigh2 = 5.0;\nlambda1 = 0.7;\nlambda2 = 0.4;")
    assert bench.octave_assignments("vfc", {"beta": 0.2, "n_control": 15}) == "conf.beta = 0.2;"
    with pytest.raises(ValueError, match="lambdas"):
        bench.octave_assignments("lpm", {"lambdas": [0.7]})
    np.testing.assert_array_equal(bench.read_keep("2\n4\n", 5), [False, True, False, True, False])
    assert not bench.read_keep("", 3).any()
    with pytest.raises(ValueError, match="outside"):
        bench.read_keep("0\n", 3)


def test_parse_ref_octave_needs_a_checkout(bench, tmp_path):
    with pytest.raises(ValueError, match="not a directory"):
        bench.parse_ref(f"lpm={tmp_path / 'missing'}")
    with pytest.raises(ValueError, match="LPM_cosF.m|demo_LPM_v2.m"):
        bench.parse_ref(f"lpm={tmp_path}")


_REF_DIRS = {name: os.environ.get(f"CTXMATCH_{name.upper()}_REF") for name in ("lpm", "glpm", "vfc")}


@pytest.mark.parametrize("name", ["lpm", "glpm", "vfc"])
def test_octave_reference_agrees_on_one_to_one_matches(bench, name):
    # The authors' code under Octave on a tie-free planted case: the same decisions as ours.
    if shutil.which("octave") is None:
        pytest.skip("GNU Octave ('octave') is not on PATH")
    if not _REF_DIRS[name]:
        pytest.skip(f"CTXMATCH_{name.upper()}_REF (a checkout of the authors' {name} code) is not set")
    x, y, m = _planted(n=200, outliers=50, seed=6)
    s = np.where(np.arange(200) % 3 == 0, 0.9, 0.5)
    [(ref, cpu)] = bench.run_octave_reference(name, Path(_REF_DIRS[name]), [dict(X=x, Y=y, small=s <= 1 / 1.5)])
    ours = FILTERS[name](x, y, m, s, image_size1=SIZE, image_size2=SIZE)
    assert cpu >= 0
    if name == "vfc":  # control points drawn at random on both sides (measured: identical here)
        assert bench.jaccard(ours, ref) > 0.95
    else:  # no ties: the same neighbourhoods, the same decisions (measured: identical)
        np.testing.assert_array_equal(ours, ref)


@pytest.mark.parametrize("drop_outside", [True, False])
def test_tree_neighbours_follow_the_demos_first_answer_rule(drop_outside):
    # Rows at repeated locations (many-to-many candidates): brute force of the rule the demos apply to the
    # k-d tree's answers, ties ranked by index: the k + 1 nearest candidates, the query included when it is
    # one; the first answer dropped for a candidate query (and for an outside query if drop_outside).
    from ctxmatch_lib.filters.lpm import _tree_neighbours

    rng = np.random.default_rng(7)
    pts = rng.integers(0, 6, (60, 2)).astype(float)  # many coincident rows
    cand = np.sort(rng.choice(60, 35, replace=False))
    k = 4
    got = _tree_neighbours(pts, cand, k, drop_outside=drop_outside)
    for i in range(60):
        d2 = ((pts[cand] - pts[i]) ** 2).sum(1)
        ranked = cand[np.lexsort((cand, d2))][:k + 1]
        member = i in set(cand)
        expect = ranked[1:k + 1] if (member or drop_outside) else ranked[:k]
        np.testing.assert_array_equal(got[i], expect, err_msg=str(i))


def test_permute_case_moves_the_rows_only(bench):
    case = dict(X=np.arange(10.0).reshape(5, 2), Y=-np.arange(10.0).reshape(5, 2), small=np.r_[True, False, True,
                False, False], matches=np.c_[np.arange(5), np.arange(5)[::-1]], scores=np.arange(5.0),
                size1=np.array(SIZE), kpts1=np.zeros((7, 2)))
    perm = np.array([3, 0, 4, 1, 2])
    out = bench.permute_case(case, perm)
    for key in ("X", "Y", "small", "matches", "scores"):
        np.testing.assert_array_equal(out[key], case[key][perm])
    assert out["size1"] is case["size1"] and out["kpts1"] is case["kpts1"]
    keep_perm = np.array([True, False, False, True, False])  # a mask on the permuted rows maps back by perm
    back = np.zeros(5, bool)
    back[perm] = keep_perm
    np.testing.assert_array_equal(np.flatnonzero(back), np.sort(perm[keep_perm]))
