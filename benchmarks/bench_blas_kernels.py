"""Which decisions move with the CPU: the same computation under several emulated x86-64 generations.

Four libraries pick code by CPU at run time, and their float results differ in the last bits: numpy's ufunc
loops (``NPY_DISABLE_CPU_FEATURES``: AVX-512, AVX2 or baseline), the C library's elementary functions that
numpy's baseline loops and numba call (glibc's FMA or plain variants, ``GLIBC_TUNABLES``), numba's code
generation (``NUMBA_CPU_NAME``), OpenCV's SIMD builds and Intel IPP (``OPENCV_CPU_DISABLE``, ``OPENCV_IPP``) and
OpenBLAS's kernels (``OPENBLAS_CORETYPE``). A generation (:data:`GENERATIONS`) sets all of them as a CPU of
that family would (``default``: nothing forced; ``avx2``: Haswell; ``sse4``: Nehalem; ``sse3``: Core 2 /
Prescott, numpy at its x86-64-v2 floor); any other name is one ``OPENBLAS_CORETYPE`` alone (``SkylakeX``,
``Haswell``, ``Sandybridge``, ``Nehalem``, ``Prescott``). A decision (keep / reject, a nearest neighbour, a
sort with ties) must not follow them. Every computation runs in a fresh subprocess per generation (the
variables are read when the libraries load), with one BLAS thread.

Three checks (``--what``):

``rows``
    The embedded evaluation rows as ``notebooks/tables.ipynb`` computes them (``--features``, default the
    three embedded feature setups; blobs ``baseline`` and ``paper-best-overlap``; every filter; models
    ``none`` and ``1sac``; every ``--pair-step``-th embedded pair), from an empty cache (features included)
    in each subprocess. Printed: per generation, the rows whose numbers differ from the first one's
    (features, blob, pair, method, model and the columns that moved).
``features``
    Keypoints, frames, orientations and descriptor bytes of the same pairs, from an empty cache.
``masks``
    Per-filter keep masks on real candidate sets (``CTXMATCH_DATA``; the pairs of ``bench_filters_real.py``,
    ``--pairs N``): the candidate sets are computed once, under the first generation, and every
    generation's subprocess filters the same arrays, so only the filters' own decisions can move. Also
    printed: whether the blob candidate sets themselves differ between generations.

Run::

    .venv/bin/python benchmarks/bench_blas_kernels.py --what features --generations default,sse4 --max-pairs 2
    .venv/bin/python benchmarks/bench_blas_kernels.py --what rows --pair-step 2
    CTXMATCH_DATA=/work/shared/data .venv/bin/python benchmarks/bench_blas_kernels.py --what masks --pairs 2

The exit status is 1 when anything differs between generations.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CORETYPES = ("SkylakeX", "Haswell", "Sandybridge", "Nehalem", "Prescott")
ROW_KEYS = ["features", "blob", "pair_id", "method", "model"]
ROW_VALUES = ["precision", "recall", "recall_star", "ap", "ap_star", "correct", "correct_norm", "output",
              "failure", "empty_output", "n_kpts1", "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "error",
              "model_inliers", "corner_error", "epi_share_mean"]
#: Columns compared to a relative tolerance, not bit for bit: the corner error reads the ground-truth homography
#: of an embedded planar pair, which the dataset generator composes with BLAS and LAPACK products, so it moves
#: with the OpenBLAS kernel in its 13th digit (the geometry tables print 4 decimals of its means).
ROW_RTOL = {"corner_error": 1e-9}
_NPY_AVX512 = "X86_V4 AVX512_ICL AVX512_SPR"
#: Emulated CPU generations: the run-time switch of each library that dispatches by CPU, as a CPU of that
#: family would set it. numpy 2.4's wheels need x86-64-v2 (SSE4.2), so ``sse3`` keeps numpy's baseline loops.
#: OpenCV's names are filtered by :func:`generation_env` to those the host has (it warns about others).
GENERATIONS = {
    "default": {},
    "avx2": {"NPY_DISABLE_CPU_FEATURES": _NPY_AVX512, "NUMBA_CPU_NAME": "haswell", "OPENBLAS_CORETYPE": "Haswell",
             "OPENCV_CPU_DISABLE": "AVX512F,AVX512-SKX", "OPENCV_IPP": "avx2"},
    "sse4": {"NPY_DISABLE_CPU_FEATURES": "X86_V3 " + _NPY_AVX512, "NUMBA_CPU_NAME": "nehalem",
             "OPENBLAS_CORETYPE": "Nehalem", "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX,-AVX2,-FMA,-AVX512F",
             "OPENCV_CPU_DISABLE": "FP16,AVX,AVX2,FMA3,AVX512F,AVX512-SKX", "OPENCV_IPP": "sse42"},
    "sse3": {"NPY_DISABLE_CPU_FEATURES": "X86_V3 " + _NPY_AVX512, "NUMBA_CPU_NAME": "core2",
             "OPENBLAS_CORETYPE": "Prescott", "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX,-AVX2,-FMA,-AVX512F",
             "OPENCV_CPU_DISABLE": "SSSE3,SSE4.1,SSE4.2,POPCNT,FP16,AVX,AVX2,FMA3,AVX512F,AVX512-SKX",
             "OPENCV_IPP": "disabled"},
}
#: The /proc/cpuinfo flag behind each OpenCV feature name of :data:`GENERATIONS`.
_CV_FLAGS = {"SSSE3": "ssse3", "SSE4.1": "sse4_1", "SSE4.2": "sse4_2", "POPCNT": "popcnt", "FP16": "f16c",
             "AVX": "avx", "AVX2": "avx2", "FMA3": "fma", "AVX512F": "avx512f", "AVX512-SKX": "avx512bw"}
#: What a generation needs of the host (a CPU cannot emulate a newer one).
_NEEDS = {"avx2": ("avx2", "fma")}
EMBEDDED_FEATURES = ("sift-rootsift", "harrisz-rootsgloh2", "harrisz-sosnet")


def blas_architecture() -> str | None:
    """The core type numpy's OpenBLAS runs with (threadpoolctl), or ``None`` when it is not OpenBLAS."""
    import threadpoolctl

    for info in threadpoolctl.threadpool_info():
        if info.get("internal_api") == "openblas" and "numpy" in info.get("filepath", ""):
            return info.get("architecture")
    return None


def cpu_flags() -> set[str]:
    """The host's CPU flags (``/proc/cpuinfo``; empty where there is none)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    return set(line.split(":", 1)[-1].split())


def runnable(generation: str) -> bool:
    """Whether this host can emulate ``generation`` (an AVX2 one needs AVX2 and FMA)."""
    flags = cpu_flags()
    return all(f in flags for f in _NEEDS.get(generation, ()))


def host_generation() -> str | None:
    """The generation this host already is, so that emulating it repeats ``default``: ``avx2`` on an AVX2 CPU
    without AVX-512 (numpy, glibc and OpenCV take the same loops; numba and OpenBLAS get another name for the
    same instruction set); ``None`` elsewhere."""
    flags = cpu_flags()
    return "avx2" if runnable("avx2") and "avx512f" not in flags else None


def generation_env(generation: str | None, cache: str, numba_cache: str, base: dict | None = None) -> dict:
    """The environment of a subprocess under ``generation`` (a key of :data:`GENERATIONS`, or one
    ``OPENBLAS_CORETYPE``), with an empty ctxmatch cache at ``cache`` and one BLAS thread.

    ``numba_cache``: numba's machine code is keyed by CPU name, so one folder serves every generation.
    """
    env = dict(os.environ if base is None else base, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               CTXMATCH_CACHE=cache, PYTHONHASHSEED="0")
    env.setdefault("NUMBA_CACHE_DIR", numba_cache)
    for k in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "NUMBA_CPU_NAME", "GLIBC_TUNABLES",
              "OPENCV_CPU_DISABLE", "OPENCV_IPP"):
        env.pop(k, None)
    if generation in GENERATIONS:
        switches = dict(GENERATIONS[generation])
        if "OPENCV_CPU_DISABLE" in switches:
            flags = cpu_flags()
            switches["OPENCV_CPU_DISABLE"] = ",".join(n for n in switches["OPENCV_CPU_DISABLE"].split(",")
                                                      if _CV_FLAGS[n] in flags)
        env.update({k: v for k, v in switches.items() if v})
    elif generation:
        env["OPENBLAS_CORETYPE"] = generation
    return env


# --- workers (run in the subprocesses) -------------------------------------------------------------------------

def worker_rows(out: Path, features, pair_step: int, filters: str, pairs: int, pair_ids=None) -> None:
    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs

    sel = select_pairs("embedded", step=pair_step, pair_ids=pair_ids)[:pairs or None]
    df = evaluate_cached(sel, features=list(features), blobs=["baseline", "paper-best-overlap"],
                         filters=filters.split(",") if filters != "all" else "all", models=("none", "1sac"),
                         cache=False, progress=False)
    df[ROW_KEYS + ROW_VALUES].to_parquet(out)


def feature_arrays(pairs, features) -> dict:
    """``{"preset|pair|side|field": array}``: keypoints, frames, angles and descriptors of ``pairs``."""
    from ctxmatch_lib.evaluation.steps import pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS

    arrays = {}
    for pair in pairs:
        for name in features:
            for side, f in zip((1, 2), pair_features(pair, FEATURE_PRESETS[name])):
                for field in ("kpts", "desc", "shapes", "angles"):
                    arrays[f"{name}|{pair.pair_id}|{side}|{field}"] = np.asarray(getattr(f, field))
    return arrays


def diff_arrays(a, b) -> list[str]:
    """One line per array of the mappings ``a`` and ``b`` that differs in shape or in any value."""
    lines = []
    for k in sorted(set(a) | set(b)):
        if k not in a or k not in b:
            lines.append(f"  {k}: only in one run")
        elif a[k].shape != b[k].shape:
            lines.append(f"  {k}: shape {a[k].shape} vs {b[k].shape}")
        elif not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"):
            x, y = a[k].astype(float), b[k].astype(float)
            lines.append(f"  {k}: {int((x != y).sum())} values, max |diff| {np.nanmax(np.abs(x - y)):.3g}")
    return lines


def worker_features(out: Path, features, pair_step: int, pairs: int) -> None:
    from ctxmatch_lib.evaluation import select_pairs

    np.savez(out, **feature_arrays(select_pairs("embedded", step=pair_step)[:pairs or None], features))


def worker_inputs(out: Path, pairs: int) -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_filters_real import DEFAULT_PAIRS, _inputs

    arrays, meta = {}, []
    for k, (pair, f1, f2, m, s) in enumerate(_inputs(DEFAULT_PAIRS[:pairs], "sift-rootsift", "paper-best-overlap",
                                                     "8000")):
        arrays.update({f"{k}_kpts1": f1.kpts, f"{k}_kpts2": f2.kpts, f"{k}_shapes1": f1.shapes,
                       f"{k}_shapes2": f2.shapes, f"{k}_matches": m, f"{k}_scores": s})
        meta.append({"pair_id": pair.pair_id, "size1": list(pair.image_size1), "size2": list(pair.image_size2)})
    np.savez(out, **arrays)
    out.with_suffix(".json").write_text(json.dumps(meta))


def worker_masks(inputs: Path, out: Path, filters: str) -> None:
    from ctxmatch_lib.filters import FILTERS

    data = np.load(inputs)
    meta = json.loads(inputs.with_suffix(".json").read_text())
    names = list(FILTERS) if filters == "all" else filters.split(",")
    masks = {}
    for k, m in enumerate(meta):
        for name in names:
            keep = FILTERS[name](data[f"{k}_kpts1"], data[f"{k}_kpts2"], data[f"{k}_matches"], data[f"{k}_scores"],
                                 image_size1=tuple(m["size1"]), image_size2=tuple(m["size2"]),
                                 shapes1=data[f"{k}_shapes1"], shapes2=data[f"{k}_shapes2"])
            masks[f"{name}|{m['pair_id']}"] = np.asarray(getattr(keep, "keep", keep), bool)
    np.savez(out, **masks)


# --- driver ------------------------------------------------------------------------------------------------------

def _run(args_list, coretype, cache, numba_cache) -> str:
    env = generation_env(coretype, cache, numba_cache)
    probe = subprocess.run([sys.executable, __file__, "--probe"], env=env, capture_output=True, text=True)
    proc = subprocess.run([sys.executable, __file__] + args_list, env=env, capture_output=True, text=True)
    if proc.returncode:
        raise RuntimeError(f"worker under {coretype or 'default'} failed:\n{proc.stderr[-4000:]}")
    return probe.stdout.strip()


def diff_rows(a, b) -> list[str]:
    """One line per row of ``a`` and ``b`` (frames with :data:`ROW_KEYS` and :data:`ROW_VALUES`) that is in
    one only or whose values differ (NaN equals NaN; :data:`ROW_RTOL` columns to their tolerance): ``"  features / blob / pair / method / model: column
    a -> b; ..."``. Empty when the frames hold the same rows."""
    import pandas as pd

    merged = pd.merge(a, b, on=ROW_KEYS, how="outer", suffixes=("_a", "_b"), indicator=True)
    lines = []
    for _, r in merged.iterrows():
        if r["_merge"] != "both":
            lines.append(f"  {tuple(r[k] for k in ROW_KEYS)}: only in one run")
            continue
        moved = []
        for c in ROW_VALUES:
            va, vb = r[f"{c}_a"], r[f"{c}_b"]
            if not (va == vb or (isinstance(va, float) and np.isnan(va) and np.isnan(vb))
                    or (c in ROW_RTOL and np.isclose(va, vb, rtol=ROW_RTOL[c], atol=0))):
                moved.append(f"{c} {va} -> {vb}")
        if moved:
            lines.append(f"  {' / '.join(str(r[k]) for k in ROW_KEYS)}: " + "; ".join(moved))
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--what", choices=["rows", "masks", "features"], default="masks")
    parser.add_argument("--generations", "--coretypes", dest="coretypes",
                        default=",".join(g for g in GENERATIONS if runnable(g)),
                        help="comma-separated generations (default, avx2, sse4, sse3) or single OPENBLAS_CORETYPE "
                        "values (SkylakeX, Haswell, Sandybridge, Nehalem, Prescott); the first is the reference")
    parser.add_argument("--features", default=",".join(EMBEDDED_FEATURES), help="rows: feature setups")
    parser.add_argument("--pair-step", type=int, default=2, help="rows: every n-th embedded pair (default 2)")
    parser.add_argument("--max-pairs", type=int, default=0, help="rows: at most this many pairs (0: all)")
    parser.add_argument("--pair-ids", default="", help="rows: comma-separated embedded pair ids (default: by --pair-step)")
    parser.add_argument("--filters", default="all", help="comma-separated filters (default all)")
    parser.add_argument("--pairs", type=int, default=2, help="masks: real pairs of bench_filters_real (default 2)")
    parser.add_argument("--keep", type=Path, help="write the per-core-type outputs into this folder")
    parser.add_argument("--reuse-inputs", action="store_true",
                        help="masks: reuse the candidate sets a previous run left in --keep")
    # worker entry points
    parser.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--worker", choices=["rows", "inputs", "masks", "features"], help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--inputs", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.probe:
        print(blas_architecture())
        return 0
    if args.worker == "rows":
        worker_rows(args.out, args.features.split(","), args.pair_step, args.filters, args.max_pairs,
                    args.pair_ids.split(",") if args.pair_ids else None)
        return 0
    if args.worker == "features":
        worker_features(args.out, args.features.split(","), args.pair_step, args.max_pairs)
        return 0
    if args.worker == "inputs":
        worker_inputs(args.out, args.pairs)
        return 0
    if args.worker == "masks":
        worker_masks(args.inputs, args.out, args.filters)
        return 0

    coretypes = [None if c == "default" else c for c in args.coretypes.split(",")]
    tmp = Path(tempfile.mkdtemp(prefix="blas_kernels_")) if args.keep is None else args.keep
    tmp.mkdir(parents=True, exist_ok=True)
    status = 0
    if args.what == "features":
        feats = {}
        for c in coretypes:
            out = tmp / f"features_{c or 'default'}.npz"
            arch = _run(["--worker", "features", "--out", str(out), "--features", args.features, "--pair-step",
                         str(args.pair_step), "--max-pairs", str(args.max_pairs)],
                        c, str(tmp / f"fcache_{c or 'default'}"), str(tmp / "numba"))
            feats[c] = np.load(out)
            print(f"{c or 'default'}: OpenBLAS core {arch}", flush=True)
        ref = coretypes[0]
        for c in coretypes[1:]:
            a, b = feats[ref], feats[c]
            lines = diff_arrays({k: a[k] for k in a.files}, {k: b[k] for k in b.files})
            print(f"\nfeatures {ref or 'default'} vs {c or 'default'}: {len(lines)} of {len(a.files)} arrays differ")
            print("\n".join(lines))
            status = status or bool(lines)
    elif args.what == "rows":
        import pandas as pd

        frames = {}
        for c in coretypes:
            out = tmp / f"rows_{c or 'default'}.parquet"
            arch = _run(["--worker", "rows", "--out", str(out), "--features", args.features, "--pair-step",
                         str(args.pair_step), "--filters", args.filters, "--max-pairs", str(args.max_pairs),
                         "--pair-ids", args.pair_ids],
                        c, str(tmp / f"cache_{c or 'default'}"), str(tmp / "numba"))
            frames[c] = pd.read_parquet(out)
            print(f"{c or 'default'}: OpenBLAS core {arch}, {len(frames[c])} rows", flush=True)
        ref = coretypes[0]
        for c in coretypes[1:]:
            lines = diff_rows(frames[ref], frames[c])
            print(f"\n{ref or 'default'} vs {c or 'default'}: {len(lines)} rows differ")
            print("\n".join(lines))
            status = status or bool(lines)
    else:
        if not os.environ.get("CTXMATCH_DATA"):
            print("CTXMATCH_DATA is not set", file=sys.stderr)
            return 2
        cache = os.environ.get("CTXMATCH_CACHE", "")  # features may come from the user's cache
        inputs = {}
        for c in coretypes:
            inputs[c] = tmp / f"inputs_{c or 'default'}.npz"
            if args.reuse_inputs and inputs[c].is_file():
                continue
            _run(["--worker", "inputs", "--out", str(inputs[c]), "--pairs", str(args.pairs)], c, cache, str(tmp / "numba"))
        ref = coretypes[0]
        a = np.load(inputs[ref])
        for c in coretypes[1:]:
            b = np.load(inputs[c])
            moved = [k for k in a.files if a[k].shape != b[k].shape or not np.array_equal(a[k], b[k])]
            print(f"blob candidate sets {ref} vs {c}: " + ("identical" if not moved else "DIFFER in " + ", ".join(moved)))
            for k in moved:
                if k.endswith("_matches"):
                    sa = {tuple(r) for r in a[k]}
                    sb = {tuple(r) for r in b[k]}
                    print(f"    {k}: {len(sa)} vs {len(sb)} rows, {len(sa - sb)} / {len(sb - sa)} only in one")
            status = status or bool(moved)
        masks = {}
        for c in coretypes:
            out = tmp / f"masks_{c or 'default'}.npz"
            arch = _run(["--worker", "masks", "--inputs", str(inputs[ref]), "--out", str(out), "--filters",
                         args.filters], c, cache, str(tmp / "numba"))
            masks[c] = np.load(out)
            print(f"{c or 'default'}: OpenBLAS core {arch}", flush=True)
        for c in coretypes[1:]:
            print(f"\nkeep masks {ref or 'default'} vs {c or 'default'} (same candidate sets):")
            differ = 0
            for k in masks[ref].files:
                x, y = masks[ref][k], masks[c][k]
                n = int((x != y).sum())
                if n:
                    print(f"  {k}: {n} of {len(x)} rows differ (kept {x.sum()} vs {y.sum()})")
                differ += bool(n)
            print(f"  {differ} of {len(masks[ref].files)} (filter, pair) masks differ")
            status = status or bool(differ)
    print(f"\noutputs in {tmp}")
    return int(status)


if __name__ == "__main__":
    sys.exit(main())
