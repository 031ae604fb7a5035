"""Time the numpy inference of the learned filters and of the deep presets' networks against torch, same run.

Learned filters: OANet and ACNe (weights trained here) on the planted-outlier case of the tests (40 %
inliers under a homography, 60 % uniform outliers, 640 x 480, informative scores), numpy (the default engine)
and torch (``backend="torch"``), with DTM timed as a floor; precision and recall of the numpy keep mask and
the largest logit difference between the engines are printed too.

Deep presets: OriNet angles and the HardNet2 / SOSNet stand-in descriptors (HardTFeat, TFeat) of ``--keypoints``
random oriented frames on scikit-image's camera photo, whole path (patch sampling + network): numpy against
kornia's sampler and modules (``backend="torch"``), with the largest difference.

Each timing is the best of ``--repeat`` runs after one warm-up call (loading and imports out of the way). Both
engines run on one thread (``OMP_NUM_THREADS=1`` for numpy's BLAS; ``torch.set_num_threads(1)``); ratios are
numpy time / torch time, measured in the same run.

    OMP_NUM_THREADS=1 python benchmarks/bench_learned.py [--sizes 500 2000] [--keypoints 2000] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import planted_homography_matches
from _common import best_of

LEARNED = ["oanet", "acne"]


def _filters(sizes, repeat, seed):
    from ctxmatch_lib.filters.learned import learned_logits

    print("Learned filters (weights trained here, not the authors'):")
    print(f"{'filter':>7} {'K':>6} {'numpy [ms]':>10} {'torch [ms]':>10} {'np/torch':>8} {'np/DTM':>7} "
          f"{'max|dlogit|':>11} {'precision':>9} {'recall':>7}")
    for k in sizes:
        pm = planted_homography_matches(k, 0.4, noise=0.5, image_size=(640, 480), informative_scores=True, rng=seed)
        args = (pm.kpts1, pm.kpts2, pm.matches, pm.scores)
        kw = dict(image_size1=pm.image_size, image_size2=pm.image_size)
        t_dtm, _ = best_of(lambda: FILTERS["dtm"](*args, **kw), repeat, warmup=True)
        for name in LEARNED:
            t_np, lg_np = best_of(lambda: learned_logits(name, *args, **kw), repeat, warmup=True)
            t_t, lg_t = best_of(lambda: learned_logits(name, *args, backend="torch", **kw), repeat, warmup=True)
            keep = lg_np > 0
            tp = int((keep & pm.is_inlier).sum())
            prec, rec = tp / max(int(keep.sum()), 1), tp / max(int(pm.is_inlier.sum()), 1)
            print(f"{name:>7} {k:>6} {1e3 * t_np:>10.1f} {1e3 * t_t:>10.1f} {t_np / t_t:>8.2f} {t_np / t_dtm:>7.2f} "
                  f"{np.abs(lg_np - lg_t).max():>11.2e} {prec:>9.3f} {rec:>7.3f}")


def _deep(n, repeat, seed):
    from skimage.data import camera

    from ctxmatch_lib.features.deep import deep_descriptors, orinet_angles

    img = camera().astype(np.float32)
    rng = np.random.default_rng(seed)
    kp = np.c_[rng.uniform(0, img.shape[1] - 1, n), rng.uniform(0, img.shape[0] - 1, n)]
    ang = rng.uniform(-np.pi, np.pi, n)
    c, s = np.cos(ang), np.sin(ang)
    A = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2) * np.exp(rng.uniform(0.4, 3.7, n))[:, None, None]
    print(f"\nDeep presets' networks, {n} keypoints on a 512 x 512 image (patch sampling + network):")
    print(f"{'network':>30} {'numpy [s]':>9} {'torch [s]':>9} {'np/torch':>8} {'max|diff|':>10}")
    runs = [("OriNet (angle, rad)", lambda b: orinet_angles(img, kp, A, weights="OriNet.pth", backend=b))]
    for desc, net, w in (("hardnet2", "hardtfeat", "HardTFeat.pth"), ("sosnet", "tfeat", "tfeat-liberty.params")):
        runs.append((f"{net} ({desc} stand-in)", lambda b, desc=desc, net=net, w=w: deep_descriptors(
            img, kp, A, descriptor=desc, net=net, weights=w, backend=b)))
    for label, fn in runs:
        t_np, a = best_of(lambda: fn("numpy"), repeat, warmup=True)
        t_t, b = best_of(lambda: fn("torch"), repeat, warmup=True)
        diff = np.abs(np.angle(np.exp(1j * (a - b)))) if a.ndim == 1 else np.abs(a - b)
        print(f"{label:>30} {t_np:>9.2f} {t_t:>9.2f} {t_np / t_t:>8.2f} {diff.max():>10.2e}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 2000])
    parser.add_argument("--keypoints", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        import kornia  # noqa: F401
        import torch
    except ImportError:
        print("torch/kornia are not installed (pip install 'ctxmatch[kornia]'): no engine to compare with.")
        return 0
    torch.set_num_threads(1)
    _filters(args.sizes, args.repeat, args.seed)
    _deep(args.keypoints, args.repeat, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
