"""AdaLAM's compiled kernels and location grouping against plain formulations of the same decisions."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ctxmatch_lib.filters import adalam
from ctxmatch_lib.filters.adalam._kernels import beaten_by_neighbours, best_confident_maps, half_keys


def _half(x: float) -> float:
    """Nearest half-precision value, through numpy's float16 (inf past the largest)."""
    with np.errstate(over="ignore"):
        return float(np.float16(x))


def _count_plain(res: np.ndarray, min_conf: float):
    """The confidence-based inlier count of one map's residuals, every residual sorted and counted."""
    o = np.argsort(res, kind="mergesort")
    sv = res[o]
    keys = [_half(np.float32(x * x)) for x in sv]
    w = np.zeros(len(sv))
    votes = 0.0
    i = 0
    while i < len(sv):
        j = i + 1
        while j < len(sv) and keys[j] == keys[i]:
            j += 1
        for k in range(i, j):
            w[k] = 0.0 if sv[k] * sv[k] <= 1e-8 else 1.0 / (j - i)
            votes += w[k]
        i = j
    if votes == 0.0:
        return 0, 0.0, o
    cum = good = 0.0
    for k in range(len(sv)):
        cum += w[k]
        if sv[k] * sv[k] * min_conf <= cum / votes or sv[k] * sv[k] <= 1e-8:
            good += w[k]
    c = int(math.floor(good + 1e-9))
    if c == 0:
        return 0, 0.0, o
    with np.errstate(divide="ignore"):  # an exact fit last: infinite confidence, as the kernel
        return c, float(np.float64(c) / (votes * sv[c - 1] * sv[c - 1])), o


def _maps_case(seed: int, B: int = 5, T: int = 24, M: int = 60, grid: float = 0.0):
    """Neighbourhoods of a common affinity with noise, outliers, duplicated members and exact fits; maps
    near the true one, unrelated ones and unusable ones. With ``grid``, members on a grid of that step (many
    equal residuals and half-precision runs on both sides of the ``r^2 * min_conf <= 1`` boundary)."""
    rng = np.random.default_rng(seed)
    U = rng.uniform(-1, 1, (B, M, 2))
    if grid:
        U = np.round(U / grid) * grid
    truth = np.eye(2) + rng.normal(0, 0.2, (B, 1, 2, 2))
    V = np.einsum("bij,bmj->bmi", truth[:, 0], U) + rng.normal(0, 1e-3, (B, M, 2))
    out = rng.random((B, M)) < 0.4
    V[out] = rng.uniform(-1, 1, (int(out.sum()), 2))
    if grid:
        V = np.round(V / grid) * grid
    V[:, :4] = np.einsum("bij,bmj->bmi", truth[:, 0], U[:, :4])  # exact fits
    U[:, 10:14], V[:, 10:14] = U[:, 20:24], V[:, 20:24]  # duplicated members
    A = truth + rng.normal(0, 1e-3, (B, T, 2, 2)) * (rng.random((B, T, 1, 1)) < 0.7)
    A[:, ::5] = rng.normal(0, 1, (B, len(range(0, T, 5)), 2, 2))
    A[:, 3] = truth[:, 0]  # maps through the exact fits
    usable = rng.random((B, T)) < 0.9
    ns = rng.integers(8, M + 1, B)
    distinct = rng.random((B, M)) < 0.8
    return A, U, V, ns, usable, distinct


@pytest.mark.parametrize("seed, size", [(s, (24, 60, 0.0)) for s in range(6)]
                         + [(6, (40, 300, 0.0)), (7, (40, 300, 1 / 64)), (8, (40, 300, 1 / 16))])
@pytest.mark.parametrize("min_conf", [200.0, 5.0])
def test_best_confident_maps_match_every_map_counted(seed, size, min_conf):
    A, U, V, ns, usable, distinct = _maps_case(seed, T=size[0], M=size[1], grid=size[2])
    count, conf, order, near, near_distinct = best_confident_maps(A, U, V, ns, usable, distinct, min_conf)
    B, T, M = A.shape[0], A.shape[1], U.shape[1]
    for b in range(B):
        n = ns[b]
        per_map = []
        for t in range(T):
            rx = A[b, t, 0, 0] * U[b, :n, 0] + A[b, t, 0, 1] * U[b, :n, 1] - V[b, :n, 0]
            ry = A[b, t, 1, 0] * U[b, :n, 0] + A[b, t, 1, 1] * U[b, :n, 1] - V[b, :n, 1]
            res = np.sqrt(rx * rx + ry * ry) if usable[b, t] else np.full(n, 2.0)
            exact = res <= 2.0 ** -12
            per_map.append(_count_plain(res, min_conf) + (int(exact.sum()), int((exact & distinct[b, :n]).sum())))
        counts = [p[0] for p in per_map]
        best = int(np.argmax(counts))
        assert count[b] == counts[best] and conf[b] == per_map[best][1]
        assert np.array_equal(order[b, :n], per_map[best][2]) and np.array_equal(order[b, n:], np.arange(n, M))
        assert np.array_equal(near[b], [p[3] for p in per_map])
        assert np.array_equal(near_distinct[b], [p[4] for p in per_map])
    assert count.max() > 0 and near_distinct.max() > 0


def test_half_keys_equal_exactly_when_float16_values_are():
    rng = np.random.default_rng(3)
    h = np.arange(0, 0x7C01, dtype=np.uint16).view(np.float16).astype(np.float32)  # every finite half and inf
    mid = (h[:-1].astype(np.float64) + h[1:]) / 2  # the rounding boundaries
    y = np.concatenate([h, np.float32(mid), np.nextafter(np.float32(mid), np.float32(0)),
                        np.nextafter(np.float32(mid), np.float32(np.inf)), np.float32(rng.random(20000) ** 8),
                        np.float32(np.exp(rng.uniform(-30, 15, 20000))), [np.float32(1e30), np.inf, np.nan]])
    y = np.sort(y.astype(np.float32))
    keys = np.empty(len(y), np.int64)
    half_keys(y, keys)
    with np.errstate(over="ignore"):
        f16 = y.astype(np.float16).astype(np.float64)
    same = f16[1:] == f16[:-1]  # NaN equal to nothing
    assert np.array_equal(keys[1:] == keys[:-1], same) and same.any() and (~same).any()
    finite = ~np.isnan(y)
    assert (np.diff(keys[finite]) >= 0).all()


def _pairs_beaten(x, s, R1):
    """The seed test over every pair of matches closer than ``R1``."""
    pairs = cKDTree(x).query_pairs(np.nextafter(R1, 0.0), output_type="ndarray")
    beaten = np.zeros(len(s), bool)
    a, b = pairs[:, 0], pairs[:, 1]
    beaten[a[s[a] > s[b]]] = True
    beaten[b[s[b] > s[a]]] = True
    return beaten


@pytest.mark.parametrize("seed", range(4))
def test_seeds_by_location_match_every_pair(seed):
    rng = np.random.default_rng(seed)
    loc = rng.uniform(0, 200, (300, 2))
    loc[:20] = np.round(loc[:20])  # some at integer spacing: distances equal to the radius
    x = loc[rng.integers(0, len(loc), 1500)]
    s = np.round(rng.random(1500), 2)  # many equal scores
    for R1 in (5.0, 12.0, 30.0):
        locs = adalam._Locations(x)
        beaten = beaten_by_neighbours(s, locs.inv, np.ascontiguousarray(
            locs.tree.query_pairs(np.nextafter(R1, 0.0), output_type="ndarray"), dtype=np.int64), len(loc))
        assert np.array_equal(beaten, _pairs_beaten(x, s, R1))
        assert np.array_equal(adalam._seeds(locs, s, R1, 0.5), np.flatnonzero(~beaten & (s < 0.5)))


def test_location_members_match_the_ball_of_every_match():
    rng = np.random.default_rng(7)
    loc = rng.uniform(0, 100, (80, 2))
    x = loc[rng.integers(0, len(loc), 400)]
    locs = adalam._Locations(x)
    centres = x[[0, 5, 17, 399]]
    lid, mid = locs.members(locs.tree.query_ball_point(centres, 15.0))
    full = cKDTree(x).query_ball_point(centres, 15.0)
    for k in range(len(centres)):
        assert sorted(mid[lid == k]) == sorted(full[k])
    assert np.array_equal(lid, np.sort(lid))
    lid, mid = locs.members([])
    assert len(lid) == 0 and len(mid) == 0
