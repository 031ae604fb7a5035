"""Time and peak memory of ``geometry.fit_homography`` next to ``cv2.findHomography(method=0)``.

Both fit the least-squares homography of the same noisy correspondences (all inliers), at 2000, 6000 and
20 000 points. Each size runs in a fresh process so that its peak resident memory (``ru_maxrss``, less
the process's baseline after imports and data) is its own. Prints the times, their ratio, the extra memory
and the transfer error of each fit. Run: ``.venv/bin/python benchmarks/bench_geometry.py [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

_CHILD = r"""
import json, resource, sys, time
import numpy as np, cv2
from ctxmatch_lib.geometry import apply_homography, fit_homography

n, repeat = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
H = np.array([[0.9, -0.1, 30.0], [0.08, 1.05, -12.0], [1e-4, -6e-5, 1.0]])
p1 = rng.uniform(0, 1000, (n, 2))
p2 = apply_homography(H, p1) + rng.normal(0, 0.5, (n, 2))
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

def best(fn):
    t = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter(); out = fn(); t = min(t, time.perf_counter() - t0)
    return t, out

which = sys.argv[3]
if which == "ours":
    t, Hf = best(lambda: fit_homography(p1, p2))
else:
    t, (Hf, _) = best(lambda: cv2.findHomography(p1.astype(np.float64), p2.astype(np.float64), method=0))
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base
err = float(np.median(np.linalg.norm(apply_homography(Hf, p1) - apply_homography(H, p1), axis=1)))
print(json.dumps({"t": t, "mem_mib": peak / 1024, "err_px": err}))
"""


def run(n: int, which: str, repeat: int, threads: int) -> dict:
    import os

    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "OPENBLAS_NUM_THREADS": str(threads),
           "MKL_NUM_THREADS": str(threads)}
    out = subprocess.run([sys.executable, "-c", _CHILD, str(n), str(repeat), which], capture_output=True,
                         text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2000 and 6000 points only, 3 repeats")
    ap.add_argument("--threads", type=int, default=1,
                    help="BLAS/OpenMP threads of both fits (default 1: a multi-threaded SVD of a 9-column "
                         "matrix only spins, badly so on a loaded machine)")
    args = ap.parse_args(argv)
    sizes = (2000, 6000) if args.quick else (2000, 6000, 20000)
    repeat = 3 if args.quick else 5
    import cv2

    print(f"fit_homography vs cv2.findHomography(method=0), OpenCV {cv2.__version__}, best of {repeat}, "
          f"{args.threads} BLAS thread(s)")
    print(f"{'points':>7} {'ours (ms)':>10} {'OpenCV (ms)':>12} {'ratio':>7} {'ours extra MiB':>15} "
          f"{'OpenCV extra MiB':>17} {'ours err px':>12} {'OpenCV err px':>14}")
    for n in sizes:
        a, b = run(n, "ours", repeat, args.threads), run(n, "opencv", repeat, args.threads)
        print(f"{n:>7} {1e3 * a['t']:>10.2f} {1e3 * b['t']:>12.2f} {a['t'] / b['t']:>7.2f} {a['mem_mib']:>15.1f} "
              f"{b['mem_mib']:>17.1f} {a['err_px']:>12.4f} {b['err_px']:>14.4f}")


if __name__ == "__main__":
    main()
