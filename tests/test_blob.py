"""Blob matching (Sec. 3): the paper's toy example, properties, FGINN against brute force, bad input."""

import math

import numpy as np
import pytest
import shapely
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ctxmatch_lib.blob import (
    BLOB_PRESETS,
    BlobConfig,
    BlobContext,
    blob_grid,
    blob_matching,
    ellipse_overlap_error,
    shapes_from_scale_angle,
)
from ctxmatch_lib.blob.toy import FIG1A_D

TOY = FIG1A_D  # Fig. 1a of the paper
S_MNN = {(2, 2), (1, 3), (3, 4), (7, 1)}
S_GNN = S_MNN | {(6, 5)}
F2 = {(2, 2), (4, 2), (1, 3), (2, 5), (3, 4), (7, 1), (7, 5), (1, 1), (4, 3)}

# The table of Fig. 1a, counting from 1. Row 6 reads "f > 0∪, f' = 1" but must mean f >= 2∪: row 4 shows
# that f = 1∪, f' = 1 gives S_mNN.
TOY_TABLE = [
    (1, "cap", 1, S_MNN),
    (1, "cap", 2, S_MNN),
    (1, "cap", 5, S_MNN),
    (1, "cup", 1, S_MNN),
    ("omega", "cup", 1, S_GNN),
    (7, "cup", 1, S_GNN),
    (2, "cup", 1, S_GNN),
    (3, "cup", 1, S_GNN),
    (5, "cup", 1, S_GNN),
    (3, "cap", 1, S_MNN),
    (1, "cup", 2, {(2, 2), (4, 2), (1, 3), (2, 5), (3, 4), (7, 1), (5, 3), (6, 1)}),
    (3, "cap", 2, F2),
    ("omega", "cup", 2, F2 | {(5, 4)}),
    (7, "cap", 2, F2 | {(5, 4)}),
    (3, "cup", 2, F2 | {(5, 4)}),
]


def as_set(out):
    return {(int(i) + 1, int(j) + 1) for i, j in out.matches}


@pytest.mark.parametrize("f, prefilter, f_prime, expected", TOY_TABLE)
def test_toy_table_of_fig_1a(f, prefilter, f_prime, expected):
    out = blob_matching(distances=TOY, f=f, prefilter=prefilter, f_prime=f_prime, ratio="D>=", t_o=None)
    assert as_set(out) == expected


def test_toy_nn_rows_and_columns():
    # The first two rows of the table: plain NN by row and by column are not blob setups, but S_mNN is
    # their intersection.
    by_row = {(i + 1, int(np.argmin(TOY[i])) + 1) for i in range(7)}
    by_col = {(int(np.argmin(TOY[:, j])) + 1, j + 1) for j in range(5)}
    assert by_row == {(1, 3), (2, 2), (3, 4), (4, 2), (5, 3), (6, 1), (7, 1)}
    assert by_col == {(1, 3), (2, 2), (2, 5), (3, 4), (7, 1)}
    assert by_row & by_col == S_MNN


def test_toy_scores_by_hand():
    # f = 1∩ gives S_mNN; D≥ with image 1 as reference: D_ij / next value >= D_ij on row i.
    out = blob_matching(distances=TOY, f=1, prefilter="cap", f_prime=1, ratio="D>=", t_o=None, combine="a")
    got = {(int(i) + 1, int(j) + 1): s for (i, j), s in zip(out.matches, out.scores)}
    assert got[(2, 2)] == pytest.approx(0.5 / 1.1)
    assert got[(1, 3)] == pytest.approx(1.0 / 1.6)
    assert got[(3, 4)] == pytest.approx(1.2 / 2.0)
    assert got[(7, 1)] == pytest.approx(1.3 / 1.4)
    # Image 2 as reference: columns.
    out = blob_matching(distances=TOY, f=1, prefilter="cap", f_prime=1, ratio="D>=", t_o=None, combine="b")
    got = {(int(i) + 1, int(j) + 1): s for (i, j), s in zip(out.matches, out.scores)}
    assert got[(2, 2)] == pytest.approx(0.5 / 0.6)
    assert got[(7, 1)] == pytest.approx(1.3 / 1.6)
    # D+ with harmonic W.
    out = blob_matching(distances=TOY, f=1, prefilter="cap", f_prime=1, ratio="D+", t_o=None)
    got = {(int(i) + 1, int(j) + 1): s for (i, j), s in zip(out.matches, out.scores)}
    a, b = 0.5 / (0.5 + 1.1), 0.5 / (0.5 + 0.6)
    assert got[(2, 2)] == pytest.approx(2 * a * b / (a + b))
    assert np.all(np.diff(out.scores) >= 0)


def test_geq_restriction_for_non_best_entries():
    # (1, 1) = 1.6 is accepted at f' = 2 but is not row 1's best (1.0): D≥ uses the next value >= 1.6
    # on row 1 (2.3), D+ the best other entry of row 1 (1.0).
    kw = dict(distances=TOY, f=3, prefilter="cap", f_prime=2, t_o=None, combine="a")
    geq = blob_matching(ratio="D>=", **kw)
    plus = blob_matching(ratio="D+", **kw)
    plus_geq = blob_matching(ratio="D+>=", **kw)
    pick = lambda out: dict(zip(map(tuple, out.matches.tolist()), out.scores))  # noqa: E731
    assert pick(geq)[(0, 0)] == pytest.approx(1.6 / 2.3)
    assert pick(plus_geq)[(0, 0)] == pytest.approx(1.6 / (1.6 + 2.3))
    assert pick(plus)[(0, 0)] == pytest.approx(1.6 / (1.6 + 1.0))


# -- a brute-force reference, straight from the definitions --------------------------------------------
def _poly(c, A, k=256):
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    return shapely.Polygon(c + np.stack([np.cos(t), np.sin(t)], 1) @ A.T)


def ref_overlap_error(c1, A1, c2, A2, k=256):
    p, q = _poly(c1, A1, k), _poly(c2, A2, k)
    return 1 - p.intersection(q).area / p.union(q).area


def reference_blob(D, cfg: BlobConfig, k1=None, k2=None, s1=None, s2=None):
    n, m = D.shape
    idx = [(i, j) for i in range(n) for j in range(m)]
    order = sorted(idx, key=lambda e: (D[e], e[0], e[1]))
    row_rank = {e: sorted(range(m), key=lambda j: (D[e[0], j], j)).index(e[1]) for e in idx}
    col_rank = {e: sorted(range(n), key=lambda i: (D[i, e[1]], i)).index(e[0]) for e in idx}
    f = max(n, m) if cfg.f == "omega" else cfg.f
    if cfg.prefilter == "cup":
        F = [e for e in order if row_rank[e] < f or col_rank[e] < f]
    else:
        F = [e for e in order if row_rank[e] < f and col_rank[e] < f]
    rc, cc, G = {}, {}, []
    for i, j in F:
        if rc.get(i, 0) < cfg.f_prime and cc.get(j, 0) < cfg.f_prime:
            rc[i], cc[j] = rc.get(i, 0) + 1, cc.get(j, 0) + 1
            G.append((i, j))

    def excluded(pts, shp, a, b):
        if a == b:
            return True
        if cfg.t_o is None:
            return False
        if cfg.t_o_kind == "px":
            return np.hypot(*(pts[a] - pts[b])) < cfg.t_o
        return ref_overlap_error(pts[a], shp[a], pts[b], shp[b]) <= cfg.t_o

    def ratio(d, others):
        if cfg.ratio != "D+":
            others = [v for v in others if v >= d]
        d2 = min(others, default=math.inf)
        if cfg.ratio == "D>=":
            return 0.0 if math.isinf(d2) else (1.0 if d == d2 == 0 else d / d2)
        return 0.0 if math.isinf(d2) else (0.5 if d == d2 == 0 else d / (d + d2))

    out = {}
    for i, j in G:
        a = ratio(D[i, j], [D[i, k] for k in range(m) if not excluded(k2, s2, k, j)])
        b = ratio(D[i, j], [D[k, j] for k in range(n) if not excluded(k1, s1, k, i)])
        out[(i, j)] = {"a": a, "b": b, "min": min(a, b), "max": max(a, b),
                       "harmonic": 0.0 if a + b == 0 else 2 * a * b / (a + b)}[cfg.combine]
    return out


def _random_case(seed, n, m, d=8):
    rng = np.random.default_rng(seed)
    desc1 = rng.random((n, d)).astype(np.float32)
    desc2 = rng.random((m, d)).astype(np.float32)
    k1, k2 = rng.uniform(0, 40, (n, 2)), rng.uniform(0, 40, (m, 2))
    s1 = shapes_from_scale_angle(rng.uniform(2, 8, n), rng.uniform(0, 6, n)) * rng.uniform(0.6, 1.4, (n, 2, 1))
    s2 = shapes_from_scale_angle(rng.uniform(2, 8, m), rng.uniform(0, 6, m)) * rng.uniform(0.6, 1.4, (m, 2, 1))
    D = np.linalg.norm(desc1[:, None].astype(np.float64) - desc2[None].astype(np.float64), axis=2)
    return desc1, desc2, D, k1, k2, s1, s2


def _borderline(cfg, k1, k2, s1, s2, tol=0.01):
    """True when some keypoint pair has an overlap error within tol of t_o (quadrature vs polygons)."""
    if cfg.t_o is None or cfg.t_o_kind != "overlap":
        return False
    for pts, shp in ((k1, s1), (k2, s2)):
        for a in range(len(pts)):
            for b in range(a + 1, len(pts)):
                if abs(ref_overlap_error(pts[a], shp[a], pts[b], shp[b]) - cfg.t_o) < tol:
                    return True
    return False


FGINN_CASES = [
    BlobConfig(f=3, prefilter="cup", f_prime=2, ratio="D+", t_o=10.0, t_o_kind="px", combine="harmonic"),
    BlobConfig(f=2, prefilter="cap", f_prime=1, ratio="D>=", t_o=5.0, t_o_kind="px", combine="a"),
    BlobConfig(f="omega", f_prime=3, ratio="D+>=", t_o=12.0, t_o_kind="px", combine="min"),
    BlobConfig(f=3, prefilter="cup", f_prime=3, ratio="D+", t_o=0.75, t_o_kind="overlap", combine="max"),
    BlobConfig(f=5, prefilter="cap", f_prime=2, ratio="D>=", t_o=0.5, t_o_kind="overlap", combine="b"),
    BlobConfig(f=1, prefilter="cup", f_prime=2, ratio="D+>=", t_o=0.99, t_o_kind="overlap", combine="harmonic"),
]


@pytest.mark.parametrize("cfg", FGINN_CASES, ids=lambda c: c.label)
def test_fginn_against_brute_force(cfg):
    checked = 0
    for seed in range(40):
        rng = np.random.default_rng(1000 + seed)
        n, m = int(rng.integers(3, 9)), int(rng.integers(3, 9))
        desc1, desc2, D, k1, k2, s1, s2 = _random_case(seed, n, m)
        if _borderline(cfg, k1, k2, s1, s2):
            continue
        ref = reference_blob(D, cfg, k1, k2, s1, s2)
        for source in ("desc", "dist"):
            kw = dict(desc1=desc1, desc2=desc2) if source == "desc" else dict(distances=D)
            out = blob_matching(**kw, kpts1=k1, kpts2=k2, shapes1=s1, shapes2=s2, **cfg.kwargs())
            got = dict(zip(map(tuple, out.matches.tolist()), out.scores))
            assert set(got) == set(ref), (seed, source)
            for e in ref:
                assert got[e] == pytest.approx(ref[e], rel=1e-5, abs=1e-6), (seed, source, e)
        checked += 1
        if checked == 8:
            break
    assert checked == 8


def test_fallback_beyond_the_sorted_lists_matches_brute_force():
    # Many keypoints close together: FGINN excludes all of the T best entries, forcing the whole-row scan.
    rng = np.random.default_rng(5)
    n, m = 60, 70
    desc1 = rng.random((n, 16)).astype(np.float32)
    desc2 = rng.random((m, 16)).astype(np.float32)
    k1 = rng.uniform(0, 30, (n, 2))
    k2 = rng.uniform(0, 30, (m, 2))
    D = np.linalg.norm(desc1[:, None].astype(np.float64) - desc2[None], axis=2)
    cfg = BlobConfig(f=2, prefilter="cup", f_prime=2, ratio="D>=", t_o=25.0, combine="harmonic")
    ctx = BlobContext(desc1, desc2, kpts1=k1, kpts2=k2, depth=2)
    assert not ctx.rows.complete and ctx.rows.idx.shape[1] < m
    out = blob_matching(desc1, desc2, kpts1=k1, kpts2=k2, **cfg.kwargs())
    ref = reference_blob(D, cfg, k1, k2)
    got = dict(zip(map(tuple, out.matches.tolist()), out.scores))
    assert set(got) == set(ref)
    assert np.allclose([got[e] for e in ref], [ref[e] for e in ref], rtol=1e-5, atol=1e-6)


def test_large_descriptor_path_matches_dense_reference():
    # Blocks, group thresholds and the packed-key sort against a plain dense computation.
    rng = np.random.default_rng(3)
    desc1 = rng.random((700, 32)).astype(np.float32)
    desc2 = rng.random((650, 32)).astype(np.float32)
    k1, k2 = rng.uniform(0, 500, (700, 2)), rng.uniform(0, 500, (650, 2))
    D = np.sqrt(np.maximum(
        (desc1.astype(np.float64) ** 2).sum(1)[:, None] + (desc2.astype(np.float64) ** 2).sum(1)[None]
        - 2 * desc1.astype(np.float64) @ desc2.T.astype(np.float64), 0))
    for name in ("paper-best", "baseline"):
        cfg = BLOB_PRESETS[name].kwargs()
        a = blob_matching(desc1, desc2, kpts1=k1, kpts2=k2, **cfg)
        b = blob_matching(distances=D, kpts1=k1, kpts2=k2, **cfg)
        assert {tuple(x) for x in a.matches.tolist()} == {tuple(x) for x in b.matches.tolist()}
        assert np.allclose(np.sort(a.scores), np.sort(b.scores), atol=1e-4)


# -- properties ----------------------------------------------------------------------------------------
def unique_matrix(min_side=1, max_side=9):
    return st.tuples(st.integers(min_side, max_side), st.integers(min_side, max_side), st.integers(0, 2**31)).map(
        lambda t: np.random.default_rng(t[2]).permutation(t[0] * t[1]).reshape(t[0], t[1]) / (t[0] * t[1]) + 0.01
    )


def mutual_nn(D):
    return {(i, int(np.argmin(D[i]))) for i in range(D.shape[0]) if np.argmin(D[:, np.argmin(D[i])]) == i}


def pairs(out):
    return {tuple(x) for x in out.matches.tolist()}


@given(unique_matrix())
def test_mnn_subset_of_gnn_and_gnn_size(D):
    gnn = pairs(blob_matching(distances=D, f="omega", f_prime=1, t_o=None))
    assert mutual_nn(D) <= gnn
    assert len(gnn) == min(D.shape)


@given(unique_matrix(), st.integers(1, 6))
def test_f1_cap_is_mutual_nn_for_any_f_prime(D, f_prime):
    assert pairs(blob_matching(distances=D, f=1, prefilter="cap", f_prime=f_prime, t_o=None)) == mutual_nn(D)
    # f = 1∪, f' = 1 always contains S_mNN and stays one-to-one.
    cup = blob_matching(distances=D, f=1, prefilter="cup", f_prime=1, t_o=None)
    assert mutual_nn(D) <= pairs(cup)
    assert len(set(cup.matches[:, 0])) == len(set(cup.matches[:, 1])) == len(cup)


def test_f1_cup_is_not_always_mutual_nn():
    # The caption of Fig. 1a says rows 3 and 4 (f = 1∩ and f = 1∪ with f' = 1) always give S_mNN. For
    # 1∩ that holds; for 1∪ it only holds on the toy matrix: here (0, 1) is row 0's best but column 1
    # prefers row 1, which the greedy already used for column 0.
    D = np.array([[0.76, 0.51], [0.01, 0.26]])
    assert mutual_nn(D) == {(1, 0)}
    assert pairs(blob_matching(distances=D, f=1, prefilter="cup", f_prime=1, t_o=None)) == {(1, 0), (0, 1)}


@given(unique_matrix(), st.sampled_from([1, 2, 3, "omega"]), st.sampled_from(["cap", "cup"]), st.integers(1, 5))
def test_caps_maximality_and_growth(D, f, prefilter, f_prime):
    out = blob_matching(distances=D, f=f, prefilter=prefilter, f_prime=f_prime, t_o=None)
    more = blob_matching(distances=D, f=f, prefilter=prefilter, f_prime=f_prime + 1, t_o=None)
    G = out.matches
    # No row or column more than f' times.
    assert np.bincount(G[:, 0]).max(initial=0) <= f_prime
    assert np.bincount(G[:, 1]).max(initial=0) <= f_prime
    # Mutual NN always survive; raising f' never shrinks G.
    assert mutual_nn(D) <= pairs(out) <= pairs(blob_matching(distances=D, f="omega", f_prime=f_prime, t_o=None)) | pairs(out)
    assert len(more) >= len(out)
    # Greedy maximality: every pre-filtered entry left out has a saturated row or column.
    ctx = BlobContext(distances=D, depth=max(f_prime, 1 if f == "omega" else f))
    rows_full = np.bincount(G[:, 0], minlength=D.shape[0]) >= f_prime
    cols_full = np.bincount(G[:, 1], minlength=D.shape[1]) >= f_prime
    big = ctx.candidates(f, prefilter, 10**6)[0]  # f' = inf: the pre-filtered set F itself
    for i, j in big.tolist():
        if (i, j) not in pairs(out):
            assert rows_full[i] or cols_full[j]


def test_raising_f_prime_can_drop_a_candidate():
    # "Raising f' never removes a candidate" does not hold in general: with f' = 2 row 3 is filled by
    # (3, 1) and (3, 2), whose columns were taken at f' = 1, so (3, 3) is no longer accepted.
    D = np.array([[0.1, 9, 9], [9, 0.2, 9], [0.3, 0.4, 0.5]])
    one = pairs(blob_matching(distances=D, f="omega", f_prime=1, t_o=None))
    two = pairs(blob_matching(distances=D, f="omega", f_prime=2, t_o=None))
    assert (2, 2) in one and (2, 2) not in two
    assert len(two) > len(one)


@given(
    st.integers(1, 8), st.integers(1, 8), st.integers(0, 2**31),
    st.sampled_from(["D>=", "D+>=", "D+"]), st.sampled_from(["a", "b", "min", "max", "harmonic"]),
    st.sampled_from([None, 3.0, 0.5]),
)
def test_ratios_lie_in_unit_interval(n, m, seed, ratio, combine, t_o):
    desc1, desc2, D, k1, k2, s1, s2 = _random_case(seed, n, m)
    kind = "overlap" if t_o == 0.5 else "px"
    out = blob_matching(desc1, desc2, kpts1=k1, kpts2=k2, shapes1=s1, shapes2=s2, f=3, f_prime=3,
                        ratio=ratio, t_o=t_o, t_o_kind=kind, combine=combine)
    assert np.all((out.scores >= 0) & (out.scores <= 1))
    assert np.all(np.diff(out.scores) >= 0)


@given(arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(1, 6)), elements=st.sampled_from([0.0, 1.0, 2.0])))
def test_ties_are_deterministic_and_order_by_row_then_column(D):
    a = blob_matching(distances=D, f=2, f_prime=2, t_o=None)
    b = blob_matching(distances=D.copy(), f=2, f_prime=2, t_o=None)
    assert np.array_equal(a.matches, b.matches) and np.array_equal(a.scores, b.scores)
    keys = list(zip(a.scores, a.matches[:, 0], a.matches[:, 1]))
    assert keys == sorted(keys)


# -- tiny and bad input ---------------------------------------------------------------------------------
@pytest.mark.parametrize("n, m", [(0, 0), (0, 3), (3, 0), (1, 1), (1, 2), (2, 1), (2, 2)])
def test_tiny_inputs(n, m):
    rng = np.random.default_rng(0)
    desc1, desc2 = rng.random((n, 4)), rng.random((m, 4))
    k1, k2 = rng.random((n, 2)) * 100, rng.random((m, 2)) * 100
    out = blob_matching(desc1, desc2, kpts1=k1, kpts2=k2, **BLOB_PRESETS["paper-best"].kwargs())
    base = blob_matching(desc1, desc2, **BLOB_PRESETS["baseline"].kwargs())
    assert out.matches.shape[1] == 2 and out.matches.dtype == np.int64 and out.scores.dtype == np.float64
    if n == 0 or m == 0:
        assert len(out) == 0 and len(base) == 0
    else:
        assert len(base) == min(n, m)
        assert len(out) >= min(n, m)
    if (n, m) == (1, 1):
        assert out.matches.tolist() == [[0, 0]] and out.scores.tolist() == [0.0]  # no second entry


def test_bad_input_names_the_argument():
    d = np.ones((3, 4))
    with pytest.raises(ValueError, match="desc1"):
        blob_matching(np.full((3, 4), np.nan), d, t_o=None)
    with pytest.raises(ValueError, match="desc2"):
        blob_matching(d, np.array([[np.inf] * 4]), t_o=None)
    with pytest.raises(ValueError, match="same dimension"):
        blob_matching(d, np.ones((3, 5)), t_o=None)
    with pytest.raises(ValueError, match="distances"):
        blob_matching(distances=np.ones(5), t_o=None)
    with pytest.raises(ValueError, match="distances"):
        blob_matching(distances=-np.ones((2, 2)), t_o=None)
    with pytest.raises(ValueError, match="kpts1"):
        blob_matching(distances=np.ones((3, 2)), kpts1=np.zeros((2, 2)), kpts2=np.zeros((2, 2)))
    with pytest.raises(ValueError, match="kpts1 and kpts2 are required"):
        blob_matching(d, d)
    with pytest.raises(ValueError, match="shapes1 and shapes2"):
        blob_matching(d, d, kpts1=np.zeros((3, 2)), kpts2=np.zeros((3, 2)), t_o=0.5, t_o_kind="overlap")
    with pytest.raises(ValueError, match="shapes2"):
        blob_matching(d, d, kpts1=np.zeros((3, 2)), kpts2=np.zeros((3, 2)), shapes1=np.ones(3),
                      shapes2=np.ones((2, 2, 2)), t_o=0.5, t_o_kind="overlap")
    with pytest.raises(ValueError, match="t_o"):
        blob_matching(d, d, kpts1=np.zeros((3, 2)), kpts2=np.zeros((3, 2)), t_o=50, t_o_kind="overlap")
    for bad in (dict(f=0), dict(f="all"), dict(f_prime=0), dict(ratio="D"), dict(combine="mean"),
                dict(prefilter="and"), dict(t_o=-1.0), dict(t_o_kind="mm")):
        with pytest.raises(ValueError, match=next(iter(bad))):
            blob_matching(d, d, kpts1=np.zeros((3, 2)), kpts2=np.zeros((3, 2)), **bad)
    with pytest.raises(ValueError, match="either"):
        blob_matching(d, d, distances=np.ones((3, 3)), t_o=None)


def test_omega_fails_fast_stating_memory():
    d = np.ones((300, 8), np.float32)
    with pytest.raises(MemoryError, match=r"GiB"):
        blob_matching(d, d, f="omega", t_o=None, max_dense_bytes=1000)


def test_presets_and_grid():
    assert BLOB_PRESETS["paper-best"] == BlobConfig(f=10, prefilter="cup", f_prime=5, ratio="D+", t_o=10.0,
                                                   t_o_kind="px", combine="harmonic")
    assert BLOB_PRESETS["baseline"] == BlobConfig(f="omega", f_prime=1, ratio="D>=", t_o=None, combine="a")
    grid = blob_grid()
    assert len(grid) == 9 * 3 * 6 * 3 * 5 == 2430
    assert len(set(grid)) == 2430
    assert {c.f_label for c in grid} == {"1∪", "1∩", "3∪", "3∩", "5∪", "5∩", "10∪", "10∩", "Ω"}
    assert {c.t_o_label for c in grid} == {"∞", "50%", "75%", "99%", "5px", "10px"}
    assert BlobConfig(t_o=math.inf).t_o is None


def test_overlap_error_against_polygons():
    rng = np.random.default_rng(1)
    P = 200
    c1 = rng.uniform(0, 20, (P, 2))
    c2 = c1 + rng.normal(0, 6, (P, 2))
    A1, A2 = rng.normal(0, 4, (P, 2, 2)), rng.normal(0, 4, (P, 2, 2))
    err = ellipse_overlap_error(c1, A1, c2, A2)
    ref = np.array([ref_overlap_error(c1[k], A1[k], c2[k], A2[k], k=2048) for k in range(P)])
    # The documented bound is 0.01; the equal-area 32-gons do far better.
    assert np.max(np.abs(err - ref)) < 1e-3
    assert (err[np.abs(err - 1) > 1e-12] < 1).all() and (err >= 0).all()
    same = ellipse_overlap_error(c1, A1, c1, A1)
    assert np.allclose(same, 0, atol=1e-9)


def _circle_pairs(P, seed):
    """Circular patches (radii 1-11, any angle) at centres up to 2000 px, the second near the first; the first
    300 pairs at external tangency, internal tangency and on the same centre."""
    from ctxmatch_lib.blob import shapes_from_scale_angle

    rng = np.random.default_rng(seed)
    r1, r2 = rng.uniform(1, 11, P), rng.uniform(1, 11, P)
    c1 = rng.uniform(0, 2000, (P, 2))
    c2 = c1 + rng.normal(0, 6, (P, 2))
    c2[:100, 0], c2[:100, 1] = c1[:100, 0] + r1[:100] + r2[:100], c1[:100, 1]
    c2[100:200, 0], c2[100:200, 1] = c1[100:200, 0] + np.abs(r1 - r2)[100:200], c1[100:200, 1]
    c2[200:300] = c1[200:300]
    return (c1, shapes_from_scale_angle(r1, rng.uniform(0, 7, P)), c2,
            shapes_from_scale_angle(r2, rng.uniform(0, 7, P)))


def test_circle_overlap_bounds_hold_and_are_tight():
    from ctxmatch_lib.blob.overlap import circle_overlap_bounds

    c1, A1, c2, A2 = _circle_pairs(20000, 3)
    err = ellipse_overlap_error(c1, A1, c2, A2)
    lo, hi = circle_overlap_bounds(c1, A1, c2, A2)
    assert ((lo <= err) & (err <= hi)).all()
    r1, r2 = np.hypot(A1[:, 0, 0], A1[:, 1, 0]), np.hypot(A2[:, 0, 0], A2[:, 1, 0])
    far = np.sum((c1 - c2) ** 2, axis=1) >= (r1 + r2) ** 2 * (1 + 1e-9)
    assert (err[far] == 1).all() and (lo[far] == 1).all() and far.sum() > 100  # decided exactly, as 1
    assert (hi - lo).max() < 0.02
    for t_o in (0.5, 0.75, 0.99):  # where FGINN must still compute the error: under 1 % of the near pairs
        assert ((lo <= t_o) & (t_o < hi)).sum() < 0.01 * (~far).sum()
    # ellipses that are not circles are not bounded
    A3 = A1 * np.array([1.0, 2.0])[None, :, None]
    lo3, hi3 = circle_overlap_bounds(c1[:500], A3[:500], c2[:500], A2[:500])
    near3 = ellipse_overlap_error(c1[:500], A3[:500], c2[:500], A2[:500]) < 1
    assert (lo3[near3] == 0).all() and (hi3[near3] == 1).all()


@pytest.mark.parametrize("t_o", [0.5, 0.75, 0.99])
def test_overlap_near_decides_as_the_errors(t_o):
    """FGINN by overlap's test on circles (bounds), ellipses and disjoint pairs equals ``error <= t_o``."""
    c1, A1, c2, A2 = _circle_pairs(3000, 4)
    A1[::3] = A1[::3] * np.array([1.0, 1.7])[None, :, None]  # every third patch an ellipse
    pts, shapes = np.vstack([c1, c2]), np.vstack([A1, A2])
    ctx = BlobContext(distances=np.ones((2, 2)), kpts1=pts[:2], kpts2=pts, shapes2=shapes)
    other, cand = np.arange(3000), np.arange(3000, 6000)
    calls = []
    errors = ctx.overlap_errors
    ctx.overlap_errors = lambda img, o, c: calls.append(len(o)) or errors(img, o, c)
    near = ctx.overlap_near(1, other, cand, t_o)
    assert np.array_equal(near, ellipse_overlap_error(c1, A1, c2, A2) <= t_o)
    assert sum(calls) < 1500  # the ellipse pairs and the few circles near t_o


def test_radii_are_validated_like_shapes():
    d = np.ones((3, 8), np.float32)
    kw = dict(kpts1=np.zeros((3, 2)), kpts2=np.zeros((3, 2)), t_o=0.5, t_o_kind="overlap")
    with pytest.raises(ValueError, match="shapes1 holds degenerate"):
        blob_matching(d, d, shapes1=np.array([1.0, 0.0, 2.0]), shapes2=np.ones(3), **kw)
    with pytest.raises(ValueError, match="shapes2 contains NaN"):
        blob_matching(d, d, shapes1=np.ones(3), shapes2=np.array([1.0, np.nan, 2.0]), **kw)
    with pytest.raises(ValueError, match="shapes1 holds degenerate"):
        blob_matching(d, d, shapes1=np.zeros((3, 2, 2)), shapes2=np.ones(3), **kw)
    # a negative radius is the same disk (r R(0) has determinant r²), as it always was
    assert len(blob_matching(d, d, shapes1=-np.ones(3), shapes2=np.ones(3), **kw)) > 0


@pytest.mark.parametrize("f_prime", [1, 2, 3])
def test_omega_heap_greedy_matches_a_full_sort(f_prime):
    # Rows run past their sorted lists here, which exercises the vectorised continuation of the heap.
    rng = np.random.default_rng(f_prime)
    D = rng.integers(0, 50, (300, 250)).astype(np.float64)  # many ties
    out = blob_matching(distances=D, f="omega", f_prime=f_prime, t_o=None)
    i, j = np.indices(D.shape)
    order = np.lexsort((j.ravel(), i.ravel(), D.ravel()))
    rc, cc, ref = np.zeros(300, int), np.zeros(250, int), set()
    for k in order:
        a, b = divmod(int(k), 250)
        if rc[a] < f_prime and cc[b] < f_prime:
            rc[a] += 1
            cc[b] += 1
            ref.add((a, b))
    assert pairs(out) == ref


def test_largest_singular_value_closed_form():
    """The bounding radius of the overlap error's ellipses against LAPACK's 2-norm (degenerate shapes too)."""
    from ctxmatch_lib.blob.overlap import _largest_singular_value

    rng = np.random.default_rng(8)
    A = rng.normal(size=(5000, 2, 2)) * rng.uniform(0.01, 100, (5000, 1, 1))
    A[:3] = [[[0, 0], [0, 0]], [[2, 4], [1, 2]], [[3, 0], [0, -3]]]  # zero, rank one, reflection
    np.testing.assert_allclose(_largest_singular_value(A), np.linalg.norm(A, ord=2, axis=(1, 2)),
                               rtol=1e-14, atol=1e-300)


@pytest.mark.parametrize("combine", ["a", "b"])
def test_one_reference_combination_equals_the_two_sided_one(combine):
    """W = a or b computes one reference's second best only; the scores are those of both computed."""
    from ctxmatch_lib.blob import combine_ratios, rank_candidates
    from ctxmatch_lib.blob.core import _sorted

    rng = np.random.default_rng(11)
    d1, d2 = rng.random((120, 16)).astype(np.float32), rng.random((90, 16)).astype(np.float32)
    k1, k2 = rng.uniform(0, 100, (120, 2)), rng.uniform(0, 100, (90, 2))
    for cfg in [BlobConfig(f=4, f_prime=2, ratio="D>=", t_o=8.0, combine=combine),
                BlobConfig(f="omega", f_prime=1, ratio="D+", t_o=None, combine=combine)]:
        ctx = BlobContext(d1, d2, kpts1=k1, kpts2=k2)
        got = blob_matching(d1, d2, kpts1=k1, kpts2=k2, **cfg.kwargs())
        m, d = ctx.candidates(cfg.f, cfg.prefilter, cfg.f_prime)
        both = rank_candidates(ctx, m, d, ratio=cfg.ratio, t_o=cfg.t_o, t_o_kind=cfg.t_o_kind)
        ref = _sorted(m, combine_ratios(*both, combine), cfg.ratio)
        np.testing.assert_array_equal(got.matches, ref.matches)
        np.testing.assert_array_equal(got.scores, ref.scores)
