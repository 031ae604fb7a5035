"""Reproducible numbers: every registered filter gives the same mask whatever the OMP/BLAS thread count,
and the neighbour search of LPM/GLPM breaks distance ties by index, not by the k-d tree's traversal order."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.filters._common import knn_without_self


def _brute_knn(points, candidates, k, queries):
    out = []
    for q in queries:
        c = np.array([j for j in candidates if j != q])
        d2 = ((points[c] - points[q]) ** 2).sum(1)
        out.append(c[np.lexsort((c, d2))][: min(k, len(candidates) - 1)])
    return np.array(out)


@pytest.mark.parametrize("seed", range(4))
def test_knn_breaks_ties_by_index(seed):
    rng = np.random.default_rng(seed)
    # Many exact ties: points on a coarse grid, each repeated (as a keypoint matched several times).
    base = rng.integers(0, 6, size=(40, 2)).astype(float)
    points = np.repeat(base, rng.integers(1, 5, size=40), axis=0)
    candidates = np.sort(rng.choice(len(points), size=len(points) * 2 // 3, replace=False))
    for k in (1, 4, 8):
        got = knn_without_self(points, candidates, k)
        np.testing.assert_array_equal(got, _brute_knn(points, candidates, k, np.arange(len(points))))
    # Sub-pixel keypoints repeated by many-to-many matching (the usual case: ties only between copies).
    real = np.repeat(rng.uniform(0, 50, size=(60, 2)), rng.integers(1, 8, size=60), axis=0)
    cand_real = np.sort(rng.choice(len(real), size=len(real) * 3 // 4, replace=False))
    for k in (1, 6, 8):
        np.testing.assert_array_equal(knn_without_self(real, cand_real, k),
                                      _brute_knn(real, cand_real, k, np.arange(len(real))))
    # Queries that are not candidates (GLPM searches among the guide matches only).
    queries = rng.choice(len(real), size=40, replace=False)
    np.testing.assert_array_equal(knn_without_self(real, cand_real, 5, queries),
                                  _brute_knn(real, cand_real, 5, queries))
    # The answer does not depend on the order the candidates are given in.
    shuffled = rng.permutation(candidates)
    np.testing.assert_array_equal(knn_without_self(points, shuffled, 6), knn_without_self(points, candidates, 6))


_SCRIPT = r"""
import json, sys
import numpy as np
from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.geometry import apply_homography

rng = np.random.default_rng(7)
H = np.array([[0.9, -0.1, 30.0], [0.08, 1.05, -12.0], [1e-4, -6e-5, 1.0]])
n_in, n_out = 150, 150
k1 = rng.uniform([20, 20], [620, 460], (n_in + n_out, 2)).round(0)  # integer pixels: many distance ties
k2 = rng.uniform([0, 0], [639, 479], (n_in + n_out, 2)).round(0)
k2[:n_in] = np.clip(apply_homography(H, k1[:n_in]), 0, [639, 479])  # keypoints stay on the image
idx = np.arange(n_in + n_out)
# Many-to-many: a third of the keypoints get a second, wrong match (repeated keypoints, tied distances).
extra = rng.choice(n_in + n_out, size=(n_in + n_out) // 3, replace=False)
matches = np.r_[np.c_[idx, idx], np.c_[extra, rng.permutation(extra)]].astype(np.int64)
scores = rng.uniform(0.3, 1.0, len(matches)).round(2)
scores[:n_in] *= 0.6
order = np.lexsort((matches[:, 1], matches[:, 0], scores))
matches, scores = matches[order], scores[order]
shapes = np.tile(3 * np.eye(2), (n_in + n_out, 1, 1))
out = {}
for name in sys.argv[1:]:
    keep = FILTERS[name](k1, k2, matches, scores, image_size1=(640, 480), image_size2=(640, 480),
                         shapes1=shapes, shapes2=shapes)
    out[name] = np.asarray(getattr(keep, "keep", keep)).astype(int).tolist()
print(json.dumps(out))
"""


def _masks(threads: int, names) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "OPENBLAS_NUM_THREADS": str(threads),
           "MKL_NUM_THREADS": str(threads), "NUMEXPR_NUM_THREADS": str(threads)}
    res = subprocess.run([sys.executable, "-c", _SCRIPT, *names], env=env, capture_output=True, text=True,
                         check=True, timeout=300)
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_every_filter_is_identical_with_1_and_2_threads():
    names = [n for n in FILTERS if not n.startswith("test-")]
    one, two = _masks(1, names), _masks(2, names)
    assert set(one) == set(names)
    for name in names:
        assert one[name] == two[name], f"filter {name!r} differs between 1 and 2 threads"
    # The planted case is informative: LPM keeps some matches and drops some.
    assert 0 < sum(one["lpm"]) < len(one["lpm"])
