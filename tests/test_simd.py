"""The 16-lane intrinsics of blob matching's scan (``ctxmatch_lib._numerics.simd``) against plain Python references."""

from bisect import bisect_right

import numpy as np
import pytest
from numba import njit

from ctxmatch_lib._numerics.simd import (band16, below16, count16, fill16, fma16, insert16, lane16, load16, prefetch,
                                row_codes, row_flags, row_reflag, store16)
from ctxmatch_lib.blob import _kernels, _walk_kernels


@njit(cache=False)
def _insert_all(values, indices, K):
    """Every (value, index) inserted in turn into an empty 16-lane line; lanes 0..K-1 returned."""
    line = np.full((1, 16), np.inf, np.float32)
    idx = np.full((1, 16), -1, np.int64)
    lv, lx = load16(line, 0, 0), load16(idx, 0, 0)
    for p in range(len(values)):
        lv, lx = insert16(lv, lx, values[p], indices[p])
    store16(line, 0, 0, lv)
    store16(idx, 0, 0, lx)
    return line[0, :K].copy(), idx[0, :K].copy(), lane16(lv, K - 1)


@njit(cache=False)
def _counts(row, v, lim):
    vec = load16(row, 0, 0)
    return count16(vec, v, lim), below16(vec, v, lim)


@pytest.mark.parametrize("K", [1, 5, 13, 16])
@pytest.mark.parametrize("levels", [3, 1000])
def test_insert16_keeps_the_k_smallest_after_equal_values(K, levels):
    """insert16 keeps a line sorted by value, a new entry after the equal ones (so ties stay in arrival
    order), and drops what falls past the last lane; lanes below K do not depend on the others."""
    rng = np.random.default_rng(K * levels)
    values = rng.integers(0, levels, 200).astype(np.float32)
    values[rng.random(200) < 0.1] = np.float32(-0.0)
    indices = np.arange(200, dtype=np.int64) + 1000
    got_v, got_x, kth = _insert_all(values, indices, K)
    line: list[tuple[float, int]] = []
    for v, x in zip(values.tolist(), indices.tolist()):
        pos = bisect_right([e[0] for e in line], v)
        line.insert(pos, (v, x))
        del line[16:]
    assert got_v.tolist() == [e[0] for e in line[:K]]
    assert got_x.tolist() == [e[1] for e in line[:K]]
    assert kth == line[K - 1][0]


def test_insert16_at_or_above_the_last_lane_changes_nothing():
    values = np.arange(16, dtype=np.float32)
    got_v, got_x, _ = _insert_all(np.r_[values, np.float32(15), np.float32(99)],
                                  np.arange(18, dtype=np.int64), 16)
    assert got_v.tolist() == values.tolist() and got_x.tolist() == list(range(16))


@pytest.mark.parametrize("lim", [0, 1, 7, 16, 40, -3])
def test_count16_and_below16_count_the_first_lim_lanes(lim):
    row = np.array([[3, 1, 2, 2, 5, 0, 2, 9, 2, 4, 2, 7, 1, 2, 8, 2]], np.float32)
    lanes = row[0, : max(0, min(16, lim))]
    assert _counts(row, np.float32(2), lim) == ((lanes <= 2).sum(), (lanes < 2).sum())


@pytest.mark.parametrize("K", [1, 4, 16, 17, 20])
@pytest.mark.parametrize("cnt", [20, 32])
def test_kth_of_is_the_order_statistic(K, cnt):
    """The scan's K-th smallest of the group minima, by ranks in registers (K <= 16) or a quickselect."""
    rng = np.random.default_rng(K + cnt)
    for levels in (4, 10**6):
        work = np.full((1, max(32, cnt)), np.inf, np.float32)
        work[0, :cnt] = rng.integers(0, levels, cnt)
        assert _kernels._kth_of(work.copy(), cnt, K) == np.sort(work[0, :cnt])[K - 1]


@njit(cache=False)
def _band_masks(Q, r, pen, lo, hi):
    out = np.empty(Q.shape[1] // 16, np.int64)
    for b in range(len(out)):
        out[b] = band16(Q, r, 16 * b, pen, lo, hi)
    return out


def _codes_and_pen(m, seed):
    rng = np.random.default_rng(seed)
    Q = rng.integers(0, 40, (2, m)).astype(np.uint16)
    Q[:, rng.random(m) < 0.05] = 65534
    pen = np.where(rng.random(m) < 0.3, 0xFFFF, 0).astype(np.uint16)
    return Q, pen


@pytest.mark.parametrize("m", [16, 48, 160])
@pytest.mark.parametrize("lo", [0, 1, 7, 39, 40, 65534])
def test_band16_against_numpy(m, lo):
    """band16: the codes in [lo, hi], taken-out entries (code | 0xFFFF) never in."""
    Q, pen = _codes_and_pen(m, m)
    x = (Q[1] | pen).astype(np.int64)
    hi = min(lo + 9, 65534)
    bits = ((x >= lo) & (x <= hi)).reshape(-1, 16) @ (1 << np.arange(16))
    assert _band_masks(Q, 1, pen, np.uint16(lo), np.uint16(hi)).tolist() == bits.tolist()


@pytest.mark.parametrize("m", [16, 37, 160])
@pytest.mark.parametrize("lo", [0, 1, 7, 39, 40, 65534])
@pytest.mark.parametrize("descending", [False, True])
def test_band_from_finds_the_least_code_and_its_whole_band_in_one_pass(m, lo, descending):
    """_band_from: the least code >= lo not taken out (0xFFFF if none), and every entry of its band
    [lo, top] listed once, in column order (a few more are allowed: met before the least code, above it);
    codes falling along the row (a new least code at each entry) and the tail beyond the last 16 too."""
    Q, pen = _codes_and_pen(m, m)
    if descending:
        Q[0] = np.sort(Q[0])[::-1]
    x = (Q[0] | pen).astype(np.int64)
    want = x[(x >= lo) & (x < 0xFFFF)].min(initial=0xFFFF)
    E, qoff, step, top_best = 1.0, 0.0, 1.0, 3
    band = np.full(m, -1, np.int64)
    mu, count = _walk_kernels._band_from(Q, 0, pen, lo, top_best, E, qoff, step, band)
    assert mu == want
    listed = band[:count]
    assert np.all(np.diff(listed) > 0) and np.all((x[listed] >= lo) & (x[listed] < 0xFFFF))
    if mu < 0xFFFF:
        top = min(_walk_kernels._band_top(mu, top_best, E, qoff, step), 65534)
        assert set(np.flatnonzero((x >= lo) & (x <= top))) <= set(listed.tolist())


@pytest.mark.parametrize("lo, hi", [(-1e-6, 4.0), (-3.0, 2e5), (0.0, 0.0)])
def test_codes_decode_within_half_a_step_and_keep_their_order(lo, hi):
    """code_scale / code: qoff + q step is within 0.51 step of v over the whole range, codes never reach
    TAKEN, and a larger v never gets a smaller code."""
    qoff, qinv, step = _kernels.code_scale(lo, hi)
    v = np.sort(np.r_[np.random.default_rng(0).uniform(lo, hi, 20000), lo, hi]).astype(np.float32)
    v = v[(v >= lo) & (v <= hi)]
    q = _kernels.encode(v[None], qoff, qinv)[0]
    assert q.max() < _kernels.TAKEN and np.all(np.diff(q.astype(np.int64)) >= 0)
    assert np.abs(float(qoff) + q * step - v.astype(np.float64)).max() <= 0.51 * step


@pytest.mark.parametrize("strict", [True, False])
@pytest.mark.parametrize("t_o2", [0.0, 400.0])
@pytest.mark.parametrize("coarse", [False, True])
def test_next_in_line_against_a_brute_force_walk(strict, t_o2, coarse):
    """next_in_line (bands of 16-bit codes, exact distances deciding) is the brute-force successor of
    (d, j) in (exact distance, index) order among the entries not taken out, on rows with tied distances;
    coarse codes (a step wider than the gaps between distances) put many entries in each band."""
    rng = np.random.default_rng(int(strict) + int(t_o2) + 2 * int(coarse))
    A = np.abs(rng.normal(size=(4, 24))).astype(np.float32)
    B = np.abs(rng.normal(size=(70, 24))).astype(np.float32)
    B[40:60] = B[rng.integers(0, 40, 20)]  # tied distances
    pts = rng.uniform(0, 100, (70, 2))
    A64, B64 = A.astype(np.float64), B.astype(np.float64)
    nb = _kernels.sq_norms(B64)
    scale = _kernels.error_scale(24)
    top = (np.sqrt(_kernels.sq_norms(A64).max()) + np.sqrt(nb.max())) ** 2
    qoff, qinv, step = _kernels.code_scale(-1e-3, top * (20000 if coarse else 1))
    for line in range(4):
        e = np.array([np.sqrt(_kernels._exact_sq(A64, line, B64, k)) for k in range(70)])
        na = _kernels._exact_sq(A64, line, np.zeros((1, 24)), 0)
        v = (np.float32(na) + nb.astype(np.float32) - 2 * (A[line] @ B.T)).astype(np.float32)
        Q = _kernels.encode(v[None], qoff, qinv)
        E = scale * (na + nb.max()) + step
        pen = np.where(rng.random(70) < 0.2, 0xFFFF, 0).astype(np.uint16)
        for start in (0, 3, 20):
            order = sorted(range(70), key=lambda k: (e[k], k))
            j = order[start]
            d = e[j]
            skip = order[start + 1]
            ok = [k for k in range(70) if pen[k] == 0 and k != skip
                  and (t_o2 == 0 or ((pts[k] - pts[skip]) ** 2).sum() >= t_o2)
                  and (e[k] > d or (e[k] == d and (k > j if strict else True)))]
            want = min(((e[k], k) for k in ok), default=(np.inf, -1))
            held = pen.copy()
            got = _walk_kernels.next_in_line(Q, 0, A64, line, B64, E, d, j, strict, skip, pen, pts, t_o2, qoff,
                                             step, np.empty(70, np.int64))
            assert got == want
            assert pen.tobytes() == held.tobytes()  # pen[skip] restored


@njit(cache=False)
def _prefetched_sum(X, order):
    s = 0.0
    for p in range(len(order)):
        if p + 1 < len(order):
            for k in range(0, X.shape[1], 16):
                prefetch(X, order[p + 1], k)
        for k in range(X.shape[1]):
            s += X[order[p], k]
    return s


def test_prefetch_changes_no_result_and_rejects_non_matrices():
    X = np.random.default_rng(0).random((50, 40)).astype(np.float32)
    order = np.random.default_rng(1).permutation(50)
    expected = 0.0
    for p in order:
        for k in range(40):
            expected += float(X[p, k])
    assert _prefetched_sum(X, order) == expected

    @njit(cache=False)
    def bad(v):
        prefetch(v, 0, 0)

    with pytest.raises(Exception, match="2-d array"):
        bad(np.zeros(4))


@njit(cache=False)
def _fused_row(Bt, a_row, a, t, n2, cthr, j0, k):
    """The 64 dot products of ``a_row`` with the columns of ``Bt`` (d, 64) by fma16, then row_flags into a
    (2, 128) V at column k; also row_reflag of the stored distances against -inf / the columns."""
    g0 = g1 = g2 = g3 = fill16(np.float32(0))
    for c in range(Bt.shape[0]):
        s = a_row[c]
        g0, g1 = fma16(g0, load16(Bt, c, 0), s), fma16(g1, load16(Bt, c, 16), s)
        g2, g3 = fma16(g2, load16(Bt, c, 32), s), fma16(g3, load16(Bt, c, 48), s)
    V = np.zeros((2, 128), np.float32)
    rows, cols = row_flags(V, 1, k, g0, g1, g2, g3, a, t, n2, cthr, j0)
    again = row_reflag(V, 1, k, np.float32(-np.inf), cthr, j0)
    return V, rows, cols, again


@njit(cache=False)
def _codes(V, qoff, qinv, m):
    dense = np.zeros((2, m), np.uint16)
    row_codes(dense, 1, m - 64, V, 0, 3, qoff, qinv, np.float32(_kernels.TAKEN - 1))
    return dense


@pytest.mark.parametrize("seed", [0, 1])
def test_row_flags_form_the_scans_distances_and_flags(seed):
    """fma16 sums a·b with one rounding per term in the order of the coordinates; row_flags stores
    v = (a + n2) - (g + g) as scan_tile forms it and flags v < t (row) and v < cthr (column) apart;
    row_reflag flags the stored distances again."""
    rng = np.random.default_rng(seed)
    d, j0, k = 24, 10, 32
    B = rng.random((64, d), dtype=np.float32)
    a_row = rng.random(d, dtype=np.float32)
    n2 = rng.random(100, dtype=np.float32) * 8
    cthr = rng.random(100, dtype=np.float32) * 8
    a, t = np.float32(2.5), np.float32(3.0)
    V, rows, cols, again = _fused_row(np.ascontiguousarray(B.T), a_row, a, t, n2, cthr, j0, k)
    g = np.zeros(64, np.float32)
    for c in range(d):  # the product is exact in float64; one rounding to float32 (no double-rounding tie here)
        g = (g.astype(np.float64) + B[:, c].astype(np.float64) * np.float64(a_row[c])).astype(np.float32)
    v = (a + n2[j0 : j0 + 64]) - (g + g)
    assert np.array_equal(V[1, k : k + 64], v) and not V[0].any() and not V[1, :k].any()
    bits = 1 << np.arange(64, dtype=np.uint64)
    as_bits = lambda mask: np.int64(mask).view(np.uint64)  # noqa: E731 (the masks are int64)
    assert as_bits(rows) == np.bitwise_or.reduce(bits[v < t])
    assert as_bits(cols) == np.bitwise_or.reduce(bits[v < cthr[j0 : j0 + 64]])
    assert again == cols


def test_row_codes_are_the_scalar_codes():
    v = np.linspace(-0.5, 9.0, 128, dtype=np.float32).reshape(2, 64)
    qoff, qinv, _ = _kernels.code_scale(-0.01, 8.0)
    V = np.zeros((1, 80), np.float32)
    V[0, 3:67] = v[0]
    dense = _codes(V, qoff, qinv, 70)
    assert np.array_equal(dense[1, 6:], _kernels.encode(v[:1], qoff, qinv)[0]) and not dense[0].any()
