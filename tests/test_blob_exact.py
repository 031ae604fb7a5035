"""Blob matching's decisions do not depend on the BLAS kernel and equal a dense float64 reference."""

import json
import os
import platform
import subprocess
import sys

import numpy as np
import pytest

from ctxmatch_lib.blob import (BLOB_PRESETS, BlobConfig, BlobContext, blob_matching, ellipse_overlap_error,
                               shapes_from_scale_angle)
from ctxmatch_lib.blob._kernels import outside_px
from ctxmatch_lib.blob.core import match_context

SETUPS = [BLOB_PRESETS["paper-best"], BLOB_PRESETS["baseline"],
          BlobConfig(f=3, prefilter="cap", f_prime=3, ratio="D+>=", t_o=5.0, combine="max"),
          BlobConfig(f="omega", f_prime=2, ratio="D>=", t_o=8.0, combine="min")]


def planted(seed, n, m, d=32, ties=False):
    """RootSIFT-like unit descriptors, half of image 2 noisy copies of image 1; ``ties``: small integers."""
    rng = np.random.default_rng(seed)
    if ties:
        d1 = rng.integers(0, 3, (n, d)).astype(np.float32)
        d2 = np.vstack([d1[: m // 3], rng.integers(0, 3, (m - m // 3, d))]).astype(np.float32)
    else:
        d1 = np.abs(rng.normal(size=(n, d))).astype(np.float32)
        d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
        d2 = np.abs(rng.normal(size=(m, d))).astype(np.float32)
        k = min(n, m) // 2
        d2[:k] = d1[rng.choice(n, k, replace=False)] + 0.2 * np.abs(rng.normal(size=(k, d))).astype(np.float32) / d
        d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    k1, k2 = rng.uniform(0, 60, (n, 2)), rng.uniform(0, 60, (m, 2))
    return d1, d2, k1, k2


def dense_reference(d1, d2, k1, k2, cfg):
    """Blob matching on the dense float64 distance matrix (differences squared and summed in float64)."""
    D = np.sqrt(((d1[:, None, :].astype(np.float64) - d2[None].astype(np.float64)) ** 2).sum(-1))
    return blob_matching(distances=D, kpts1=k1, kpts2=k2, **cfg.kwargs())


@pytest.mark.parametrize("cfg", SETUPS, ids=lambda c: c.label)
@pytest.mark.parametrize("seed, n, m, ties", [(0, 300, 260, False), (1, 90, 400, False), (2, 250, 200, True)])
def test_descriptors_equal_the_dense_float64_reference(cfg, seed, n, m, ties):
    d1, d2, k1, k2 = planted(seed, n, m, ties=ties)
    got = blob_matching(d1, d2, kpts1=k1, kpts2=k2, **cfg.kwargs())
    ref = dense_reference(d1, d2, k1, k2, cfg)
    assert np.array_equal(got.matches, ref.matches)
    # Distances agree to the last bits only: the reference sums in numpy's order, the kernel in its own.
    assert np.allclose(got.scores, ref.scores, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("tile", [(32, 48), (7, 20), (150, 130)])
@pytest.mark.parametrize("cfg", SETUPS[:2], ids=lambda c: c.label)
def test_many_small_tiles_give_the_reference(tile, cfg):
    """Tiles smaller than D, with partial ones at the edges: each accumulates into the buffer the scan of the
    one before left zeroed (``_blas.accumulate_product``), so any tile shape gives the same lists."""

    class Tiled(BlobContext):
        pass

    Tiled.tile, Tiled.product = tile, "tiles"
    d1, d2, k1, k2 = planted(4, 150, 130)
    dense = cfg.f == "omega"
    depth = cfg.f_prime if dense else max(cfg.f_prime, cfg.f)
    ctx = Tiled(d1, d2, kpts1=k1, kpts2=k2, depth=depth, margin=2, keep_dense=dense)
    got = match_context(ctx, cfg)
    ref = dense_reference(d1, d2, k1, k2, cfg)
    assert np.array_equal(got.matches, ref.matches)
    assert np.allclose(got.scores, ref.scores, rtol=1e-12, atol=1e-14)


def _with_product(product):
    class Context(BlobContext):
        pass

    Context.product = product
    return Context


@pytest.mark.parametrize("cfg", SETUPS, ids=lambda c: c.label)
@pytest.mark.parametrize("seed, n, m, d, ties, margin", [
    (0, 1, 1, 8, False, None), (1, 2, 70, 8, False, None), (2, 70, 3, 16, False, None), (3, 131, 67, 32, False, 2),
    (4, 257, 600, 32, True, None), (5, 600, 1100, 128, False, 22), (6, 400, 520, 64, True, 22),
    (7, 1100, 300, 16, True, None)])
def test_the_fused_product_keeps_the_tiles_lists(cfg, seed, n, m, d, ties, margin):
    """The pass with the product in registers (``product="fused"``) keeps the lists of the BLAS tiles, bit for
    bit, and so the same candidates and scores: ragged row groups and column blocks, fewer rows than the
    fresh columns' start (FRESH_ROWS), lines of more than 16 entries (margin 22), ties, f = Ω's codes (over
    more rows than a ROW_BLOCK: the columns' buckets then outlive a chunk's sweep)."""
    d1, d2, k1, k2 = planted(seed, n, m, d=d, ties=ties)
    dense = cfg.f == "omega"
    depth = cfg.f_prime if dense else max(cfg.f_prime, cfg.f)
    kw = dict(kpts1=k1, kpts2=k2, depth=depth, margin=margin, keep_dense=dense, columns=not dense)
    tiles, fused = _with_product("tiles")(d1, d2, **kw), _with_product("fused")(d1, d2, **kw)
    for a, b in ((tiles.rows, fused.rows), (tiles.cols, fused.cols)):
        assert (a is None) == (b is None)
        assert a is None or (np.array_equal(a.idx, b.idx) and np.array_equal(a.val, b.val))
    if dense:
        # f = Ω's 16-bit codes of the float32 product only propose (the certified bound holds for any summation
        # order): they equal the tiles' where the BLAS kernel sums as fma16 does (OpenBLAS's SkylakeX kernel)
        # and differ by one code where another kernel rounds a float32 sum the other way (Haswell / Zen); the
        # candidates and scores below are the same either way.
        gap = np.abs(tiles._approx.astype(np.int64) - fused._approx.astype(np.int64))
        assert gap.max(initial=0) <= 1 and (gap > 0).mean() < 1e-3
    if not dense or cfg.combine == "a":  # a context without columns serves W = a only
        x, y = match_context(tiles, cfg), match_context(fused, cfg)
        assert np.array_equal(x.matches, y.matches) and np.array_equal(x.scores, y.scores)


def test_the_product_is_named_and_checked():
    """``product="auto"`` is the fused pass where the CPU has AVX-512 and numba compiles for it, the tiles
    elsewhere; an unknown value is refused by name."""
    from ctxmatch_lib.blob import _fused_kernels

    assert BlobContext.product == "auto"
    d1, d2, *_ = planted(0, 20, 30)
    with pytest.raises(ValueError, match="product"):
        _with_product("gemm")(d1, d2)
    _fused_kernels.fused_product_fast.cache_clear()
    try:
        import numba

        saved, numba.config.CPU_NAME = numba.config.CPU_NAME, "generic"
        assert not _fused_kernels.fused_product_fast()
    finally:
        numba.config.CPU_NAME = saved
        _fused_kernels.fused_product_fast.cache_clear()


def test_a_cpu_llvm_cannot_describe_keeps_the_tiles(monkeypatch):
    from llvmlite import binding

    from ctxmatch_lib.blob import _fused_kernels

    def cannot_tell():
        raise RuntimeError("no host CPU features")

    monkeypatch.setattr(binding, "get_host_cpu_features", cannot_tell)
    _fused_kernels.fused_product_fast.cache_clear()
    try:
        assert not _fused_kernels.fused_product_fast()
    finally:
        _fused_kernels.fused_product_fast.cache_clear()


def test_pack_columns_layout():
    from ctxmatch_lib.blob._fused_kernels import NR, pack_columns

    B = np.arange(70 * 3, dtype=np.float32).reshape(70, 3)
    Bp, n2p = pack_columns(B, np.arange(70, dtype=np.float32))
    assert Bp.shape == (2, 3 * NR) and n2p.shape == (2 * NR,)
    for j in (0, 5, 63, 64, 69):
        assert [Bp[j // NR, k * NR + j % NR] for k in range(3)] == B[j].tolist()
    assert not Bp[1, [k * NR + q for k in range(3) for q in range(6, NR)]].any()
    assert np.array_equal(n2p[:70], np.arange(70)) and np.all(n2p[70:] == np.inf)
    assert Bp.ctypes.data % 64 == 0  # 16-lane loads never straddle two cache lines


@pytest.mark.parametrize("precomputed", [False, True])
def test_a_context_without_columns_serves_the_baseline_and_refuses_the_rest(precomputed):
    """f = Ω with W = a reads rows only: ``columns=False`` (what blob_matching builds for it) gives the same
    matches and scores; the pre-filter and image 2's ratio, which need the columns, say so."""
    d1, d2, k1, k2 = planted(6, 160, 140)
    cfg = BLOB_PRESETS["baseline"]
    D = np.sqrt(((d1[:, None, :].astype(np.float64) - d2[None]) ** 2).sum(-1))

    def make(columns):
        if precomputed:
            return BlobContext(distances=D, depth=1, margin=8, columns=columns)
        return BlobContext(d1, d2, depth=1, margin=8, keep_dense=True, columns=columns)

    rows_only, both = make(False), make(True)
    assert rows_only.cols is None and np.array_equal(rows_only.rows.idx, both.rows.idx)
    a, b = match_context(rows_only, cfg), match_context(both, cfg)
    assert np.array_equal(a.matches, b.matches) and np.array_equal(a.scores, b.scores) and len(a) == 140
    with pytest.raises(ValueError, match="columns=False"):
        rows_only.candidates(1, "cup", 1)
    with pytest.raises(ValueError, match="columns=False"):
        rows_only.second_best(1, a.matches[:, 1], a.matches[:, 0], np.asarray(a.scores), geq=True, t_o=None)


def test_scan_tile_leaves_the_tile_zeroed():
    from ctxmatch_lib.blob import _kernels

    rng = np.random.default_rng(5)
    A, B = rng.random((40, 8), np.float32), rng.random((70, 8), np.float32)
    G = A @ B.T
    n1 = (A.astype(np.float64) ** 2).sum(1).astype(np.float32)
    n2 = (B.astype(np.float64) ** 2).sum(1).astype(np.float32)
    V = (n1[:, None] + n2[None]) - (G + G)
    rv, ri = np.full((40, 16), np.inf, np.float32), np.zeros((40, 16), np.int64)
    cv, ci = np.full((70, 16), np.inf, np.float32), np.zeros((70, 16), np.int64)
    rthr, cthr = np.full(40, np.inf, np.float32), np.full(70, np.inf, np.float32)
    _kernels.scan_tile(G, 0, 0, n1, n2, rv, ri, rthr, cv, ci, cthr, 6, 6, np.empty((1, 1), np.uint16), False,
                       np.float32(0), np.float32(1))
    assert not G.any()
    np.testing.assert_array_equal(rv[:, :6], np.sort(V, axis=1)[:, :6])
    np.testing.assert_array_equal(cv[:, :6], np.sort(V, axis=0)[:6].T)


def test_sorted_lists_hold_the_exact_best_entries_with_ties_by_index():
    d1, d2, _, _ = planted(3, 200, 180, ties=True)
    ctx = BlobContext(d1, d2, depth=5)
    D = np.sqrt(((d1[:, None, :].astype(np.float64) - d2[None]) ** 2).sum(-1))
    T = ctx.rows.idx.shape[1]
    for i in range(len(d1)):
        order = np.lexsort((np.arange(D.shape[1]), D[i]))[:T]
        assert np.array_equal(ctx.rows.idx[i], order)
    assert np.allclose(ctx.rows.val, np.take_along_axis(D, ctx.rows.idx, 1), rtol=1e-12)


def test_empty_inputs():
    d = np.zeros((0, 8), np.float32)
    e = np.ones((3, 8), np.float32)
    for a, b in ((d, e), (e, d), (d, d)):
        out = blob_matching(a, b, t_o=None)
        assert out.matches.shape == (0, 2) and out.scores.shape == (0,)


CHILD = r"""
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from test_blob_exact import SETUPS, planted
from ctxmatch_lib.blob import BlobContext, blob_matching
BlobContext.product = sys.argv[2]
out = []
for seed, n, m, ties in [(0, 700, 650, False), (2, 300, 280, True)]:
    d1, d2, k1, k2 = planted(seed, n, m, d=128, ties=ties)
    for cfg in SETUPS:
        r = blob_matching(d1, d2, kpts1=k1, kpts2=k2, **cfg.kwargs())
        out.append([r.matches.tolist(), [float(s).hex() for s in r.scores]])
print(json.dumps(out))
"""


@pytest.mark.slow
@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="OPENBLAS_CORETYPE names x86-64 kernels")
def test_outputs_identical_under_every_openblas_kernel():
    """The same candidates and scores, bit for bit, whichever SIMD kernels OpenBLAS picks, through the BLAS
    tiles or the fused product (which uses BLAS only for the rare look-ups beyond the lists)."""
    here = os.path.dirname(__file__)
    results = {}
    for core in (None, "Haswell", "Nehalem", "Prescott"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
        env.pop("OPENBLAS_CORETYPE", None)
        if core:
            env["OPENBLAS_CORETYPE"] = core
        for product in ("tiles", "fused"):
            proc = subprocess.run([sys.executable, "-c", CHILD, here, product], env=env, capture_output=True,
                                  text=True, check=True)
            results[core or "default", product] = json.loads(proc.stdout)
    first = results["default", "tiles"]
    for core, res in results.items():
        assert res == first, core


class _ShortLists(BlobContext):
    margin = 0  # lists of `depth` entries only: most second-best searches fall back to whole lines


@pytest.mark.parametrize("ties", [False, True])
@pytest.mark.parametrize("t_o, kind", [(None, "px"), (12.0, "px"), (0.6, "overlap")])
def test_whole_line_second_best_equals_the_dense_reference(ties, t_o, kind):
    """The fallback beyond the sorted lists (float32 rows propose, exact distances decide) on every line."""
    d1, d2, k1, k2 = planted(4, 220, 190, ties=ties)
    rng = np.random.default_rng(5)
    s1, s2 = rng.uniform(3, 15, len(d1)), rng.uniform(3, 15, len(d2))
    kw = dict(kpts1=k1, kpts2=k2, shapes1=np.einsum("n,ij->nij", s1, np.eye(2)),
              shapes2=np.einsum("n,ij->nij", s2, np.eye(2)), depth=2)
    D = np.sqrt(((d1[:, None, :].astype(np.float64) - d2[None].astype(np.float64)) ** 2).sum(-1))
    ctx, ref = _ShortLists(d1, d2, **kw), _ShortLists(distances=D, **kw)
    matches, dist = ctx.candidates(2, "cup", 2)
    i, j = matches[:, 0], matches[:, 1]
    pts, shapes = (k1, k2), (kw["shapes1"], kw["shapes2"])
    for geq in (False, True):
        for side, (a, b) in enumerate(((i, j), (j, i))):
            got = ctx.second_best(side, a, b, dist, geq=geq, t_o=t_o, t_o_kind=kind)
            want = ref.second_best(side, a, b, dist, geq=geq, t_o=t_o, t_o_kind=kind)
            # Asked again, the lines come from the context's memo: the same answer.
            assert np.array_equal(ctx.second_best(side, a, b, dist, geq=geq, t_o=t_o, t_o_kind=kind), got)
            # The definition (Eqs. 9, 13-14) on whole lines of D, every exclusion computed.
            lines = D[a] if side == 0 else D.T[a]
            other = np.arange(lines.shape[1])
            allowed = other[None, :] != b[:, None]
            if geq:
                allowed &= lines >= dist[:, None]
            if t_o is not None:
                p, sh = pts[1 - side], shapes[1 - side]
                if kind == "px":
                    allowed &= ((p[None, :, :] - p[b][:, None, :]) ** 2).sum(-1) >= t_o**2
                else:
                    aa, oo = np.broadcast_arrays(b[:, None], other[None, :])
                    err = ellipse_overlap_error(p[aa.ravel()], sh[aa.ravel()], p[oo.ravel()], sh[oo.ravel()])
                    allowed &= err.reshape(aa.shape) > t_o
            brute = np.where(allowed, lines, np.inf).min(axis=1)
            assert np.isinf(brute).sum() < len(brute)
            for res in (got, want):
                assert np.array_equal(np.isinf(res), np.isinf(brute))
                assert np.allclose(res[np.isfinite(res)], brute[np.isfinite(brute)], rtol=1e-12, atol=1e-14)


def test_fginn_by_pixels_keeps_keypoints_t_o_or_farther():
    """FGINN by pixels (Eq. 9), the rule all three second-best searches share: a keypoint closer than
    ``t_o`` to the match is excluded (the match itself too), one exactly ``t_o`` away is kept."""
    pts = np.array([[0.0, 0.0], [3.0, 4.0], [2.9, 4.0], [10.0, 0.0]])  # (x, y) pixels
    got = outside_px(pts, np.array([0, 3]), 5.0**2)
    assert got.tolist() == [[False, True, False, True], [True, True, True, False]]
    assert outside_px(pts, np.empty(0, np.int64), 25.0).shape == (0, 4)


@pytest.mark.parametrize("margin", [-1, 2.5])
def test_margin_must_be_a_non_negative_integer(margin):
    d1, d2, k1, k2 = planted(1, 30, 30)
    with pytest.raises(ValueError, match="margin"):
        BlobContext(d1, d2, kpts1=k1, kpts2=k2, depth=2, margin=margin)


@pytest.mark.parametrize("name", ["paper-best", "paper-best-overlap", "baseline"])
def test_results_do_not_depend_on_the_margin(name):
    """The margin sets how often the second best is looked for beyond the lists, not what it is."""
    d1, d2, k1, k2 = planted(2, 260, 240)
    rng = np.random.default_rng(2)
    kw = dict(kpts1=k1, kpts2=k2, shapes1=shapes_from_scale_angle(rng.uniform(2, 12, len(d1))),
              shapes2=shapes_from_scale_angle(rng.uniform(2, 12, len(d2))))
    cfg = BLOB_PRESETS[name]
    dense = cfg.f == "omega"
    depth = cfg.f_prime if dense else max(cfg.f_prime, cfg.f)
    outs = [match_context(BlobContext(d1, d2, depth=depth, margin=margin, keep_dense=dense, **kw), cfg)
            for margin in (0, 2, 22)]
    for out in outs[1:]:
        assert np.array_equal(out.matches, outs[0].matches)
        assert np.array_equal(out.scores, outs[0].scores)
    assert len(outs[0]) > 0


@pytest.mark.parametrize("size,levels", [(0, 1), (1, 1), (60, 3), (700, 2), (3000, 500)])
def test_break_ties_orders_like_lexsort(size, levels):
    """Runs of equal values, short (insertion) and long (a keyed sort), signed zeros included."""
    from ctxmatch_lib.blob import _select_kernels

    rng = np.random.default_rng(size)
    vals = rng.integers(0, levels, size).astype(np.float64) / 7
    vals[::9] *= -1.0  # -0.0 where the value is 0: equal to 0.0 for both sorts
    pairs = rng.choice(40 * 1000, size, replace=False)
    first, second = pairs // 1000, pairs % 1000
    order = _select_kernels.break_ties(np.argsort(vals), vals, first, second)
    np.testing.assert_array_equal(order, np.lexsort((second, first, vals)))


@pytest.mark.parametrize("cup", [True, False])
def test_prefilter_lists_is_the_union_or_intersection(cup):
    """F∪ / F∩ from the sorted lists against the sets they define (Eqs. 10-11), values from the rows."""
    from ctxmatch_lib.blob import _select_kernels

    rng = np.random.default_rng(5)
    n, m, T = 40, 30, 6
    D = rng.integers(0, 9, (n, m)).astype(np.float64)
    ridx = np.argsort(D, axis=1, kind="stable")[:, :T]
    cidx = np.argsort(D.T, axis=1, kind="stable")[:, :T]
    rval, cval = np.take_along_axis(D, ridx, 1), np.take_along_axis(D.T, cidx, 1)
    for fr, fc in [(1, 1), (3, 5), (T, T)]:
        rows, cols, vals = _select_kernels.prefilter_lists(ridx, rval, cidx, cval, fr, fc, cup)
        got = sorted(zip(rows.tolist(), cols.tolist()))
        in_rows = {(i, int(j)) for i in range(n) for j in ridx[i, :fr]}
        in_cols = {(int(i), j) for j in range(m) for i in cidx[j, :fc]}
        assert got == sorted(in_rows | in_cols if cup else in_rows & in_cols)
        np.testing.assert_array_equal(vals, D[rows, cols])


@pytest.mark.parametrize("d", [1, 7, 8, 128, 131])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_exact_distance_is_the_documented_sum_bit_for_bit(d, dtype):
    """The SIMD exact distance equals its order spelled out in scalar float64: eight running sums (k mod 8),
    the last d mod 8 terms added to the first, then ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))."""
    from ctxmatch_lib.blob import _kernels

    rng = np.random.default_rng(d)
    A = (rng.random((12, d)) ** 3).astype(dtype)
    B = rng.normal(size=(15, d)).astype(dtype)

    def reference(a, b):
        s = [0.0] * 8
        d8 = d - d % 8
        for k in range(d8):
            t = float(a[k]) - float(b[k])
            s[k % 8] += t * t
        for k in range(d8, d):
            t = float(a[k]) - float(b[k])
            s[0] += t * t
        return ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]))

    got = [_kernels._exact_sq(A, i, B, j) for i in range(12) for j in range(15)]
    assert got == [reference(A[i], B[j]) for i in range(12) for j in range(15)]
    # four at a time (the re-ranking's blocks and whole lines), and against a row widened to float64
    # beforehand (certify_lines): the same bits
    four = [_kernels._exact_sq4(A, i, B, j, (j + 3) % 15, (j + 7) % 15, (j + 11) % 15) for i in range(12)
            for j in range(15)]
    assert four == [tuple(reference(A[i], B[k]) for k in (j, (j + 3) % 15, (j + 7) % 15, (j + 11) % 15))
                    for i in range(12) for j in range(15)]
    js = np.arange(15)[::-1].copy()
    for q in (0, 3, 4, 9, 15):  # tails of 0-3 after the blocks of four
        out = np.full(15, -1.0)
        _kernels._exact_block(A.astype(np.float64), 5, B, js, q, out)
        assert out[:q].tolist() == [np.sqrt(reference(A[5], B[k])) for k in js[:q]] and (out[q:] == -1).all()
    for m in (13, 14, 15):
        row = np.empty(m)
        _kernels._exact_row(A, 2, B[:m], row)
        assert row.tolist() == [np.sqrt(reference(A[2], B[k])) for k in range(m)]
    # a plain left-to-right sum rounds differently on these values: the comparison can tell orders apart
    plain = [sum((float(x) - float(y)) ** 2 for x, y in zip(A[i], B[j])) for i in range(12) for j in range(15)]
    assert got != plain or d < 16
