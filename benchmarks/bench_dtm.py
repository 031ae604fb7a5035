"""DTM speed on the planted-outlier case: ratios against the Delaunay floor and, when its checkout
is given, the author's port, both measured in this run.

Prints, for 1500 and 5000 matches (640x480, 40 % inliers, 0.5 px noise): DTM's CPU time (one thread; the
median of ``--repeat`` runs per seed, then the median over the seeds), the time spent inside the Delaunay
triangulations DTM performs (its floor; ``calls`` counts the triangulations extracted, from scratch or after
inserting B into the triangulation of V), DTM's ratio to that floor, and precision / recall. With
``--port PATH`` (a checkout of github fb82/DTM, GPL-3: run in its own process by ``--port-python``, never
imported, never a dependency) the same inputs also go through the port, ``--repeat`` times per seed inside
its process (its CPU time, one thread, the median kept): printed are its median over the seeds, our speed-up
(the median over the seeds of the per-seed ratios) and the worst seed's ratio; without it, no speed-up is
printed. Both are CPU times, so that other load on the machine skews the ratio less.
Run: ``.venv/bin/python benchmarks/bench_dtm.py [--port PATH --port-python PY] [--repeat N]``.
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
from ctxmatch_lib.testing import planted_homography_matches

SIZES = (1500, 5000)
SEEDS = (0, 1, 2)
REPEATS = 5

# The port's driver of bench_dtm_real (same input and call) timing ``argv[4]`` calls in one process: the CPU
# time of each call, one thread.
_PORT_REPEAT_DRIVER = r"""
import sys, time
import numpy as np
import torch
sys.path.insert(0, sys.argv[1] + "/src")
import dtm as port
d = np.load(sys.argv[2])
cpu = []
for _ in range(int(sys.argv[4])):
    pipe = {"img": [str(d["image1"]), str(d["image2"])],
            "kp": [torch.from_numpy(d["kpts1"]), torch.from_numpy(d["kpts2"])],
            "m_idx": torch.from_numpy(d["matches"]), "m_val": torch.from_numpy(d["scores"]),
            "m_mask": torch.ones(len(d["matches"]), dtype=torch.bool)}
    c0 = time.process_time()
    label = port.dtm(pipe, prepare_data=port.prepare_data_shaped)
    cpu.append(time.process_time() - c0)
keep = np.zeros(len(d["matches"]), bool) if label is None else np.asarray(label) <= 0
np.savez(sys.argv[3], keep=keep, cpu=np.asarray(cpu))
"""


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
                t0 = time.process_time()
                try:
                    return orig(*args, **kwargs)
                finally:
                    clock.seconds += time.process_time() - t0
                    clock.calls += count
            return wrapper

        for name, orig in self._orig.items():
            setattr(_triangulation.IncrementalDelaunay, name, timed(orig, int(name == "simplices")))
        return self

    def __exit__(self, *exc):
        for name, orig in self._orig.items():
            setattr(_triangulation.IncrementalDelaunay, name, orig)


def _port_seconds(port: Path, python: str, p, work: Path, repeat: int) -> float:
    """Median CPU seconds of ``repeat`` calls of the port's DTM on planted case ``p`` in one process."""
    import cv2

    image = work / f"blank-{p.image_size[0]}x{p.image_size[1]}.png"  # the port reads the sizes from images
    if not image.exists():
        cv2.imwrite(str(image), np.zeros(p.image_size[::-1], np.uint8))
    inp, out, driver = work / "in.npz", work / "out.npz", work / "driver.py"
    np.savez(inp, image1=str(image), image2=str(image), kpts1=np.asarray(p.kpts1, np.float32),
             kpts2=np.asarray(p.kpts2, np.float32), matches=p.matches.astype(np.int64),
             scores=p.scores.astype(np.float32))
    driver.write_text(_PORT_REPEAT_DRIVER)
    env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    subprocess.run([python, str(driver), str(port), str(inp), str(out), str(repeat)], check=True, env=env)
    return float(np.median(np.load(out)["cpu"]))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=Path, help="checkout of github fb82/DTM (holds src/dtm.py)")
    parser.add_argument("--port-python", default=sys.executable, help="interpreter of the port's environment")
    parser.add_argument("--repeat", type=int, default=REPEATS,
                        help=f"timed calls per seed, ours and the port's, the median kept (default {REPEATS})")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be a positive integer, got {args.repeat}")
    if args.port is not None and not (args.port / "src" / "dtm.py").is_file():
        parser.error(f"--port {args.port} holds no src/dtm.py")
    assert _boundary.IncrementalDelaunay is _triangulation.IncrementalDelaunay  # every Delaunay goes through it
    with_port = args.port is not None
    print(f"{'K':>5} {'dtm ms':>8} " + (f"{'port ms':>8} {'speed-up':>8} {'worst':>6} " if with_port else "")
          + f"{'delaunay ms':>11} {'calls':>5} {'dtm/floor':>9} {'P':>6} {'R':>6} {'P1':>6} {'R1':>6}")
    for k in SIZES:
        times, floors, calls, pr, ports = [], [], [], [], []
        for seed in SEEDS:
            p = planted_homography_matches(k, 0.4, noise=0.5, image_size=(640, 480), rng=seed)
            args_ = (p.kpts1, p.kpts2, p.matches, p.scores)
            kw = dict(image_size1=p.image_size, image_size2=p.image_size)
            dtm(*args_, **kw)  # untimed: numba kernels load on the first call
            runs = []
            for _ in range(args.repeat):
                t0 = time.process_time()
                res = dtm(*args_, **kw)
                runs.append(time.process_time() - t0)
            with _DelaunayClock() as clock:
                dtm(*args_, **kw)
            times.append(float(np.median(runs)))
            floors.append(clock.seconds)
            calls.append(clock.calls)
            keep1 = res.removed_at == 0
            pr.append((p.is_inlier[res.keep].mean(), res.keep[p.is_inlier].mean(),
                       p.is_inlier[keep1].mean(), keep1[p.is_inlier].mean()))
            if with_port:
                with tempfile.TemporaryDirectory() as tmp:
                    ports.append(_port_seconds(args.port, args.port_python, p, Path(tmp), args.repeat))
        t, f = float(np.median(times)), float(np.median(floors))
        prec, rec, prec1, rec1 = np.mean(pr, axis=0)
        ratios = np.asarray(ports) / np.asarray(times) if with_port else None
        port = (f"{np.median(ports) * 1e3:>8.0f} {np.median(ratios):>7.1f}x {ratios.min():>5.1f}x " if with_port
                else "")
        print(f"{k:>5} {t * 1e3:>8.1f} {port}{f * 1e3:>11.1f} "
              f"{int(np.median(calls)):>5} {t / f:>8.2f}x {prec:>6.3f} {rec:>6.3f} {prec1:>6.3f} {rec1:>6.3f}")
        if with_port:
            print("      per seed (ours / port ms): " + ", ".join(
                f"{seed}: {a * 1e3:.1f} / {b * 1e3:.0f}" for seed, a, b in zip(SEEDS, times, ports)))
    print(f"dtm ms: CPU time, median of {args.repeat} runs per seed, median over seeds {SEEDS}; P/R: DTM2 output, "
          "P1/R1: DTM1 output"
          + (f"; port ms: the port's CPU time in its own process (one thread), median of {args.repeat} calls per "
             "seed, median over the seeds; speed-up: median over the seeds of port / ours, worst: the smallest"
             if with_port else "; no speed-up without --port (a ratio to a peer is only printed when measured in "
                               "this run)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
