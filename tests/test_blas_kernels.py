"""The embedded evaluation rows do not depend on the OpenBLAS kernel (issue 31).

numpy's OpenBLAS picks SIMD kernels for the CPU it runs on (a ``DYNAMIC_ARCH`` build); ``OPENBLAS_CORETYPE``
forces others. Each kernel sums a product in its own order, so a decision that hinged on float rounding (a
threshold, a nearest neighbour, a sort with ties) would change with the CPU, and the committed figures would
not regenerate byte for byte elsewhere. Here the evaluation rows of every filter under both models (no
model and 1SAC) on one embedded pair of each kind (:data:`PAIRS`), with two feature setups (SIFT/RootSIFT,
and HarrisZ with AffNet/OriNet/SOSNet, whose networks run in numpy) and the paper-best-overlap blob setup of
the tables, are computed from an empty cache
(features included) in one subprocess per core type that every x86-64 CPU can run: ``Prescott`` (SSE3),
``Nehalem`` (SSE4), ``Haswell`` (AVX2/FMA, where the CPU has it) and the default (whatever the CPU gets,
AVX-512 kernels on such a machine). The rows must be identical.

The check runs on x86-64 with numpy on OpenBLAS; elsewhere it skips with the reason. It does not cover
numpy's own SIMD dispatch (``np.exp`` differs in its last bit between AVX-512 and AVX2 machines), nor
numba's code generation per CPU.
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
#: The blob setup of the tables whose candidate sets reach LMR's and LLT's knife edges (issue 31).
BLOBS = ["paper-best-overlap"]
#: One pair of each kind; planar/lab/1-5 is where LLT kept 302 matches under the SkylakeX kernels and 252
#: under Nehalem before its products left BLAS, nonplanar/horse where LMR moved by 4-6 points of precision.
PAIRS = ["planar/lab/1-5", "nonplanar/horse", "depth/motorcycle"]
KEYS = ["features", "blob", "pair_id", "method", "model"]
VALUES = ["precision", "recall", "recall_star", "ap", "ap_star", "correct", "correct_norm", "output", "failure",
          "empty_output", "n_kpts1", "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "error"]

_WORKER = textwrap.dedent("""
    import json, sys
    import threadpoolctl
    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs

    out, features, blobs, keys, values = sys.argv[1], *map(json.loads, sys.argv[2:6])
    pairs = select_pairs("embedded", pair_ids=json.loads(sys.argv[6]))
    df = evaluate_cached(pairs, features=features, blobs=blobs, filters="all", models=("none", "1sac"),
                         cache=False, progress=False)
    df[keys + values].to_parquet(out)
    arch = [i.get("architecture") for i in threadpoolctl.threadpool_info()
            if i.get("internal_api") == "openblas" and "numpy" in i.get("filepath", "")]
    print(json.dumps(arch[0] if arch else None))
""")


def _numpy_openblas() -> str | None:
    threadpoolctl = pytest.importorskip("threadpoolctl")
    for info in threadpoolctl.threadpool_info():
        if info.get("internal_api") == "openblas" and "numpy" in info.get("filepath", ""):
            return info.get("architecture")
    return None


def _cpu_has(*flags) -> bool:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    have = set(line.split(":", 1)[-1].split())
    return all(f in have for f in flags)


def _coretypes() -> list[str | None]:
    out: list[str | None] = [None, "Prescott", "Nehalem"]
    if _cpu_has("avx2", "fma"):
        out.append("Haswell")
    return out


def _rows(coretype: str | None, tmp: Path):
    import pandas as pd

    label = coretype or "default"
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", CTXMATCH_CACHE=str(tmp / label),
               NUMBA_CACHE_DIR=os.environ.get("NUMBA_CACHE_DIR", str(tmp / "numba")))
    env.pop("OPENBLAS_CORETYPE", None)
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    out = tmp / f"rows_{label}.parquet"
    proc = subprocess.run([sys.executable, "-c", _WORKER, str(out), *(json.dumps(v) for v in
                                                                     (FEATURES, BLOBS, KEYS, VALUES, PAIRS))],
                          env=env, capture_output=True, text=True, timeout=1500)
    assert proc.returncode == 0, f"OPENBLAS_CORETYPE={label}: the evaluation failed:\n{proc.stderr[-3000:]}"
    arch = json.loads(proc.stdout.strip().splitlines()[-1])
    return arch, pd.read_parquet(out)


def _differences(a, b) -> list[str]:
    import pandas as pd

    m = pd.merge(a, b, on=KEYS, how="outer", suffixes=("_a", "_b"), indicator=True)
    lines = []
    for _, r in m.iterrows():
        if r["_merge"] != "both":
            lines.append(f"{tuple(r[k] for k in KEYS)}: only in one run")
            continue
        moved = [f"{c} {r[c + '_a']!r} -> {r[c + '_b']!r}" for c in VALUES
                 if not (r[c + "_a"] == r[c + "_b"] or (isinstance(r[c + "_a"], float) and np.isnan(r[c + "_a"])
                                                         and np.isnan(r[c + "_b"])))]
        if moved:
            lines.append(" / ".join(str(r[k]) for k in KEYS) + ": " + "; ".join(moved))
    return lines


def test_evaluation_rows_identical_under_every_openblas_kernel(tmp_path):
    if platform.machine().lower() not in ("x86_64", "amd64"):
        pytest.skip(f"OPENBLAS_CORETYPE names x86-64 kernels; this is {platform.machine()}")
    if _numpy_openblas() is None:
        pytest.skip("numpy's BLAS is not OpenBLAS (threadpoolctl finds no OpenBLAS in numpy): no kernel to force")
    results = {c: _rows(c, tmp_path) for c in _coretypes()}
    archs = {c or "default": arch for c, (arch, _) in results.items()}
    if len(set(archs.values())) < 2:
        pytest.skip(f"OpenBLAS ignored OPENBLAS_CORETYPE (not a DYNAMIC_ARCH build?): cores {archs}")
    ref_arch, ref = results[None]
    assert len(ref) > 0 and set(ref.model) == {"none", "1sac"} and ref.method.nunique() >= 17, \
        (len(ref), sorted(set(ref.method)))
    problems = []
    for c, (arch, df) in results.items():
        if c is None:
            continue
        lines = _differences(ref, df)
        if lines:
            problems.append(f"default ({ref_arch}) vs OPENBLAS_CORETYPE={c} ({arch}): {len(lines)} rows differ\n  "
                            + "\n  ".join(lines[:40]))
    assert not problems, "\n".join(problems)
