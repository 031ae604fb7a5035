"""``ctxmatch match`` as a user runs it (a fresh process), beside OpenCV's own SIFT + ratio test + MAGSAC script
measured in the same run, with the peak memory of both sides.

The pair is two 6 MP images of Strecha's castle-P19 (3072 x 2048, from ``$CTXMATCH_DATA``); the folder is eight
pairs of consecutive castle-P19 images (nine images). Every run is a new process, with
``PYTHONDONTWRITEBYTECODE`` unset (as on a user's machine) and the median wall time of ``--repeat`` runs:

* **OpenCV script** (the peer): ``cv2.SIFT_create(8000)`` on both images, ``BFMatcher.knnMatch`` with the 0.8
  ratio test, ``cv2.findFundamentalMat(USAC_MAGSAC, 1 px, 0.9999, 100 000 iterations)``; in folder mode one
  process looping over the pairs (imports once, each image extracted for each of its pairs).
* **ctxmatch, warm**: ``ctxmatch match A B --model magsac`` on a pair it has not seen (an empty feature cache),
  the compiled kernels in numba's cache (``ctxmatch warmup`` ran first).
* **ctxmatch, cold**: the same with an empty cache folder, numba's included (the first run on a machine).
* **ctxmatch, again**: the same pair a second time (its features cached).
* **folder mode**: ``ctxmatch match --pairs pairs.txt --images DIR --model magsac``, kernels warm, features not.

Targets (printed as ratios against the peer measured in this run): warm at most 1.5x the script, cold at most
2x warm, the folder mode at least as fast per pair as the script pair after pair.
Run: ``CTXMATCH_DATA=../shared/data .venv/bin/python benchmarks/bench_match_cli.py [--repeat N]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

OPENCV_SCRIPT = textwrap.dedent("""
    import sys
    import cv2
    import numpy as np

    sift = cv2.SIFT_create(8000)
    matcher = cv2.BFMatcher()
    for line in open(sys.argv[1]):
        a, b = line.split()
        f = [sift.detectAndCompute(cv2.imread(p, cv2.IMREAD_GRAYSCALE), None) for p in (a, b)]
        good = [m for m, n in matcher.knnMatch(f[0][1], f[1][1], k=2) if m.distance < 0.8 * n.distance]
        p1 = np.float64([f[0][0][m.queryIdx].pt for m in good])
        p2 = np.float64([f[1][0][m.trainIdx].pt for m in good])
        F, mask = cv2.findFundamentalMat(p1, p2, cv2.USAC_MAGSAC, 1.0, 0.9999, 100000)
        print(len(f[0][0]), len(f[1][0]), len(good), int(mask.sum()) if mask is not None else 0)
""")


def run(cmd, env) -> tuple[float, float, str]:
    """``(seconds, peak RSS in GB, stdout)`` of one process."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    out, err = proc.stdout.read(), proc.stderr.read()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed:\n{err[-2000:]}")
    return seconds, usage.ru_maxrss / 1024**2, out


def median_of(label: str, make, repeat: int) -> float:
    runs = [make(i) for i in range(repeat)]
    t = statistics.median(r[0] for r in runs)
    mem = max(r[1] for r in runs)
    print(f"  {label:<46} {t:6.2f} s  (runs {', '.join(f'{r[0]:.2f}' for r in runs)}; peak {mem:.2f} GB)",
          flush=True)
    return t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    root = os.environ.get("CTXMATCH_DATA")
    scene = Path(root or "", "calibrated", "strecha", "castle-P19", "images")
    if not root or not scene.is_dir():
        sys.exit("needs CTXMATCH_DATA with calibrated/strecha/castle-P19 (the 6 MP pairs)")
    images = sorted(scene.glob("*.jpg"))
    base = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "CTXMATCH_CACHE",
                                                              "NUMBA_CACHE_DIR")}
    py = sys.executable
    ctx = [py, "-m", "ctxmatch_lib.cli", "match"]
    work = Path(tempfile.mkdtemp(prefix="bench_match_cli-"))
    script = work / "opencv_match.py"
    script.write_text(OPENCV_SCRIPT)
    # Warm kernels: one folder compiled once by `ctxmatch warmup`, shared by the warm runs.
    kernels = work / "kernels"
    run([py, "-m", "ctxmatch_lib.cli", "warmup"], {**base, "CTXMATCH_CACHE": str(work / "warmup-cache"),
                                                      "NUMBA_CACHE_DIR": str(kernels)})
    import cv2

    print(f"ctxmatch match against the OpenCV script (OpenCV {cv2.__version__}), {os.cpu_count()} cores, "
          f"median of {args.repeat} fresh processes")

    def new_cache(tag, i, *, warm_kernels=True):
        env = {**base, "CTXMATCH_CACHE": str(work / f"{tag}-{i}")}
        if warm_kernels:
            env["NUMBA_CACHE_DIR"] = str(kernels)
        return env

    # One pair: the repeats take different pairs, so that neither side reads anything it has seen.
    pairs = [(images[2 * i], images[2 * i + 1]) for i in range(args.repeat)]
    print(f"one pair (3072 x 2048): {', '.join(f'{a.stem}-{b.stem}' for a, b in pairs)}")
    pair_files = []
    for i, (a, b) in enumerate(pairs):
        f = work / f"pair{i}.txt"
        f.write_text(f"{a} {b}\n")
        pair_files.append(f)
    peer = median_of("OpenCV script", lambda i: run([py, str(script), str(pair_files[i])], base), args.repeat)
    warm = median_of("ctxmatch match, new pair, kernels compiled",
                     lambda i: run([*ctx, str(pairs[i][0]), str(pairs[i][1]), "--model", "magsac", "--no-progress",
                                    "--out", str(work / f"warm{i}.npz")], new_cache("warm", i)), args.repeat)
    cold = median_of("ctxmatch match, empty cache (numba's included)",
                     lambda i: run([*ctx, str(pairs[i][0]), str(pairs[i][1]), "--model", "magsac", "--no-progress",
                                    "--out", str(work / f"cold{i}.npz")], new_cache("cold", i, warm_kernels=False)),
                     args.repeat)
    again = median_of("ctxmatch match, the same pair again",
                      lambda i: run([*ctx, str(pairs[i][0]), str(pairs[i][1]), "--model", "magsac", "--no-progress",
                                     "--out", str(work / f"again{i}.npz")], new_cache("warm", i)), args.repeat)

    # The folder: eight pairs of consecutive images.
    folder_pairs = [(images[i].name, images[i + 1].name) for i in range(8)]
    listing = work / "pairs.txt"
    listing.write_text("".join(f"{a} {b}\n" for a, b in folder_pairs))
    absolute = work / "pairs_abs.txt"
    absolute.write_text("".join(f"{scene / a} {scene / b}\n" for a, b in folder_pairs))
    print(f"folder: {len(folder_pairs)} pairs of consecutive images ({folder_pairs[0][0]} ... {folder_pairs[-1][1]})")
    peer_folder = median_of("OpenCV script, pair after pair", lambda i: run([py, str(script), str(absolute)], base),
                            args.repeat)
    folder = median_of("ctxmatch match --pairs, kernels compiled",
                       lambda i: run([*ctx, "--pairs", str(listing), "--images", str(scene), "--model", "magsac",
                                      "--no-progress", "--out", str(work / f"folder{i}")], new_cache("folder", i)),
                       args.repeat)
    n = len(folder_pairs)
    print("ratios (target):")
    print(f"  warm / OpenCV script          {warm / peer:5.2f}  (at most 1.5)")
    print(f"  cold / warm                   {cold / warm:5.2f}  (at most 2)")
    print(f"  again / OpenCV script         {again / peer:5.2f}")
    print(f"  folder per pair / script's    {folder / n:5.2f} s / {peer_folder / n:5.2f} s = "
          f"{(folder / n) / (peer_folder / n):5.2f}  (at most 1)")
    print(f"(scratch files in {work})")


if __name__ == "__main__":
    main()
