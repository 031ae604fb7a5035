"""The 16-lane intrinsics of blob matching's scan (``ctxmatch_lib._simd``) against plain Python references."""

from bisect import bisect_right

import numpy as np
import pytest
from numba import njit

from ctxmatch_lib._simd import below16, count16, insert16, lane16, load16, store16
from ctxmatch_lib.blob import _kernels


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
