"""RFM-SCAN against its authors' code: the reference plugin ``benchmarks/ref_rfm_scan.py`` and what the
alignment with StaRainJ/RFM-SCAN changed in :func:`ctxmatch_lib.filters.rfm_scan.rfm_scan_filter`.

The comparison with the authors' MATLAB code runs only when GNU Octave is on PATH and ``CTXMATCH_RFM_SCAN_REF``
names a checkout of StaRainJ/RFM-SCAN.
"""

from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.filters import rfm_scan as rfm_module
from ctxmatch_lib.filters.rfm_scan import _added_matches, _MotionSpace, _Round
from ctxmatch_lib.testing import planted_homography_matches

SIZE = (640, 480)

# A stand-in for the demo's layout (the lines the plugin reads; not the authors' file).
DEMO = """clear;
gamma = 10;          % comment
Bound = [3,30];
pct   = 0.05;
Mu    = [0.1,0.08];
%% noise
N      = size(X,1);
NoiseX = [X;1];
X = NoiseX; Y = NoiseY;

tic
A = 1;
B = 2;
toc
%%
IDX1=IDX1(1:N);
ind=find(IDX1>0);
disp(1)
"""


@pytest.fixture(scope="module")
def plugin(bench):
    return bench.plugin("rfm_scan")


def rfm(x, y, **kw):
    m = np.c_[np.arange(len(x)), np.arange(len(x))]
    return FILTERS["rfm_scan"](x, y, m, None, image_size1=SIZE, image_size2=SIZE, **kw)


def test_plugin_is_registered_and_reads_the_demo_lines(plugin, bench, tmp_path):
    assert "rfm_scan" in bench.PLUGIN_REFERENCES
    assert set(plugin.FUNC_FILES) <= set(plugin.FILES) and "Demo_main.m" in plugin.FILES
    params, block = plugin.demo_parts(DEMO)
    assert params.splitlines()[0].startswith("gamma = 10;") and len(params.splitlines()) == 4
    # The random-match block, the lines between tic and toc (without them), the kept rows; nothing else.
    assert block.splitlines() == ["N      = size(X,1);", "NoiseX = [X;1];", "X = NoiseX; Y = NoiseY;", "A = 1;",
                                  "B = 2;", "IDX1=IDX1(1:N);", "ind=find(IDX1>0);"]
    (tmp_path / "Demo_main.m").write_text(DEMO)
    body = plugin.octave_body(tmp_path, {"mu": [0.2, 0.1], "min_pts_bounds": [4, 20], "rng": 3})
    assert "Mu(1) = 0.2;\nMu(2) = 0.1;\nBound(1) = 4.0;\nBound(2) = 20.0;" in body
    assert body.index("c0 = cputime;") < body.index("N      = size") < body.index("cpu = cputime - c0;")
    assert body.rstrip().endswith("keep = ind;") and "rng" not in body and "clear" not in body
    with pytest.raises(ValueError, match="Demo_main.m"):
        plugin.demo_parts(DEMO.replace("toc\n", ""))
    plugin.compile_mex(tmp_path, tmp_path)
    assert (tmp_path / "pdist2.m").exists() and (tmp_path / "mapminmax.m").exists()


def test_added_matches_are_octaves_rand_state_draws_in_zero_to_max():
    x = np.array([[10.0, 5.0], [200.0, 40.0], [50.0, 400.0]])
    y = np.array([[1.0, 2.0], [30.0, 8.0], [3.0, 4.0]])
    nx, ny = _added_matches(x, y, 2, 0)
    # rand('state', 0) in GNU Octave 7.3 starts 0.844421851525048 0.757954402940302 0.420571580830845 ...;
    # rand(2, 2) fills its first column first.
    draw = random.Random(0).random
    u = [draw() for _ in range(8)]
    np.testing.assert_allclose(u[:3], [0.844421851525048, 0.757954402940302, 0.420571580830845], atol=1e-15)
    np.testing.assert_array_equal(nx, np.array([[u[0], u[2]], [u[1], u[3]]]) * [200.0, 400.0])
    np.testing.assert_array_equal(ny, np.array([[u[4], u[6]], [u[5], u[7]]]) * [30.0, 8.0])
    gx, _ = _added_matches(x, y, 5, np.random.default_rng(1))
    assert gx.shape == (5, 2) and (gx >= 0).all() and (gx <= [200.0, 400.0]).all()


@pytest.mark.parametrize("n, expected", [(50, 3), (30, 2), (10, 1), (9, 0), (1000, 20)])
def test_number_of_added_matches_rounds_halves_up_as_matlab(monkeypatch, n, expected):
    seen = []
    real = rfm_module._added_matches

    def spy(x, y, n_noise, rng):
        seen.append(n_noise)
        return real(x, y, n_noise, rng)

    monkeypatch.setattr(rfm_module, "_added_matches", spy)
    x = np.random.default_rng(0).uniform(0, 600, (n, 2))
    rfm(x, x + 5.0)
    assert seen == [expected]  # round(0.05 * 50) = round(2.5) = 3 in MATLAB (Python's round gives 2)


def test_rng_is_validated_and_generators_accepted():
    x = np.random.default_rng(0).uniform(0, 600, (80, 2))
    with pytest.raises(ValueError, match="rng"):
        rfm(x, x + 3.0, rng=-1)
    with pytest.raises(ValueError, match="rng"):
        rfm(x, x + 3.0, rng="seed")
    assert rfm(x, x + 3.0, rng=np.random.default_rng(4)).shape == (80,)
    np.testing.assert_array_equal(rfm(x, x + 3.0, rng=np.int64(7)), rfm(x, x + 3.0, rng=7))


def test_rows_as_given_let_copies_of_a_wrong_match_support_themselves():
    # 60 correct matches (MinPts at its floor of 3) and one wrong match repeated 3 times: the authors' code
    # (merge_coincident=False) makes the copies a core point of DBSCAN; the default decides them once.
    pm = planted_homography_matches(60, 1.0, noise=0.5, image_size=SIZE, rng=0)
    x, y = pm.kpts1[pm.matches[:, 0]], pm.kpts2[pm.matches[:, 1]]
    wx, wy = np.array([[323.3, 235.9]]), np.array([[90.0, 400.0]])
    x3, y3 = np.vstack([x, np.repeat(wx, 3, 0)]), np.vstack([y, np.repeat(wy, 3, 0)])
    assert not rfm(np.vstack([x, wx]), np.vstack([y, wy]))[-1]
    assert not rfm(x3, y3)[-3:].any()
    assert rfm(x3, y3, merge_coincident=False)[-3:].all()


def _brute_kth(space, scale, k, queries):
    d = space.dist(queries[:, None], np.arange(space.n)[None, :]) * scale[None, :]
    return np.partition(d, k - 1, axis=1)[:, k - 1]


@pytest.mark.parametrize("n_near", [40, 5])
def test_dense_kth_with_far_groups_searched_by_ball_equals_whole_rows(n_near):
    # Second-round scales (1 for the first round's clusters, 100 for the rest): the k-th smallest from the
    # scale-1 rows whole plus the scale-100 rows within the upper bound equals the one from whole rows; with
    # fewer than k scale-1 rows, whole rows.
    rng = np.random.default_rng(n_near)
    feats = rng.uniform(0, 1, (300, 6))
    feats[:20] = feats[20] + rng.normal(0, 1e-3, (20, 6))  # a tight group of unclustered rows
    scale = np.full(300, 100.0, np.float32)
    scale[rng.choice(np.arange(20, 300), n_near, replace=False)] = 1.0
    space = _MotionSpace(feats, 10.0)
    rnd = _Round(space, scale, 8)
    queries = np.arange(300)
    upper = rnd.upper()
    exact = _brute_kth(space, scale, 8, queries)
    assert (upper >= exact).all()
    np.testing.assert_array_equal(rnd.dense_kth(queries, upper), exact)


def test_octave_reference_agrees_on_a_planted_case(bench):
    # The authors' Demo_main.m filtering under Octave (random state 0) and ours (rng=0) on a planted case
    # without coincident rows: the same added matches, the same mask (measured: identical).
    if shutil.which("octave") is None:
        pytest.skip("GNU Octave ('octave') is not on PATH")
    root = os.environ.get("CTXMATCH_RFM_SCAN_REF")
    if not root:
        pytest.skip("CTXMATCH_RFM_SCAN_REF (a checkout of StaRainJ/RFM-SCAN) is not set")
    pm = planted_homography_matches(250, 0.5, noise=0.5, image_size=SIZE, rng=2)
    x, y = pm.kpts1[pm.matches[:, 0]], pm.kpts2[pm.matches[:, 1]]
    case = dict(X=x, Y=y, small=np.ones(len(x), bool), info=np.array([*SIZE, *SIZE], float))
    [(ref, cpu)] = bench.run_octave_reference("rfm_scan", Path(root), [case])
    assert cpu >= 0 and 0 < ref.sum() < len(x)
    np.testing.assert_array_equal(rfm(x, y), ref)
    np.testing.assert_array_equal(rfm(x, y, merge_coincident=False), ref)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_clusters_as_the_dense_definition_with_second_round_scales(seed):
    # One round with the second round's column scales (1 / 100): the pruned searches (L1-bound core test,
    # nearest-core reach test) give the dense definition's clustered set.
    space, scale, n = _clusters_with_scales(seed)
    k, mu = 12, 0.08
    _assert_dense_clustering(_Round(space, scale, k).clustered(mu), space, scale, n, k, mu)


def _clusters_with_scales(seed):
    """Four tight clusters and uniform clutter in 6-D, 60 % of the columns at scale 1 and the rest at 100."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 1, (4, 6))
    feats = np.vstack([c + rng.normal(0, 0.02, (60, 6)) for c in centres] + [rng.uniform(0, 1, (160, 6))])
    scale = np.where(rng.random(len(feats)) < 0.6, 1.0, 100.0).astype(np.float32)
    return _MotionSpace(feats, 10.0), scale, len(feats)


def _assert_dense_clustering(got, space, scale, n, k, mu):
    """``got`` is the round's clustered set by the dense definition: cores and what they reach."""
    every = np.arange(n)
    d = space.dist(every[:, None], every[None, :]) * scale[None, :]
    kth = np.partition(d, k - 1, axis=1)[:, k - 1]
    eps = kth.min() + np.float32(mu) * (kth.max() - kth.min())
    core = kth <= eps
    np.testing.assert_array_equal(got, core | (d[core] <= eps).any(0))
    assert 0 < got.sum() < n


@pytest.mark.parametrize("cells_per_member", [4.0, 0.01])
@pytest.mark.parametrize("seed", [0, 1])
def test_grid_counts_equal_a_plain_count_and_bracket_the_float32_one(seed, cells_per_member):
    # The compiled grid counts (ctxmatch_lib.filters.rfm_scan._kernels) against every pair in float64 (same
    # formula, same float32-rounded points), and the filter's float32 count between their sure and possible
    # counts; coarse grids (few cells per member) and queries outside the members' extent included.
    from ctxmatch_lib.filters.rfm_scan._kernels import MARGIN, MotionGrid, count_within

    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 1, (3, 6))
    feats = np.vstack([c + rng.normal(0, 0.03, (50, 6)) for c in centres] + [rng.uniform(0, 1, (150, 6))])
    space = _MotionSpace(np.clip(feats, 0, 1), 10.0)
    members = np.flatnonzero(rng.random(space.n) < 0.5)
    queries = np.arange(space.n)
    qscale = np.where(rng.random(space.n) < 0.7, 1.0, 100.0)
    f = space.f64
    dx = np.hypot(f[:, None, 0] - f[None, members, 0], f[:, None, 1] - f[None, members, 1])
    dy = np.hypot(f[:, None, 2] - f[None, members, 2], f[:, None, 3] - f[None, members, 3])
    dv = np.hypot(f[:, None, 4] - f[None, members, 4], f[:, None, 5] - f[None, members, 5])
    d = dx + dy + (1.0 + space.gamma32 * np.exp(-np.minimum(dx, dy))) * dv
    d32 = space.dist(queries[:, None], members[None, :]).astype(np.float64)
    for gscale in (1.0, 100.0):
        eps = float(np.quantile(d, 0.05)) / gscale
        t = d * gscale * qscale[:, None]
        grid = MotionGrid(f, members, eps / gscale / qscale.min(), space.gamma32, cells_per_member)
        never = np.full(space.n, 10**9)
        sure, possible = count_within(grid, f, qscale, never, eps, space.gamma32, gscale=gscale)
        np.testing.assert_array_equal(sure, (t <= eps * (1 - MARGIN)).sum(1))
        np.testing.assert_array_equal(possible, (t <= eps * (1 + MARGIN)).sum(1))
        exact = (d32 * np.float32(gscale) * qscale[:, None] <= eps).sum(1)
        assert (sure <= exact).all() and (exact <= possible).all() and 0 < exact.sum() < d.size
        # Stopped counts: the sure count stops at the target, the possible one with on_possible.
        stop = rng.integers(0, 6, space.n)
        sure_s, _ = count_within(grid, f, qscale, stop, eps, space.gamma32, gscale=gscale)
        np.testing.assert_array_equal(sure_s, np.where(stop > 0, np.minimum(sure, stop), 0))
        _, pos_s = count_within(grid, f, qscale, stop, eps, space.gamma32, gscale=gscale, on_possible=True)
        np.testing.assert_array_equal(pos_s, np.where(stop > 0, np.minimum(possible, stop), 0))


@pytest.mark.parametrize("m", [8, 13])
def test_upper_kth_bounds_the_float32_kth_and_equals_a_plain_float64_one(m):
    # The compiled upper bound of L (ctxmatch_lib.filters.rfm_scan._kernels.upper_kth) against numpy: the k-th
    # smallest of the float64 distances times 1 + MARGIN, at least the filter's float32 k-th smallest.
    from ctxmatch_lib.filters.rfm_scan._kernels import MARGIN, upper_kth

    rng = np.random.default_rng(m)
    space = _MotionSpace(rng.uniform(0, 1, (200, 6)), 10.0)
    rows = rng.choice(200, 50, replace=False)
    cand = rng.integers(0, 200, (50, m))
    cscale = np.where(rng.random((50, m)) < 0.8, 1.0, 100.0)
    k = 8
    got = upper_kth(space.f64, rows, cand, cscale, k, space.gamma32)
    f = space.f64
    dx = np.hypot(*(f[rows][:, None, :2] - f[cand][..., :2]).transpose(2, 0, 1))
    dy = np.hypot(*(f[rows][:, None, 2:4] - f[cand][..., 2:4]).transpose(2, 0, 1))
    dv = np.hypot(*(f[rows][:, None, 4:] - f[cand][..., 4:]).transpose(2, 0, 1))
    d64 = (dx + dy + (1.0 + space.gamma32 * np.exp(-np.minimum(dx, dy))) * dv) * cscale
    want = (np.sort(d64, 1)[:, k - 1] * (1 + MARGIN)).astype(np.float32)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    d32 = space.dist(rows[:, None], cand) * cscale.astype(np.float32)
    assert (got >= np.sort(d32, 1)[:, k - 1]).all()


@pytest.mark.parametrize("few_rows", [0, 1000])
def test_round_settles_what_the_grid_counts_leave_open_as_the_dense_definition(monkeypatch, few_rows):
    # A wide margin leaves many grid counts open: the exact float32 tests that settle them (whole rows for a
    # few queries, ball searches for more) give the dense definition's clustered set.
    from ctxmatch_lib.filters.rfm_scan import _kernels as _rfm_kernels

    monkeypatch.setattr(_rfm_kernels, "MARGIN", 0.3)
    monkeypatch.setattr(rfm_module, "_FEW_ROWS", few_rows)
    space, scale, n = _clusters_with_scales(7)
    k, mu = 12, 0.08
    rnd = _Round(space, scale, k)
    sure, possible = rnd.counts(np.arange(n), 0.3)
    assert ((sure < k) & (possible >= k)).sum() > 0  # open counts
    _assert_dense_clustering(rnd.clustered(mu), space, scale, n, k, mu)


def test_round_refines_coarse_bounds_that_do_not_prune_as_the_dense_definition(monkeypatch):
    # Second-round coarse upper bounds of L above max L (valid bounds, too loose to prune): the search for
    # max L replaces them by k-NN bounds and the round still clusters as the dense definition.
    original, refined = _Round.coarse_upper, []

    def loose(self):
        out = original(self)
        out[self.coarse] = np.float32(1e3)
        return out

    monkeypatch.setattr(_Round, "coarse_upper", loose)
    refine = _Round.refine
    monkeypatch.setattr(_Round, "refine", lambda self, upper: refined.append(self.coarse.sum()) or refine(self, upper))
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 1, (4, 6))  # more than 512 matches: not every match is a seed
    feats = np.vstack([c + rng.normal(0, 0.02, (200, 6)) for c in centres] + [rng.uniform(0, 1, (600, 6))])
    scale = np.where(rng.random(len(feats)) < 0.6, 1.0, 100.0).astype(np.float32)
    space = _MotionSpace(feats, 10.0)
    k, mu = 12, 0.08
    rnd = _Round(space, scale, k)
    got = rnd.clustered(mu)
    assert refined and refined[0] > 0 and not rnd.coarse.any()
    every = np.arange(len(feats))
    d = space.dist(every[:, None], every[None, :]) * scale[None, :]
    kth = np.partition(d, k - 1, axis=1)[:, k - 1]
    eps = kth.min() + np.float32(mu) * (kth.max() - kth.min())
    core = kth <= eps
    np.testing.assert_array_equal(got, core | (d[core] <= eps).any(0))
