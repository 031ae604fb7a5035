"""One wrapper around every filter's core: the masks it gives are those of a plain reference, the
public signatures and docstrings are composed from the shared parts, and the scores carry their scale.

The reference for the filters that merge coincident rows is written out here by hand: the distinct
(x1, y1, x2, y2) rows found with a Python dict in input order, each standing with its best-scored copy (the
first on ties), the core run on those rows, and the decision copied to every row of the group (for PGM, only
the first of the rows that repeat one keypoint pair; a row given twice, same score, is kept twice or not at all). The real-data counterpart, every registered filter's
masks before and after a change on the real candidate sets, is ``benchmarks/check_filter_masks.py``.
"""

from __future__ import annotations

import inspect
import pickle
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from ctxmatch_lib._numerics.scores import NNRScores, nnr_scores, nnr_threshold, score_ratio
from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.filters._common import knn_without_self, prepare
from ctxmatch_lib.testing import planted_homography_matches
from filter_cases import SIZE

FILTER_DIR = Path(__file__).resolve().parents[1] / "ctxmatch_lib" / "filters"

#: Filters that decide coincident rows once (the option name where it is one).
MERGING = {"bm": None, "lpm": None, "glpm": None, "pgm": None, "scv": None, "lmr": "merge_coincident",
           "rfm_scan": "merge_coincident"}
#: Wrapped filters (a ``.core`` on a prepared match set).
WRAPPED = ["th", "gms", "lpm", "glpm", "vfc", "llt", "adalam", "rfm_scan", "pgm", "scv", "bm", "pfm", "lmr"]


def _planted(n=240, inlier_ratio=0.5, seed=0, copies=30, repeats=10):
    """A planted set with coincident copies (new keypoint indices, same coordinates, own scores) and repeated
    rows (same indices), shuffled."""
    pm = planted_homography_matches(n, inlier_ratio, image_size=SIZE, rng=seed)
    rng = np.random.default_rng(seed + 7)
    rows = rng.choice(n, size=copies, replace=False)
    k1 = np.vstack([pm.kpts1, pm.kpts1[pm.matches[rows, 0]]])
    k2 = np.vstack([pm.kpts2, pm.kpts2[pm.matches[rows, 1]]])
    new = np.c_[n + np.arange(copies), n + np.arange(copies)]
    rep = rng.choice(n, size=repeats, replace=False)
    m = np.vstack([pm.matches, new, pm.matches[rep]]).astype(np.int64)
    s = np.r_[pm.scores, rng.uniform(size=copies), rng.uniform(size=repeats)]
    s[-1] = s[rep[-1]]  # a tie between copies: the first one stands for the group
    perm = rng.permutation(len(m))
    return k1, k2, m[perm], s[perm]


def _hand_merged(x, y, scores):
    """Groups of rows with equal (x, y) coordinates, by hand: ``rows`` (best-scored copy of each group, in
    order of first copy) and ``group`` (position in ``rows`` of every row)."""
    first: dict[tuple, int] = {}
    group = np.empty(len(x), np.int64)
    best: list[int] = []
    for i, key in enumerate(map(tuple, np.c_[x, y].tolist())):
        g = first.setdefault(key, len(first))
        group[i] = g
        if g == len(best):
            best.append(i)
        elif scores[i] < scores[best[g]]:
            best[g] = i
    return np.asarray(best, np.int64), group


def _reference(name, k1, k2, m, s, **params):
    """The core on hand-merged rows, the decisions copied to every copy (see the module docstring)."""
    func = FILTERS[name]
    ms = prepare(k1, k2, m, s, SIZE, SIZE)
    rows, group = _hand_merged(ms.x, ms.y, ms.scores)
    keep = func.core(ms.take(rows), **params)[group]
    if name == "pgm":
        first_pair: dict[tuple, int] = {}
        for i in np.lexsort((np.arange(len(m)), ms.scores)):  # best score first, index on ties
            first_pair.setdefault(tuple(m[i]), i)
        one = np.zeros(len(m), bool)
        one[list(first_pair.values())] = True
        keep &= one
        # The same row given twice (same keypoints, same score) is one candidate: kept if any copy is.
        key = list(zip(map(tuple, m.tolist()), ms.scores.tolist()))
        any_copy: dict[tuple, bool] = {}
        for k, kept in zip(key, keep):
            any_copy[k] = any_copy.get(k, False) or bool(kept)
        keep = np.array([any_copy[k] for k in key])
    return keep


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("name", sorted(MERGING))
def test_merging_filters_match_the_core_on_hand_merged_rows(name, seed):
    k1, k2, m, s = _planted(seed=seed)
    keep = FILTERS[name](k1, k2, m, s, image_size1=SIZE, image_size2=SIZE)
    expected = _reference(name, k1, k2, m, s)
    assert keep.dtype == bool and keep.shape == (len(m),)
    np.testing.assert_array_equal(keep, expected)
    assert 0 < keep.sum() < len(m)


@pytest.mark.parametrize("name", ["lmr", "rfm_scan"])
def test_merge_option_off_decides_every_row(name):
    k1, k2, m, s = _planted(seed=2)
    keep = FILTERS[name](k1, k2, m, s, image_size1=SIZE, image_size2=SIZE, merge_coincident=False)
    expected = FILTERS[name].core(prepare(k1, k2, m, s, SIZE, SIZE))
    np.testing.assert_array_equal(keep, expected)
    assert inspect.signature(FILTERS[name]).parameters["merge_coincident"].default is True


@pytest.mark.parametrize("name", WRAPPED)
def test_without_copies_the_filter_is_its_core(name):
    pm = planted_homography_matches(200, 0.5, image_size=SIZE, informative_scores=True, rng=3)
    keep = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, pm.scores, image_size1=SIZE, image_size2=SIZE)
    params = {}
    if name == "th":
        params["threshold"] = 0.8
    elif name == "glpm":
        params["ratio"] = 1 / 1.5
    elif name == "adalam":
        params["seed_threshold"] = 0.8
    np.testing.assert_array_equal(keep, FILTERS[name].core(prepare(pm.kpts1, pm.kpts2, pm.matches, pm.scores,
                                                                   SIZE, SIZE), **params))


@pytest.mark.parametrize("name", WRAPPED)
def test_public_signature_and_docstring(name):
    func = FILTERS[name]
    params = list(inspect.signature(func).parameters.values())
    assert [p.name for p in params[:8]] == ["kpts1", "kpts2", "matches", "scores", "image_size1", "image_size2",
                                            "shapes1", "shapes2"]
    assert all(p.kind is p.KEYWORD_ONLY for p in params[4:])
    core = list(inspect.signature(func.core).parameters)
    assert core[0] == "ms" and all(p in [q.name for q in params] for p in core[1:])
    doc = func.__doc__
    assert "%(" not in doc and "{label}" not in doc
    for p in params:
        assert re.search(rf"\b{p.name}\b.* :", doc), (name, p.name)
    assert func.__module__ == func.core.__module__ and func.__name__ == f"{name}_filter"


def test_bad_arguments_still_name_the_argument():
    k = np.zeros((3, 2))
    m = [[0, 0], [1, 1], [2, 2]]
    with pytest.raises(ValueError, match="image_size1"):
        FILTERS["bm"](k, k, m, None, image_size1=(0, 8), image_size2=(8, 8))
    with pytest.raises(ValueError, match="lambdas"):
        FILTERS["lpm"](k, k, m, None, image_size1=(8, 8), image_size2=(8, 8), lambdas=(0.8,))
    with pytest.raises(ValueError, match="seed_threshold"):
        FILTERS["adalam"](k, k, m, None, image_size1=(8, 8), image_size2=(8, 8), seed_threshold=0)
    with pytest.raises(ValueError, match="shapes1 and shapes2"):
        FILTERS["pfm"](k, k, m, None, image_size1=(8, 8), image_size2=(8, 8), shapes1=np.tile(np.eye(2), (3, 1, 1)))
    with pytest.raises(TypeError, match="bm_filter.*unexpected|bm_filter.*got an unexpected"):
        FILTERS["bm"](k, k, m, None, image_size1=(8, 8), image_size2=(8, 8), nope=1)
    with pytest.raises(TypeError, match="th_filter.*scores"):
        FILTERS["th"](k, k, m, image_size1=(8, 8), image_size2=(8, 8))


def test_no_filter_module_repeats_the_coincident_row_block():
    for path in sorted(FILTER_DIR.rglob("*.py")):
        if path.name == "_common.py":
            continue
        text = path.read_text()
        assert "merge_coincident(" not in text and "keep[group]" not in text, path.name
        if path.parent == FILTER_DIR:  # the learned filters' logits are a function of their own
            assert "ms = prepare(" not in text, path.name


def test_empty_input_gives_an_empty_mask():
    for name in WRAPPED:
        keep = FILTERS[name](np.zeros((0, 2)), np.zeros((0, 2)), np.empty((0, 2), np.int64), np.empty(0),
                             image_size1=SIZE, image_size2=SIZE)
        assert keep.shape == (0,) and keep.dtype == bool, name


def test_knn_without_self_queries_are_the_candidates():
    rng = np.random.default_rng(0)
    pts = np.round(rng.uniform(0, 20, size=(300, 2)))  # many coincident points
    every = np.arange(len(pts))
    a = knn_without_self(pts, every, 6)
    b = knn_without_self(pts, every, 6, queries=every.copy())
    c = knn_without_self(pts, every, 6, queries=every[::-1].copy())[::-1]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    ref = np.lexsort((np.broadcast_to(every, d2.shape), d2), axis=1)[:, :6]  # (distance, index), self last
    np.testing.assert_array_equal(a, ref)


# ------------------------------------------------------------------------------------------------------------
# Scores that carry their scale.

def test_nnr_scores_keep_their_ratio():
    s = nnr_scores([0.3, 0.1, 0.45, 0.2], "D+")
    for t in (s[1:], s[[2, 0]], np.sort(s), s.copy(), s[s > 0.15], pickle.loads(pickle.dumps(s))):
        assert isinstance(t, NNRScores) and t.ratio == "D+"
    assert type(s * 2) is np.ndarray and type(s <= 0.2) is np.ndarray and score_ratio(np.asarray(s)) is None
    assert isinstance(s.max(), float) and score_ratio(s) == "D+"
    with pytest.raises(ValueError, match="ratio"):
        nnr_scores([0.1], "D+=")
    with pytest.raises(ValueError, match="carry ratio 'D\\+'"):
        nnr_scores(s, "D>=")
    assert nnr_threshold(0.8, "D+>=") == 0.8 / 1.8 and nnr_threshold(0.8, "D>=") == 0.8


def _grid_case(n_side=8):
    g = np.stack(np.meshgrid(np.arange(n_side) * 20.0, np.arange(n_side) * 20.0), -1).reshape(-1, 2) + 30
    m = np.c_[np.arange(len(g)), np.arange(len(g))]
    return g, g + (5.0, -3.0), m


def test_th_reads_the_scale_the_scores_carry():
    k, k2, m = _grid_case()
    raw = np.random.default_rng(0).uniform(0.2, 0.5, len(m))
    call = dict(image_size1=SIZE, image_size2=SIZE)
    plus = FILTERS["th"](k, k2, m, raw, ratio="D+", **call)
    assert 0 < plus.sum() < len(m)
    np.testing.assert_array_equal(FILTERS["th"](k, k2, m, nnr_scores(raw, "D+"), **call), plus)
    np.testing.assert_array_equal(FILTERS["th"](k, k2, m, nnr_scores(raw, "D+"), ratio="D+", **call), plus)
    with pytest.raises(ValueError, match="ratio='D>=' contradicts"):
        FILTERS["th"](k, k2, m, nnr_scores(raw, "D+"), ratio="D>=", **call)
    with pytest.raises(ValueError, match="ratio must be one of"):
        FILTERS["th"](k, k2, m, raw, ratio="D", **call)
    # A plain array of unknown scale: read as NNR ratios ("D>="), with a warning when that keeps every row
    # although every score is in the D+ range.
    with pytest.warns(UserWarning, match="pass ratio="):
        assert FILTERS["th"](k, k2, m, raw, **call).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(FILTERS["th"](k, k2, m, raw + 0.4, **call), raw + 0.4 <= 0.8)
        FILTERS["th"](k, k2, m, None, **call)
        FILTERS["th"](k, k2, m, raw, ratio="D>=", **call)
        FILTERS["th"](k, k2, m, raw, threshold=0.3, **call)


@pytest.mark.parametrize("name, param", [("glpm", "ratio"), ("adalam", "seed_threshold")])
def test_nnr_thresholds_follow_the_scores_scale(name, param):
    pm = planted_homography_matches(300, 0.5, image_size=SIZE, informative_scores=True, rng=4)
    s = pm.scores / (1 + pm.scores) * 0.9  # on the D+ scale
    call = dict(image_size1=SIZE, image_size2=SIZE)
    default = inspect.signature(FILTERS[name]).parameters[param].default
    tagged = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, nnr_scores(s, "D+"), **call)
    by_hand = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, s, **call, **{param: nnr_threshold(default, "D+")})
    np.testing.assert_array_equal(tagged, by_hand)
    with pytest.warns(UserWarning, match=name):
        plain = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, s, **call)
    assert FILTERS[name].nnr_thresholds == (param,)
    assert plain.shape == tagged.shape


def test_engine_tags_the_scores_with_the_blob_ratio():
    from types import SimpleNamespace

    from ctxmatch_lib.evaluation.steps import run_filter

    pm = planted_homography_matches(300, 0.5, image_size=SIZE, informative_scores=True, rng=5)
    s = pm.scores / (1 + pm.scores)
    f1, f2 = SimpleNamespace(kpts=pm.kpts1, shapes=None), SimpleNamespace(kpts=pm.kpts2, shapes=None)
    for name in ("th", "glpm"):
        keep, _ = run_filter(name, f1, f2, pm.matches, s, image_size1=SIZE, image_size2=SIZE, blob_ratio="D+")
        ref = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, nnr_scores(s, "D+"), image_size1=SIZE,
                            image_size2=SIZE)
        np.testing.assert_array_equal(keep, ref)


def test_blob_matching_scores_carry_the_ratio():
    from ctxmatch_lib import blob_matching

    rng = np.random.default_rng(0)
    D = rng.uniform(size=(30, 40))
    for ratio in ("D>=", "D+>=", "D+"):
        out = blob_matching(distances=D, f=3, prefilter="cap", f_prime=2, ratio=ratio, t_o=None)
        assert isinstance(out.scores, NNRScores) and out.scores.ratio == ratio and out.scores.dtype == np.float64


@pytest.mark.slow
def test_readme_style_th_call_applies_the_ratio_test():
    """The README's Python example with ``th`` in place of ``dtm``, on ``paper-best`` candidates (D+ scores)
    of an embedded pair: Lowe's 0.8 on the NNR ratio, exactly what ``ratio="D+"`` keeps, not every row."""
    from ctxmatch_lib import BLOB_PRESETS, blob_matching
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.features import FeatureConfig, extract_features

    pair = select_pairs("embedded-planar")[0]
    cfg = FeatureConfig(max_keypoints=1000)
    f1, f2 = extract_features(pair.image1, cfg), extract_features(pair.image2, cfg)
    cand = blob_matching(f1.desc, f2.desc, kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes, shapes2=f2.shapes,
                         **BLOB_PRESETS["paper-best"].kwargs())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        keep = FILTERS["th"](f1.kpts, f2.kpts, cand.matches, cand.scores, image_size1=f1.image_size,
                             image_size2=f2.image_size)
    explicit = FILTERS["th"](f1.kpts, f2.kpts, cand.matches, np.asarray(cand.scores), image_size1=f1.image_size,
                             image_size2=f2.image_size, ratio="D+")
    np.testing.assert_array_equal(keep, explicit)
    assert 0 < keep.sum() < len(keep)
