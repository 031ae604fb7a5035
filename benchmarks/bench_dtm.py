"""DTM speed on the planted-outlier case (issue 3): ratios against the author's port and the Delaunay floor.

Prints, for 1500 and 5000 matches (640x480, 40 % inliers, 0.5 px noise): the median DTM time over a few
seeds, its speed-up over the author's public Python port as measured on the project machine (0.52 s and
2.77 s), the time spent inside the Delaunay triangulations DTM performs (its floor; ``calls`` counts the
triangulations extracted, from scratch or after inserting B into the triangulation of V), DTM's ratio to that
floor, and precision / recall. Run: ``.venv/bin/python benchmarks/bench_dtm.py``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from ctxmatch_lib.dtm import boundary as _boundary
from ctxmatch_lib.dtm import dtm
from ctxmatch_lib.dtm import triangulation as _triangulation
from ctxmatch_lib.synthetic import planted_homography_matches

PORT_SECONDS = {1500: 0.52, 5000: 2.77}  # author's Python port, measured on the project machine
SEEDS = (0, 1, 2)
REPEATS = 5


class _DelaunayClock:
    """Adds up the time spent building Delaunay triangulations: the methods of ``IncrementalDelaunay``
    (OpenCV ``Subdiv2D`` insertions and triangle extraction, Qhull as fallback), through which every
    triangulation DTM performs goes."""

    _METHODS = ("__init__", "add", "simplices")

    def __init__(self):
        self.seconds = 0.0
        self.calls = 0
        self._orig = {name: getattr(_triangulation.IncrementalDelaunay, name) for name in self._METHODS}

    def __enter__(self):
        clock = self

        def timed(orig, count):
            def wrapper(*args, **kwargs):
                t0 = time.perf_counter()
                try:
                    return orig(*args, **kwargs)
                finally:
                    clock.seconds += time.perf_counter() - t0
                    clock.calls += count
            return wrapper

        for name, orig in self._orig.items():
            setattr(_triangulation.IncrementalDelaunay, name, timed(orig, int(name == "simplices")))
        return self

    def __exit__(self, *exc):
        for name, orig in self._orig.items():
            setattr(_triangulation.IncrementalDelaunay, name, orig)


def main() -> int:
    assert _boundary.IncrementalDelaunay is _triangulation.IncrementalDelaunay  # every Delaunay goes through it
    print(f"{'K':>5} {'dtm ms':>8} {'port ms':>8} {'speed-up':>8} {'delaunay ms':>11} {'calls':>5} "
          f"{'dtm/floor':>9} {'P':>6} {'R':>6} {'P1':>6} {'R1':>6}")
    for k, port in PORT_SECONDS.items():
        times, floors, calls, pr = [], [], [], []
        for seed in SEEDS:
            p = planted_homography_matches(k, 0.4, noise=0.5, image_size=(640, 480), rng=seed)
            args = (p.kpts1, p.kpts2, p.matches, p.scores)
            kw = dict(image_size1=p.image_size, image_size2=p.image_size)
            best = np.inf
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                res = dtm(*args, **kw)
                best = min(best, time.perf_counter() - t0)
            with _DelaunayClock() as clock:
                dtm(*args, **kw)
            times.append(best)
            floors.append(clock.seconds)
            calls.append(clock.calls)
            keep1 = res.removed_at == 0
            pr.append((p.is_inlier[res.keep].mean(), res.keep[p.is_inlier].mean(),
                       p.is_inlier[keep1].mean(), keep1[p.is_inlier].mean()))
        t, f = float(np.median(times)), float(np.median(floors))
        prec, rec, prec1, rec1 = np.mean(pr, axis=0)
        print(f"{k:>5} {t * 1e3:>8.1f} {port * 1e3:>8.0f} {port / t:>7.1f}x {f * 1e3:>11.1f} "
              f"{int(np.median(calls)):>5} {t / f:>8.2f}x {prec:>6.3f} {rec:>6.3f} {prec1:>6.3f} {rec1:>6.3f}")
    print("dtm ms: best of", REPEATS, "runs, median over seeds", SEEDS, "; P/R: DTM2 output, P1/R1: DTM1 output")
    return 0


if __name__ == "__main__":
    sys.exit(main())
