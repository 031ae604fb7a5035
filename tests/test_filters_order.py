"""Every registered filter decides on a *set* of candidate rows: permuting the rows permutes the keep mask and
changes nothing else, and a row given twice gets one decision.

The filters decide on the rows in their canonical order (``ctxmatch_lib._numerics.order.canonical_order``:
score, keypoint coordinates, keypoint indices) and spread the decisions back, so this holds by construction;
the tests check it on every filter of the registry, on

- real candidate sets: the ``baseline`` and ``paper-best`` blob candidates of SIFT + RootSIFT at the paper's
  1500 keypoints on HPatches v_churchill 1-2 (planar) and kusvod2 temple1 (non-planar), from ``CTXMATCH_DATA``
  (skipped without it), called as the evaluation engine calls the filters (keypoint shapes, the blob ratio);
- planted sets: a homography's inliers among outliers, with tied scores, coincident keypoint copies,
  repeated rows and many-to-many rows (the ties that made LPM, GLPM, PGM, SCV and PFM depend on the order
  of their rows before), with and without shapes;

each under several seeded random permutations.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS, nnr_scores
from ctxmatch_lib._numerics.order import canonical_order, spread_back
from ctxmatch_lib.testing import planted_homography_matches

SIZE = (640, 480)
# The package's own filters: other test modules register toy filters ("test-...") into the same registry.
NAMES = [name for name in FILTERS if not name.startswith("test-")]
REAL_PAIRS = ("hpatches/v_churchill/1-2", "kusvod2/temple1")
REAL_BLOBS = ("baseline", "paper-best")
#: Random permutations per candidate set (real sets cost more: fewer of them).
N_PERM_PLANTED = 4
N_PERM_REAL = 2


def _shapes(n: int, rng) -> np.ndarray:
    """Similarity shapes (scale 2-4 px, any orientation), one per keypoint."""
    a = rng.uniform(0, 2 * np.pi, n)
    s = rng.uniform(2, 4, n)
    return s[:, None, None] * np.stack([np.stack([np.cos(a), -np.sin(a)], -1),
                                        np.stack([np.sin(a), np.cos(a)], -1)], 1)


def _planted(seed: int, n: int, inliers: float, *, shapes: bool) -> dict:
    """A planted set with the ties real candidates hold: scores on a coarse grid (many equal), coincident
    keypoint copies of some rows (new indices, same coordinates, same score), repeated rows (same indices,
    same score: the same candidate twice) and many-to-many rows (one keypoint, another partner)."""
    pm = planted_homography_matches(n, inliers, informative_scores=True, image_size=SIZE, rng=seed)
    rng = np.random.default_rng(seed)
    k1, k2, m = pm.kpts1, pm.kpts2, pm.matches.astype(np.int64)
    s = np.round(pm.scores, 1)
    cop = rng.choice(n, n // 10, replace=False)
    new = np.c_[len(k1) + np.arange(len(cop)), len(k2) + np.arange(len(cop))]
    k1, k2 = np.vstack([k1, k1[m[cop, 0]]]), np.vstack([k2, k2[m[cop, 1]]])
    rep = rng.choice(n, n // 20, replace=False)
    many = rng.choice(n, n // 10, replace=False)
    m = np.vstack([m, new, m[rep], np.c_[m[many, 0], rng.choice(n, len(many))]])
    s = np.r_[s, s[cop], s[rep], np.round(rng.uniform(size=len(many)), 1)]
    d = dict(kpts1=k1, kpts2=k2, matches=m, scores=s, image_size1=SIZE, image_size2=SIZE)
    if shapes:
        d.update(shapes1=_shapes(len(k1), rng), shapes2=_shapes(len(k2), rng))
    return d


PLANTED = {
    "planted-300-shapes": lambda: _planted(0, 300, 0.5, shapes=True),
    "planted-200-noshapes": lambda: _planted(1, 200, 0.3, shapes=False),
    "planted-40-shapes": lambda: _planted(2, 40, 0.7, shapes=True),
}


def _call(name: str, d: dict, perm: np.ndarray | None = None) -> np.ndarray:
    """``FILTERS[name]`` on ``d``, its rows taken in the order ``perm``; the mask in the order of ``d``."""
    f = FILTERS[name]
    m, s = d["matches"], d["scores"]
    if perm is not None:
        m, s = m[perm], s[perm]  # NNRScores keep their ratio through indexing
    params = {"ratio": d["ratio"]} if "ratio" in d and getattr(f, "uses_blob_ratio", False) else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # e.g. filters told to pass shapes: not what is tested
        keep = f(d["kpts1"], d["kpts2"], m, s, image_size1=d["image_size1"], image_size2=d["image_size2"],
                 shapes1=d.get("shapes1"), shapes2=d.get("shapes2"), **params)
    assert keep.dtype == bool and keep.shape == (len(m),)
    if perm is None:
        return keep
    back = np.empty_like(keep)
    back[perm] = keep
    return back


def _assert_equivariant(name: str, key: str, d: dict, n_perm: int) -> None:
    ref = _call(name, d)
    for i in range(n_perm):
        perm = np.random.default_rng([i, len(d["matches"])]).permutation(len(d["matches"]))
        back = _call(name, d, perm)
        diff = np.flatnonzero(back != ref)
        assert not len(diff), (f"{name} on {key}, permutation {i}: {len(diff)} of {len(ref)} decisions change "
                               f"(kept {int(ref.sum())} in the given order)")


@pytest.fixture(scope="module")
def planted_sets():
    return {k: make() for k, make in PLANTED.items()}


@pytest.mark.parametrize("key", list(PLANTED))
@pytest.mark.parametrize("name", NAMES)
def test_planted_rows_permuted_permute_the_mask(name, key, planted_sets):
    _assert_equivariant(name, key, planted_sets[key], N_PERM_PLANTED)


@pytest.fixture(scope="module")
def real_sets(data_root):
    """The real candidate sets (features and candidates come from the disk cache after the first run)."""
    from dataclasses import replace

    from ctxmatch_lib._numerics.scores import score_ratio
    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import blob_candidates, pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget

    fcfg = replace(FEATURE_PRESETS["sift-rootsift"], max_keypoints=keypoint_budget("paper"))
    out = {}
    for pair in select_pairs(["planar", "nonplanar"], REAL_PAIRS):
        f1, f2 = pair_features(pair, fcfg)
        for blob in REAL_BLOBS:
            cfg = BLOB_PRESETS[blob]
            m, s, _ = blob_candidates(f1, f2, cfg)
            s = s if score_ratio(s) is not None else nnr_scores(s, cfg.ratio)  # as blob_matching returns them
            out[f"{pair.pair_id}@{blob}"] = dict(
                kpts1=f1.kpts, kpts2=f2.kpts, matches=m, scores=s, image_size1=tuple(pair.image_size1),
                image_size2=tuple(pair.image_size2), shapes1=f1.shapes, shapes2=f2.shapes, ratio=cfg.ratio)
    return out


REAL_KEYS = [f"{p}@{b}" for p in REAL_PAIRS for b in REAL_BLOBS]


@pytest.mark.parametrize("key", REAL_KEYS)
@pytest.mark.parametrize("name", NAMES)
def test_real_rows_permuted_permute_the_mask(name, key, real_sets):
    d = real_sets[key]
    _assert_equivariant(name, key, d, N_PERM_REAL)


@pytest.mark.parametrize("name", NAMES)
def test_a_row_given_twice_is_kept_twice_or_not_at_all(name, planted_sets):
    d = dict(planted_sets["planted-300-shapes"])
    n = len(d["matches"])
    rows = np.arange(0, n, 7)  # inliers and outliers, some kept and some not
    d["matches"] = np.vstack([d["matches"], d["matches"][rows]])
    d["scores"] = np.r_[d["scores"], d["scores"][rows]]
    keep = _call(name, d)
    twice = np.flatnonzero(keep[rows] != keep[n:])
    assert not len(twice), f"{name}: {len(twice)} of {len(rows)} rows given twice kept once"
    perm = np.random.default_rng(5).permutation(len(d["matches"]))
    np.testing.assert_array_equal(_call(name, d, perm), keep)


def test_canonical_order_depends_on_the_set_only():
    rng = np.random.default_rng(0)
    x = rng.integers(0, 3, (200, 2)).astype(float)
    y = rng.integers(0, 3, (200, 2)).astype(float)
    m = rng.integers(0, 4, (200, 2))
    s = rng.integers(0, 2, 200).astype(float)
    order, twins = canonical_order(x, y, m, s)
    rows = np.c_[s, x, y, m][order]
    perm = rng.permutation(200)
    order_p, twins_p = canonical_order(x[perm], y[perm], m[perm], s[perm])
    np.testing.assert_array_equal(np.c_[s, x, y, m][perm][order_p], rows)  # the same sorted rows
    np.testing.assert_array_equal(twins_p, twins)
    # Sorted by score, then the coordinates, then the indices; equal rows share a group, numbered in order.
    assert (np.diff(rows[:, 0]) >= 0).all()
    new = np.r_[True, (rows[1:] != rows[:-1]).any(axis=1)]
    np.testing.assert_array_equal(twins, np.cumsum(new) - 1)
    # A mask decided in canonical order goes back to the rows given; equal rows get one decision (any copy).
    keep = rng.integers(0, 2, 200).astype(bool)
    back = spread_back(keep, order, twins)
    np.testing.assert_array_equal(back[order], (np.bincount(twins, weights=keep) > 0)[twins])
    assert canonical_order(np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.int64), np.empty(0))[1] is None


# ----- no silent empty mask without the keypoint shapes --------------------------------------------------


def _quiet_call(name: str, d: dict, *, shapes: bool):
    """``(keep or None, messages)``: the mask (None when a ValueError was raised) and every warning's or the
    error's message."""
    f = FILTERS[name]
    params = {"ratio": d["ratio"]} if "ratio" in d and getattr(f, "uses_blob_ratio", False) else {}
    sh = dict(shapes1=d.get("shapes1"), shapes2=d.get("shapes2")) if shapes else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            keep = f(d["kpts1"], d["kpts2"], d["matches"], d["scores"], image_size1=d["image_size1"],
                     image_size2=d["image_size2"], **sh, **params)
        except ValueError as exc:
            return None, [str(exc)]
    return keep, [str(w.message) for w in caught]


@pytest.mark.parametrize("key", [k for k in REAL_KEYS if k.endswith("@paper-best")])
@pytest.mark.parametrize("name", NAMES)
def test_without_shapes_a_filter_decides_or_names_them(name, key, real_sets):
    """Called as the README calls DTM (no shapes), a filter keeps something, or keeps nothing as it does with
    the shapes, or says that it needs them: never an empty mask that reads as a verdict."""
    d = real_sets[key]
    bare, said = _quiet_call(name, d, shapes=False)
    if bare is not None and bare.any():
        return
    if any("shapes1" in m for m in said):
        return
    keep, _ = _quiet_call(name, d, shapes=True)
    assert not keep.any(), (f"{name} keeps nothing of {key} without shapes1 / shapes2 ({int(keep.sum())} with "
                            "them) and says nothing")


def _many_to_many(seed: int = 0, n: int = 400, partners: int = 3):
    """Planted one-to-one candidates, and every image-1 keypoint matched to ``partners`` more random image-2
    keypoints (as blob matching's many-to-many candidates)."""
    pm = planted_homography_matches(n, 0.6, informative_scores=True, image_size=SIZE, rng=seed)
    rng = np.random.default_rng(seed)
    extra = np.c_[np.repeat(pm.matches[:, 0], partners), rng.integers(0, len(pm.kpts2), partners * n)]
    return pm, np.vstack([pm.matches, extra]), np.r_[pm.scores, rng.uniform(size=len(extra))]


def test_pfm_without_shapes_on_many_to_many_candidates_warns_naming_them():
    pm, m, s = _many_to_many()
    rng = np.random.default_rng(1)
    sh1, sh2 = _shapes(len(pm.kpts1), rng), _shapes(len(pm.kpts2), rng)
    with pytest.warns(UserWarning, match="shapes1 / shapes2"):
        FILTERS["pfm"](pm.kpts1, pm.kpts2, m, s, image_size1=SIZE, image_size2=SIZE)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        FILTERS["pfm"](pm.kpts1, pm.kpts2, m, s, image_size1=SIZE, image_size2=SIZE, shapes1=sh1, shapes2=sh2)
        # One-to-one candidates: the maps fitted to shared neighbours decide, without a warning.
        keep = FILTERS["pfm"](pm.kpts1, pm.kpts2, pm.matches, pm.scores, image_size1=SIZE, image_size2=SIZE)
    assert pm.is_inlier[keep].mean() > 0.9 and keep[pm.is_inlier].mean() > 0.8
