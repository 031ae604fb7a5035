"""Speed of the ground-truth methods B and C against method D at 15 000 candidates.

For each ground-truth kind (planar homography, non-planar F with hand-taken points, dense flow) a synthetic
pair with K candidate matches is built, a fraction ``--correct`` of them near-true correspondences (their
regions overlap, so B computes a real intersection area) and the rest random pairs; the script prints the
best-of-``--repeat`` time of :func:`ctxmatch_lib.groundtruth.label_matches` with methods D, B and C, and the
ratios B / D and C / D measured in the same run (the target: at most 3). ``--correct 1`` is the worst case
for B (every region pair overlaps). The three methods are timed in the same process on the same inputs; the
best of ``--repeat`` runs excludes the first call's compilation (numba) and the noise of the shared machine.
Run: ``OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_groundtruth.py [--candidates K] [--correct F]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from ctxmatch_lib.datasets.base import EpipolarGT, FlowGT, HomographyGT
from ctxmatch_lib.groundtruth import label_matches
from _common import best_of


def _shapes(rng, n):
    scale = rng.uniform(2.0, 12.0, n)
    ang = rng.uniform(0, np.pi, n)
    c, s = np.cos(ang), np.sin(ang)
    R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    D = np.zeros((n, 2, 2))
    D[:, 0, 0], D[:, 1, 1] = scale, scale * rng.uniform(0.6, 1.0, n)
    return R @ D


def _candidates(rng, k, n, correct):
    m = np.c_[rng.integers(0, n, k), rng.integers(0, n, k)]
    good = rng.random(k) < correct
    m[good, 1] = m[good, 0]
    return m


def planar(rng, k, correct):
    n = k
    H = np.array([[0.9, 0.1, 30.0], [-0.05, 1.1, 10.0], [1e-4, 5e-5, 1.0]])
    k1 = rng.uniform(0, 800, (n, 2))
    h = np.c_[k1, np.ones(n)] @ H.T
    k2 = h[:, :2] / h[:, 2:] + rng.normal(0, 1.0, (n, 2))
    s1 = _shapes(rng, n)
    return k1, k2, s1, s1 * 1.05, _candidates(rng, k, n, correct), HomographyGT(H=H)


def nonplanar(rng, k, correct):
    n = k
    f = 700.0
    Kc = np.array([[f, 0, 400], [0, f, 300], [0, 0, 1.0]])
    X = np.c_[rng.uniform(-4, 4, (n, 2)), rng.uniform(6, 14, n)]
    a = 0.1
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([-1.0, 0.1, 0.2])
    x1 = X @ Kc.T
    x2 = (X @ R.T + t) @ Kc.T
    k1, k2 = x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(Kc)
    F = Ki.T @ tx @ R @ Ki
    hand = rng.choice(n, 40, replace=False)
    s1 = _shapes(rng, n)
    gt = EpipolarGT(F=F, pts1=k1[hand], pts2=k2[hand])
    return k1, k2 + rng.normal(0, 1.0, (n, 2)), s1, s1, _candidates(rng, k, n, correct), gt


def flow(rng, k, correct):
    n = k
    h, w = 480, 640
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    fl = np.stack([5 + 0.05 * xx + 4 * np.sin(yy / 60), -3 + 0.03 * yy + 4 * np.cos(xx / 80)], axis=2)
    k1 = np.c_[rng.uniform(0, w - 1, n), rng.uniform(0, h - 1, n)]
    d = fl[np.rint(k1[:, 1]).astype(int), np.rint(k1[:, 0]).astype(int)]
    s1 = _shapes(rng, n)
    return k1, k1 + d + rng.normal(0, 1.0, (n, 2)), s1, s1, _candidates(rng, k, n, correct), FlowGT(flow12=fl)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=15000)
    ap.add_argument("--correct", type=float, default=0.3, help="fraction of near-true candidates")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print(f"K = {args.candidates} candidates, {args.correct:.0%} near-true; best of {args.repeat} (seconds)")
    print(f"{'kind':<10} {'D':>9} {'B':>9} {'C':>9} {'B/D':>6} {'C/D':>6}  |B| |C| |D|")
    for name, make in (("planar", planar), ("nonplanar", nonplanar), ("flow", flow)):
        k1, k2, s1, s2, m, gt = make(rng, args.candidates, args.correct)
        times, counts = {}, {}
        for meth in ("D", "B", "C"):
            t, lab = best_of(lambda: label_matches(k1, k2, m, gt, method=meth, shapes1=s1, shapes2=s2), args.repeat)
            times[meth], counts[meth] = t, int(lab.sum())
        print(f"{name:<10} {times['D']:9.4f} {times['B']:9.4f} {times['C']:9.4f} "
              f"{times['B'] / times['D']:6.2f} {times['C'] / times['D']:6.2f}  "
              f"{counts['B']} {counts['C']} {counts['D']}")


if __name__ == "__main__":
    main()
