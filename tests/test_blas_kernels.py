"""The embedded features and evaluation rows do not depend on the CPU they run on.

numpy (its ufunc loops: AVX-512, AVX2 or baseline), the C library (FMA or plain variants of ``exp``, ``sin``,
``atan2``, … behind numpy's baseline loops and numba), numba (code generated for the host CPU), OpenCV (its
SSE4 / AVX2 / AVX-512 builds and Intel IPP) and OpenBLAS (its kernel) all pick code by CPU at run time, and
their float results differ in the last bits. A decision that hinged on them (a threshold, a nearest neighbour,
a sort with ties, a histogram bin, a rounding to a descriptor byte) would change with the CPU, and the
committed figures would not regenerate byte for byte elsewhere. Here, from an empty cache (features included),
in one subprocess per emulated CPU generation (``benchmarks/bench_blas_kernels.py``'s ``GENERATIONS``: the
default, AVX2 / Haswell where the host has it, SSE4 / Nehalem, SSE3 / Core 2 with OpenBLAS's Prescott
kernel), the keypoints, frames, angles and descriptor bytes of every embedded HarrisZ and SIFT setup on one
pair, and the evaluation rows of every filter under three models (no model, 1SAC, and MAGSAC with its
geometry: inliers, corner error, epipolar share) on one embedded pair of each kind (:data:`PAIRS`), with two feature setups (SIFT/RootSIFT, and HarrisZ with OriNet/SOSNet, whose
networks run in numpy) and the paper-best-overlap blob setup of the tables, must be identical (the corner
error to 1e-9: ``bench_blas_kernels.ROW_RTOL`` says why).

Every generation's run also traces numpy's ufuncs with AVX-512 loops (``benchmarks/bench_cpu_paths.py``):
no call from the library may reach one, directly or through scipy (``tests/test_cpu_paths.py`` says why).

The check runs on x86-64 (the switches name x86-64 code paths); elsewhere it skips with the reason. A CPU can
only emulate older generations than its own: on an AVX2 host, AVX-512 code is not exercised, and the AVX2
generation is the default run itself, so it is not run twice.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

FEATURES = ["sift-rootsift", "harrisz-sosnet"]
#: Setups compared by their features only (their descriptors are the other transcendental paths: dominant
#: gradient orientation with SIFT on patches, and sGLOH2).
FEATURES_ONLY = ["harrisz-rootsift", "harrisz-rootsgloh2"]
#: The blob setup of the tables whose candidate sets reach LMR's and LLT's knife edges.
BLOBS = ["paper-best-overlap"]
#: One pair of each kind; planar/lab/1-5 is where LLT kept 302 matches under the SkylakeX kernels and 252
#: under Nehalem before its products left BLAS, nonplanar/horse where LMR moved by 4-6 points of precision.
PAIRS = ["planar/lab/1-5", "nonplanar/horse", "depth/motorcycle"]
BENCH = Path(__file__).resolve().parents[1] / "benchmarks"

_WORKER = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, sys.argv[1])
    import numpy as np
    from bench_blas_kernels import ROW_KEYS, ROW_VALUES, blas_architecture, feature_arrays
    from bench_cpu_paths import offending, traced
    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs

    out, features, only, blobs, pair_ids = sys.argv[2], *map(json.loads, sys.argv[3:7])
    with traced() as hits:  # numpy's ufuncs with AVX-512 loops, counted where the library reaches them
        pairs = select_pairs("embedded", pair_ids=pair_ids)
        df = evaluate_cached(pairs, features=features, blobs=blobs, filters="all",
                             models=("none", "1sac", "magsac"), cache=False, progress=False)
        arrays = feature_arrays(pairs[:1], features + only)
    df[ROW_KEYS + ROW_VALUES].to_parquet(out + ".parquet")
    np.savez(out + ".npz", **arrays)
    print(json.dumps({"arch": blas_architecture(), "avx512_ufuncs": sorted(map(list, offending(hits)))}))
""")


def _run(bench, generation: str, tmp: Path):
    import pandas as pd

    env = bench.generation_env(generation, str(tmp / generation), os.environ.get("NUMBA_CACHE_DIR",
                                                                                str(tmp / "numba")))
    out = tmp / generation
    proc = subprocess.run([sys.executable, "-c", _WORKER, str(BENCH), str(out),
                           *(json.dumps(v) for v in (FEATURES, FEATURES_ONLY, BLOBS, PAIRS))],
                          env=env, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, f"{generation}: the evaluation failed:\n{proc.stderr[-3000:]}"
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    arch, reached = report["arch"], report["avx512_ufuncs"]
    assert not reached, f"{generation}: the library reaches numpy ufuncs with AVX-512 loops: {reached}"
    with np.load(out.with_suffix(".npz")) as z:
        feats = {k: z[k] for k in z.files}
    return arch, feats, pd.read_parquet(out.with_suffix(".parquet"))


def test_features_and_rows_identical_under_every_cpu_generation(tmp_path, load_benchmark):
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip(f"the switches name x86-64 code paths; this is {platform.machine()}")
    from concurrent.futures import ThreadPoolExecutor

    bench = load_benchmark("bench_blas_kernels")
    # The host's own generation (avx2 on an AVX2 CPU) would repeat the default run: it is left out.
    generations = [g for g in bench.GENERATIONS if bench.runnable(g) and g != bench.host_generation()]
    # One subprocess per generation, as many at once as there are cores (each runs on one BLAS thread).
    with ThreadPoolExecutor(max_workers=max(1, min(len(generations), os.cpu_count() or 1))) as pool:
        results = dict(zip(generations, pool.map(lambda g: _run(bench, g, tmp_path), generations)))
    ref_arch, ref_feats, ref = results["default"]
    assert len(ref) > 0 and set(ref.model) == {"none", "1sac", "magsac"} and ref.method.nunique() >= 17, \
        (len(ref), sorted(set(ref.method)))
    assert len(ref_feats) == 2 * 4 * len(FEATURES + FEATURES_ONLY)
    problems = []
    for g, (arch, feats, df) in results.items():
        if g == "default":
            continue
        for what, lines in (("feature arrays", bench.diff_arrays(ref_feats, feats)),
                            ("rows", bench.diff_rows(ref, df))):
            if lines:
                problems.append(f"default (OpenBLAS {ref_arch}) vs {g} (OpenBLAS {arch}): {len(lines)} {what} "
                                "differ\n" + "\n".join(lines[:40]))
    assert not problems, "\n".join(problems)
