"""Speed and memory of blob matching against its floor, the float32 GEMM ``d1 @ d2.T``.

For n = m = 5000 and 8000 planted RootSIFT-like descriptors (d = 128) it times, in the same process and
interleaved (round-robin, ``--repeat`` rounds, median of each):

- the float32 GEMM ``d1 @ d2.T`` with ``--threads`` BLAS threads: the floor of any exhaustive matcher
  (into an output allocated once, so that only the product is timed, not the page faults of a new array);
- OpenCV's ``BFMatcher(NORM_L2).knnMatch(k=2)`` with ``--threads`` OpenCV threads (when cv2 is installed);
- blob matching with the ``baseline`` (f = Ω, f' = 1, D≥), ``paper-best`` (FGINN by pixels) and
  ``paper-best-overlap`` (FGINN by overlap) presets, with the default pass (``BlobContext.product``:
  on AVX-512 CPUs the compiled product fused with the scan) and, where that is the fused one, again with the
  BLAS GEMM tiles (``[tiles]``, ``product="tiles"``), the same candidates;
- with ``--sgloh``, blob matching with the RootsGLOH2 rotation distance (``SGLOH2Distance``, d = 256)
  against that distance's own product (the hook over the whole matrix), which is its floor.

and prints each time with its ratio to the floor. Blob matching runs on one thread whatever ``--threads``
says (the fused product is single-threaded; the GEMM tiles run on one BLAS thread). The tiles go through
SciPy's ``sgemm`` with ``beta = 1`` into a buffer the scan zeroes as it reads
(``ctxmatch_lib._numerics.blas.accumulate_product``); the floor, NumPy's ``matmul``, pays OpenBLAS's zeroing pass over
its output (in the tiles at 5000, about 3 of 48 ms). Times are CPU process times
by default (``--wall`` for wall-clock): on a shared machine they are skewed less by other processes. First
(before the timed runs) the peak RSS of ``paper-best`` at n = m = 20000 in a fresh process, and what f = Ω
does there (the baseline, in the same process: it runs while the 16-bit codes of D fit in
``max_dense_bytes``, 1 GiB, up to n = m = 23 170, and fails fast above).

With ``--breakdown``, one more call per preset and size (default pass) with each compiled stage timed, the
fused pass (``product_scan``) or the GEMM tiles and their scan (the numbers behind docs/blob-matching.md).

With ``--warm-malloc``, the script runs again with glibc keeping freed memory mapped
(``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_``), so that blob matching's arrays cost no page faults,
as the floor's output allocated once costs none. The baseline writes 16-bit codes of all of D (50 MB at
5000, 128 MB at 8000) into a buffer blob matching keeps from one call to the next
(``ctxmatch_lib.blob.free_workspace`` drops it), so only its first call (the slowest round) faults those
pages in: in the virtual machine these numbers come from, that cost up to 300 ms more in some runs than in
others (the host takes freed guest memory back). Before that buffer, every call paid it, and the
baseline's median depended on the rounds it hit.

Run: ``.venv/bin/python benchmarks/bench_blob.py [--sizes 5000 8000] [--threads 1] [--repeat 5] [--quick]
[--breakdown] [--warm-malloc]``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits


def rootsift_like(n: int, m: int, d: int = 128, seed: int = 0):
    """Non-negative unit descriptors; image 2 holds noisy copies of half of image 1 plus distractors."""
    rng = np.random.default_rng(seed)
    d1 = np.abs(rng.normal(size=(n, d))).astype(np.float32)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    shared = rng.choice(n, m // 2, replace=False)
    d2 = np.abs(rng.normal(size=(m, d))).astype(np.float32)
    d2[: m // 2] = d1[shared] + 0.25 * np.abs(rng.normal(size=(m // 2, d))).astype(np.float32) / np.sqrt(d)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    k1 = rng.uniform(0, 1000, (n, 2))
    k2 = rng.uniform(0, 1000, (m, 2))
    return d1, d2, k1, k2


def radii(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform(2, 12, n)


def timed(clock):
    def run(fn):
        t0 = clock()
        fn()
        return clock() - t0
    return run


def interleaved(jobs: dict, repeat: int, clock, spread: dict | None = None) -> dict:
    """Median time of each job, the jobs run round-robin so that a busy spell hits them alike, each round
    starting one job later (so that no job always follows the same one: the call after ``knnMatch`` paid up to
    twice its time in page faults at 8000, whichever it was); ``spread``, when given, receives each job's
    (fastest, slowest) round."""
    run = timed(clock)
    names = list(jobs)
    times = {name: [] for name in names}
    for r in range(repeat):
        for k in range(len(names)):
            name = names[(r + k) % len(names)]
            times[name].append(run(jobs[name]))
    if spread is not None:
        spread.update({name: (min(t), max(t)) for name, t in times.items()})
    return {name: float(np.median(t)) for name, t in times.items()}


def speed(n: int, threads: int, repeat: int, clock, sgloh: bool) -> None:
    from ctxmatch_lib.blob import BLOB_PRESETS, BlobContext, blob_matching
    from ctxmatch_lib.blob._fused_kernels import fused_product_fast

    d1, d2, k1, k2 = rootsift_like(n, n)
    s1, s2 = radii(n, 1), radii(n, 2)
    presets = ("baseline", "paper-best", "paper-best-overlap")
    for name in presets:  # warm-up: numba kernels load or compile, imports happen
        blob_matching(d1[:300], d2[:300], kpts1=k1[:300], kpts2=k2[:300], shapes1=s1[:300], shapes2=s2[:300],
                      **BLOB_PRESETS[name].kwargs())
    jobs = {}
    with threadpool_limits(threads):
        # The product alone, into an output allocated and touched once: a fresh n x m array per call adds
        # its page faults (at 8000, 126 ms of product took 130-430 ms with them, varying run to run).
        product = np.empty((n, n), np.float32)
        product.fill(0)
        jobs["float32 GEMM d1 @ d2.T"] = lambda: np.matmul(d1, d2.T, out=product)
        try:
            import cv2

            cv2.setNumThreads(threads)
            bf = cv2.BFMatcher(cv2.NORM_L2)
            bf.knnMatch(d1[:300], d2[:300], k=2)
            jobs["OpenCV BFMatcher.knnMatch(k=2)"] = lambda: bf.knnMatch(d1, d2, k=2)
        except ImportError:
            pass
        sizes = {}
        # The default pass (BlobContext.product "auto": fused on AVX-512 CPUs), and the BLAS tiles beside it.
        products = ("auto", "tiles") if fused_product_fast() else ("auto",)
        for name in presets:
            kw = BLOB_PRESETS[name].kwargs()
            for prod in products:
                def job(kw=kw, name=name, prod=prod):
                    BlobContext.product = prod
                    try:
                        sizes[name] = len(blob_matching(d1, d2, kpts1=k1, kpts2=k2, shapes1=s1, shapes2=s2, **kw))
                    finally:
                        BlobContext.product = "auto"
                jobs[f"blob {name}" + (" [tiles]" if prod == "tiles" else "")] = job
        spread: dict = {}
        t = interleaved(jobs, repeat, clock, spread)
    floor = t["float32 GEMM d1 @ d2.T"]
    print(f"n = m = {n}, d = 128, {threads} thread(s), median of {repeat} ({clock.__name__}; the fastest and "
          "slowest round in brackets):")
    for name, sec in t.items():
        extra = ""
        if name.startswith("blob "):
            extra = f"   {sizes[name[5:].removesuffix(' [tiles]')]} candidates"
            if "OpenCV BFMatcher.knnMatch(k=2)" in t:
                extra += f", {sec / t['OpenCV BFMatcher.knnMatch(k=2)']:.2f}x knnMatch"
        lo, hi = spread[name]
        print(f"  {name:34s} {sec * 1e3:9.1f} ms [{lo * 1e3:.0f}-{hi * 1e3:.0f}]   {sec / floor:5.2f}x GEMM{extra}")
    if sgloh:
        sgloh_speed(n, threads, repeat, clock)


#: The compiled stages of the L2 path timed by ``--breakdown``: (module of ``ctxmatch_lib.blob``, name).
STAGES = (("_fused_kernels", "product_scan"), ("_kernels", "scan_tile"), ("_kernels", "certify_lines"),
          ("_select_kernels", "prefilter_lists"),
          ("_select_kernels", "greedy_sorted"), ("_walk_kernels", "greedy_dense"), ("_kernels", "first_allowed"),
          ("_kernels", "next_allowed"), ("_walk_kernels", "next_in_lines"))


def breakdown(n: int, clock) -> None:
    """Where blob matching's time goes: the GEMM tiles, each compiled stage and the rest (NumPy glue), per
    preset, for one call after a warm-up (the stages are wrapped for the call, then restored)."""
    from ctxmatch_lib.blob import BLOB_PRESETS, blob_matching
    from ctxmatch_lib.blob import _pass

    d1, d2, k1, k2 = rootsift_like(n, n)
    s1, s2 = radii(n, 1), radii(n, 2)
    spent: dict = {}

    def timed_stage(name, fn):
        def run(*args, **kwargs):
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] = spent.get(name, 0.0) + clock() - t0
        return run

    product = _pass.accumulate_product  # the GEMM tiles (sgemm into the tile buffer) of product="tiles"

    print(f"n = m = {n}: where the time goes ({clock.__name__}, one call after a warm-up):")
    for name in ("baseline", "paper-best", "paper-best-overlap"):
        kw = dict(kpts1=k1, kpts2=k2, shapes1=s1, shapes2=s2, **BLOB_PRESETS[name].kwargs())
        blob_matching(d1, d2, **kw)
        modules = {mod: importlib.import_module(f"ctxmatch_lib.blob.{mod}") for mod, _ in STAGES}
        saved = {(mod, stage): getattr(modules[mod], stage) for mod, stage in STAGES}
        spent.clear()
        try:
            for (mod, stage), fn in saved.items():
                setattr(modules[mod], stage, timed_stage(stage, fn))
            _pass.accumulate_product = timed_stage("GEMM tiles", product)
            t0 = clock()
            blob_matching(d1, d2, **kw)
            total = clock() - t0
        finally:
            _pass.accumulate_product = product
            for (mod, stage), fn in saved.items():
                setattr(modules[mod], stage, fn)
        parts = ", ".join(f"{k} {v * 1e3:.0f}" for k, v in spent.items() if v * 1e3 >= 0.5)
        print(f"  {name:20s} {total * 1e3:7.1f} ms: {parts}, the rest {(total - sum(spent.values())) * 1e3:.0f} (ms)")


def sgloh_speed(n: int, threads: int, repeat: int, clock) -> None:
    from ctxmatch_lib.blob import BLOB_PRESETS, blob_matching
    from ctxmatch_lib.features.sgloh import SGLOH2Distance

    d1, d2, k1, k2 = rootsift_like(n, n, d=256, seed=3)
    hook = SGLOH2Distance()
    kw = BLOB_PRESETS["paper-best"].kwargs()
    blob_matching(d1[:300], d2[:300], kpts1=k1[:300], kpts2=k2[:300], distance=hook, **kw)
    with threadpool_limits(threads):
        t = interleaved({"RootsGLOH2 distance product": lambda: hook(d1, d2),
                         "blob paper-best (RootsGLOH2)": lambda: blob_matching(
                             d1, d2, kpts1=k1, kpts2=k2, distance=hook, **kw)}, repeat, clock)
    floor = t["RootsGLOH2 distance product"]
    for name, sec in t.items():
        print(f"  {name:34s} {sec * 1e3:9.1f} ms   {sec / floor:5.2f}x its product")


CHILD = r"""
import resource, sys, time
import numpy as np
sys.path.insert(0, "benchmarks")
from bench_blob import rootsift_like
from ctxmatch_lib.blob import BLOB_PRESETS, blob_matching
n = int(sys.argv[1])
d1, d2, k1, k2 = rootsift_like(n, n)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
out = blob_matching(d1, d2, kpts1=k1, kpts2=k2, **BLOB_PRESETS["paper-best"].kwargs())
t1 = time.perf_counter()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"{len(out)} {t1 - t0:.2f} {base / 2**20:.3f} {peak / 2**20:.3f}")
t0 = time.perf_counter()
try:
    out = blob_matching(d1, d2, **BLOB_PRESETS["baseline"].kwargs())
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(f"ran: {len(out)} candidates in {time.perf_counter() - t0:.1f} s (wall), peak RSS {peak / 2**20:.2f} GiB")
except MemoryError as exc:
    print(f"fails in {time.perf_counter() - t0:.3f} s: {exc}")
"""


def memory(n: int) -> None:
    out = subprocess.run([sys.executable, "-c", CHILD, str(n)], capture_output=True, text=True, check=True)
    first, second = out.stdout.strip().splitlines()[:2]
    k, secs, base, peak = first.split()
    print(f"n = m = {n}, d = 128, paper-best: {k} candidates in {float(secs):.1f} s (wall); peak RSS "
          f"{float(peak):.2f} GiB (inputs and imports alone {float(base):.2f} GiB)")
    print(f"  f = Ω at this size: {second}")


#: glibc settings of ``--warm-malloc``: allocations from the heap (not one ``mmap`` each), and the heap never
#: trimmed, so that a call's large arrays reuse pages already mapped.
_WARM = {"MALLOC_MMAP_THRESHOLD_": str(2**32), "MALLOC_TRIM_THRESHOLD_": str(2**34)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5000, 8000], help="n = m values (default 5000 8000)")
    ap.add_argument("--threads", type=int, default=1, help="BLAS / OpenCV threads of the GEMM and knnMatch")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds; medians are printed")
    ap.add_argument("--wall", action="store_true", help="wall-clock instead of CPU process time")
    ap.add_argument("--sgloh", action="store_true", help="also RootsGLOH2's rotation distance vs its product")
    ap.add_argument("--memory", type=int, default=20000, help="n = m of the peak-RSS run (0: skip)")
    ap.add_argument("--quick", action="store_true", help="n = 2000, 2 rounds, no memory run")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the GEMM tiles and each compiled stage of one call per preset and size")
    ap.add_argument("--warm-malloc", action="store_true",
                    help="run with glibc keeping freed memory mapped (see the module docstring)")
    args = ap.parse_args()
    if args.warm_malloc and os.environ.get("MALLOC_MMAP_THRESHOLD_") != _WARM["MALLOC_MMAP_THRESHOLD_"]:
        # glibc reads these once, at start-up: run again with them set.
        argv = [sys.executable, *sys.argv]
        os.execve(sys.executable, argv, {**os.environ, **_WARM})
    if args.warm_malloc:
        settings = ", ".join(f"{k}={v}" for k, v in _WARM.items())
        print(f"--warm-malloc: glibc keeps freed memory mapped ({settings})")
    clock = time.perf_counter if args.wall else time.process_time
    if args.quick:
        speed(2000, args.threads, 2, clock, args.sgloh)
        return
    if args.memory:
        # First: Linux keeps a process's peak RSS across exec, so a child started after the timed runs would
        # report this process's larger peak as its own.
        memory(args.memory)
    for n in args.sizes:
        speed(n, args.threads, args.repeat, clock, args.sgloh)
    if args.breakdown:
        with threadpool_limits(args.threads):
            for n in args.sizes:
                breakdown(n, clock)


if __name__ == "__main__":
    main()
