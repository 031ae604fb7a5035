"""Extraction time of HarrisZ and RootsGLOH2 as ratios to SIFT+RootSIFT, and the memory of RootsGLOH2 blob
matching ("HarrisZ and RootsGLOH2 each at most 3x SIFT+RootSIFT's extraction time on an 800x640
image (Oxford graf)"; "n = m = 8000 within 2.5 GB").

All timings are best-of-N wall times of the same process on Oxford graf img1 (800x640, from $CTXMATCH_DATA;
without it, skimage's camera resized to 800x640, said so in the output), no feature cache:

* SIFT+RootSIFT (``sift-rootsift``): the peer, OpenCV SIFT detection and description;
* HarrisZ detection alone (:func:`ctxmatch_lib.features.harrisz.harrisz`);
* SIFT+RootsGLOH2 (``sift-rootsgloh2``): the same SIFT detection, RootsGLOH2 description;
* HarrisZ+RootsGLOH2 and HarrisZ+RootSIFT presets, whole extraction, for reference;
* with ``--deep`` and torch/kornia installed, the deep presets (stand-in weights) too.

Then, in a fresh process, blob matching (paper-best) of n = m = 8000 RootsGLOH2-like descriptors with the
sGLOH2 rotation-min distance hook: time and peak RSS.
Run: ``.venv/bin/python benchmarks/bench_features.py [--quick] [--deep] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np


def load_graf():
    from ctxmatch_lib.features import load_image

    root = os.environ.get("CTXMATCH_DATA")
    path = os.path.join(root, "planar", "oxford", "graf", "img1.png") if root else None
    if path and os.path.isfile(path):
        return load_image(path), "Oxford graf img1"
    import cv2
    from skimage.data import camera

    return cv2.resize(camera(), (800, 640), interpolation=cv2.INTER_AREA), "skimage camera resized (no CTXMATCH_DATA)"


def best_of(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def speed(repeat: int, deep: bool) -> None:
    from ctxmatch_lib.features import FEATURE_PRESETS, extract_features
    from ctxmatch_lib.features.harrisz import harrisz

    img, what = load_graf()
    print(f"{what}: {img.shape[1]}x{img.shape[0]}, best of {repeat}, feature cache off")
    runs = [
        ("SIFT+RootSIFT (peer)", lambda: extract_features(img, FEATURE_PRESETS["sift-rootsift"], cache_dir=False)),
        ("HarrisZ detection", lambda: harrisz(img, max_keypoints=8000)),
        ("SIFT+RootsGLOH2", lambda: extract_features(img, FEATURE_PRESETS["sift-rootsgloh2"], cache_dir=False)),
        ("HarrisZ+RootsGLOH2", lambda: extract_features(img, FEATURE_PRESETS["harrisz-rootsgloh2"], cache_dir=False)),
        ("HarrisZ+RootSIFT", lambda: extract_features(img, FEATURE_PRESETS["harrisz-rootsift"], cache_dir=False)),
    ]
    if deep:
        try:
            import kornia  # noqa: F401
            import torch  # noqa: F401
        except ImportError:
            print("  (--deep: torch/kornia not installed, deep presets skipped)")
        else:
            for name in ("sift-hardnet2", "sift-sosnet", "harrisz-hardnet2", "harrisz-sosnet"):
                cfg = FEATURE_PRESETS[name]
                runs.append((f"{name} (stand-in)", lambda cfg=cfg: extract_features(img, cfg, cache_dir=False)))
    for _, fn in runs[:1]:
        fn()  # warm-up: OpenCV and numpy initialisation
    peer = None
    targets = {"HarrisZ detection": 3.0, "SIFT+RootsGLOH2": 3.0}
    for label, fn in runs:
        t, out = best_of(fn, repeat)
        peer = t if peer is None else peer
        ratio = t / peer
        tgt = f"   (target <= {targets[label]:.0f}x: {'met' if ratio <= targets[label] else 'NOT met'})" \
            if label in targets else ""
        print(f"  {label:34s} {len(out):5d} kpts {t * 1e3:8.1f} ms   ratio {ratio:5.2f}x{tgt}")


CHILD = r"""
import resource, sys, time
import numpy as np
from ctxmatch_lib.blob import BLOB_PRESETS, blob_matching
from ctxmatch_lib.features.sgloh import SGLOH_DIM, SGLOH2Distance, sgloh_rotate
n = int(sys.argv[1])
rng = np.random.default_rng(0)
def halves(k):
    h = np.abs(rng.normal(size=(k, 2, 128))).astype(np.float32)
    h /= np.linalg.norm(h, axis=2, keepdims=True) * np.sqrt(2)
    return h.reshape(k, SGLOH_DIM)
d1, d2 = halves(n), halves(n)
shared = rng.choice(n, n // 2, replace=False)
d2[: n // 2] = sgloh_rotate(d1[shared], 3) + 0.01 * halves(n // 2)  # rotated noisy copies
k1, k2 = rng.uniform(0, 1000, (n, 2)), rng.uniform(0, 1000, (n, 2))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
out = blob_matching(d1, d2, kpts1=k1, kpts2=k2, distance=SGLOH2Distance(), **BLOB_PRESETS["paper-best"].kwargs())
t1 = time.perf_counter()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"{len(out)} {t1 - t0:.2f} {base / 2**20:.3f} {peak / 2**20:.3f}")
"""


def memory(n: int) -> None:
    out = subprocess.run([sys.executable, "-c", CHILD, str(n)], capture_output=True, text=True, check=True)
    k, secs, base, peak = out.stdout.split()
    print(f"RootsGLOH2 blob matching, n = m = {n}, paper-best, sGLOH2 distance (16 rotations): {k} candidates in "
          f"{float(secs):.1f} s; peak RSS {float(peak):.2f} GiB (inputs alone {float(base):.2f} GiB; "
          "target <= 2.5 GB)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="one repeat and n = 2000 for the memory run")
    ap.add_argument("--deep", action="store_true", help="also time the deep presets (needs torch and kornia)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    speed(1 if args.quick else args.repeat, args.deep)
    memory(2000 if args.quick else 8000)


if __name__ == "__main__":
    main()
