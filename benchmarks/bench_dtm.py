"""DTM speed on the planted-outlier case (issue 3): ratios against the Delaunay floor and, when its checkout
is given, the author's port, both measured in this run.

Prints, for 1500 and 5000 matches (640x480, 40 % inliers, 0.5 px noise): the median DTM time over a few
seeds, the time spent inside the Delaunay triangulations DTM performs (its floor; ``calls`` counts the
triangulations extracted, from scratch or after inserting B into the triangulation of V), DTM's ratio to that
floor, and precision / recall. With ``--port PATH`` (a checkout of github fb82/DTM, GPL-3: run in its own
process by ``--port-python``, never imported, never a dependency) the same inputs also go through the port,
whose median CPU time and our speed-up over it are printed; without it, no speed-up is printed.
Run: ``.venv/bin/python benchmarks/bench_dtm.py [--port PATH --port-python PY]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ctxmatch_lib.dtm import boundary as _boundary
from ctxmatch_lib.dtm import dtm
from ctxmatch_lib.dtm import triangulation as _triangulation
from ctxmatch_lib.synthetic import planted_homography_matches

SIZES = (1500, 5000)
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


def _port_seconds(port: Path, python: str, p, work: Path) -> float:
    """CPU seconds of the port's DTM on planted case ``p`` (its driver is bench_dtm_real's)."""
    import cv2

    from bench_dtm_real import _PORT_DRIVER  # the one driver of the port, next to this script

    image = work / f"blank-{p.image_size[0]}x{p.image_size[1]}.png"  # the port reads the sizes from images
    if not image.exists():
        cv2.imwrite(str(image), np.zeros(p.image_size[::-1], np.uint8))
    inp, out, driver = work / "in.npz", work / "out.npz", work / "driver.py"
    np.savez(inp, image1=str(image), image2=str(image), kpts1=np.asarray(p.kpts1, np.float32),
             kpts2=np.asarray(p.kpts2, np.float32), matches=p.matches.astype(np.int64),
             scores=p.scores.astype(np.float32))
    driver.write_text(_PORT_DRIVER)
    env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    subprocess.run([python, str(driver), str(port), str(inp), str(out)], check=True, env=env)
    return float(np.load(out)["cpu"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=Path, help="checkout of github fb82/DTM (holds src/dtm.py)")
    parser.add_argument("--port-python", default=sys.executable, help="interpreter of the port's environment")
    args = parser.parse_args(argv)
    if args.port is not None and not (args.port / "src" / "dtm.py").is_file():
        parser.error(f"--port {args.port} holds no src/dtm.py")
    assert _boundary.IncrementalDelaunay is _triangulation.IncrementalDelaunay  # every Delaunay goes through it
    with_port = args.port is not None
    print(f"{'K':>5} {'dtm ms':>8} " + (f"{'port ms':>8} {'speed-up':>8} " if with_port else "")
          + f"{'delaunay ms':>11} {'calls':>5} {'dtm/floor':>9} {'P':>6} {'R':>6} {'P1':>6} {'R1':>6}")
    for k in SIZES:
        times, floors, calls, pr, ports = [], [], [], [], []
        for seed in SEEDS:
            p = planted_homography_matches(k, 0.4, noise=0.5, image_size=(640, 480), rng=seed)
            args_ = (p.kpts1, p.kpts2, p.matches, p.scores)
            kw = dict(image_size1=p.image_size, image_size2=p.image_size)
            best = np.inf
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                res = dtm(*args_, **kw)
                best = min(best, time.perf_counter() - t0)
            with _DelaunayClock() as clock:
                dtm(*args_, **kw)
            times.append(best)
            floors.append(clock.seconds)
            calls.append(clock.calls)
            keep1 = res.removed_at == 0
            pr.append((p.is_inlier[res.keep].mean(), res.keep[p.is_inlier].mean(),
                       p.is_inlier[keep1].mean(), keep1[p.is_inlier].mean()))
            if with_port:
                with tempfile.TemporaryDirectory() as tmp:
                    ports.append(_port_seconds(args.port, args.port_python, p, Path(tmp)))
        t, f = float(np.median(times)), float(np.median(floors))
        prec, rec, prec1, rec1 = np.mean(pr, axis=0)
        port = f"{np.median(ports) * 1e3:>8.0f} {np.median(ports) / t:>7.1f}x " if with_port else ""
        print(f"{k:>5} {t * 1e3:>8.1f} {port}{f * 1e3:>11.1f} "
              f"{int(np.median(calls)):>5} {t / f:>8.2f}x {prec:>6.3f} {rec:>6.3f} {prec1:>6.3f} {rec1:>6.3f}")
    print("dtm ms: best of", REPEATS, "runs, median over seeds", SEEDS, "; P/R: DTM2 output, P1/R1: DTM1 output"
          + ("; port ms: the port's CPU time in its own process (one thread), median over the seeds" if with_port
             else "; no speed-up without --port (a ratio to a peer is only printed when measured in this run)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
