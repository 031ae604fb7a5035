"""How often DTM keeps a whole set of matches that agree (issue 14, small sets; quoted in ``dtm``'s Notes).

For K = 4 ... 300 matches related by the identity, a random similarity (rotation up to 0.5 rad, scale
0.7-1.3 about the image centre) or a random homography (the same plus a perspective part), drawn in the
middle 60 % of a 640 x 480 image, prints per boundary construction the number of draws in which DTM dropped
at least one match, out of the draws whose points stay on both images. Run:
``.venv/bin/python benchmarks/bench_dtm_small_sets.py``.
"""

from __future__ import annotations

import sys

import numpy as np

from ctxmatch_lib.dtm import dtm
from ctxmatch_lib.geometry import apply_homography

W, H = 640, 480
SIZES = (4, 5, 6, 8, 12, 20, 50, 100, 300)
DRAWS = 10


def _motion(kind: str, rng) -> np.ndarray:
    if kind == "identity":
        return np.eye(3)
    a, s = rng.uniform(-0.5, 0.5), rng.uniform(0.7, 1.3)
    m = np.eye(3)
    m[:2, :2] = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    m[:2, 2] = np.array([W / 2, H / 2]) - m[:2, :2] @ [W / 2, H / 2]
    if kind == "homography":
        m[2, :2] = rng.uniform(-4e-4, 4e-4, 2)
    return m


def main() -> int:
    print(f"{'motion':<11} {'boundary':<10} " + " ".join(f"{k:>6}" for k in SIZES))
    for kind in ("identity", "similarity", "homography"):
        for boundary in ("alpha", "keypoints"):
            rng = np.random.default_rng(0)
            cells = []
            for k in SIZES:
                lost = tried = 0
                for _ in range(DRAWS):
                    m = _motion(kind, rng)
                    p = rng.random((k, 2)) * [W * 0.6, H * 0.6] + [W * 0.2, H * 0.2]
                    q = apply_homography(m, p)
                    if not ((q >= 0).all() and (q[:, 0] <= W - 1).all() and (q[:, 1] <= H - 1).all()):
                        continue
                    res = dtm(p, q, np.c_[np.arange(k), np.arange(k)], None, image_size1=(W, H),
                              image_size2=(W, H), boundary=boundary)
                    tried += 1
                    lost += int(not res.keep.all())
                cells.append(f"{lost:>3}/{tried:<2}")
            print(f"{kind:<11} {boundary:<10} " + " ".join(cells), flush=True)
    print("cells: draws in which DTM dropped at least one match / draws tried")
    return 0


if __name__ == "__main__":
    sys.exit(main())
