"""How often DTM keeps a whole set of matches that agree (small sets; quoted in ``dtm``'s Notes).

For K = 4 ... 300 matches related by the identity, a random similarity (rotation up to 0.5 rad, scale
0.7-1.3 about the image centre) or a random homography (the same plus a perspective part), drawn in the
middle 60 % of a 640 x 480 image, prints per boundary construction the number of draws in which DTM dropped
at least one match, out of the draws whose points stay on both images: with the whole-set rule (the default,
``whole_set_tol=1``) and with DTM alone (``whole_set_tol=None``). The last rows check the rule against
what it must not do: on K random matches (no relation; ``random``) and on K - 1 agreeing matches plus one
random match (``one outlier``, similarity), they count the draws in which the rule kept the whole set. Run:
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


def _draw(kind: str, k: int, rng) -> tuple[np.ndarray, np.ndarray] | None:
    """``k`` matches of one kind, or ``None`` when a point leaves the second image."""
    p = rng.random((k, 2)) * [W * 0.6, H * 0.6] + [W * 0.2, H * 0.2]
    if kind == "random":
        q = rng.random((k, 2)) * [W - 1, H - 1]
    else:
        q = apply_homography(_motion("similarity" if kind == "one outlier" else kind, rng), p)
        if kind == "one outlier":
            q[-1] = rng.random(2) * [W - 1, H - 1]
    if not ((q >= 0).all() and (q[:, 0] <= W - 1).all() and (q[:, 1] <= H - 1).all()):
        return None
    return p, q


def main() -> int:
    print(f"{'matches':<12} {'boundary':<10} {'rule':<5} " + " ".join(f"{k:>6}" for k in SIZES))
    rows = [(kind, boundary, rule) for kind in ("identity", "similarity", "homography")
            for boundary in ("alpha", "keypoints") for rule in (1.0, None)]
    rows += [("random", "alpha", 1.0), ("one outlier", "alpha", 1.0)]
    for kind, boundary, rule in rows:
        rng = np.random.default_rng(0)
        cells = []
        for k in SIZES:
            counted = tried = 0
            for _ in range(DRAWS):
                drawn = _draw(kind, k, rng)
                if drawn is None:
                    continue
                res = dtm(*drawn, np.c_[np.arange(k), np.arange(k)], None, image_size1=(W, H), image_size2=(W, H),
                          boundary=boundary, whole_set_tol=rule)
                tried += 1
                counted += int(res.whole_set if kind in ("random", "one outlier") else not res.keep.all())
            cells.append(f"{counted:>3}/{tried:<2}")
        print(f"{kind:<12} {boundary:<10} {'on' if rule else 'off':<5} " + " ".join(cells), flush=True)
    print("cells: draws in which DTM dropped at least one match (random, one outlier: in which the whole-set rule "
          "kept them all) / draws tried")
    return 0


if __name__ == "__main__":
    sys.exit(main())
