"""Which decisions move with the BLAS kernel: the same computation under several ``OPENBLAS_CORETYPE`` values (issue 31).

numpy's OpenBLAS (a ``DYNAMIC_ARCH`` build) picks its SIMD kernels from the CPU; ``OPENBLAS_CORETYPE`` forces
others (``Prescott``: SSE3, ``Nehalem``: SSE4, ``Sandybridge``: AVX, ``Haswell``: AVX2/FMA, ``SkylakeX``:
AVX-512). Each kernel sums a product in its own order, so float results differ in their last bits; a
decision (keep / reject, a nearest neighbour, a sort with ties) must not follow them. Every computation here
runs in a fresh subprocess per core type (the variable is read when OpenBLAS loads), with one BLAS thread.

Two checks (``--what``):

``rows``
    The embedded evaluation rows as ``notebooks/tables.ipynb`` computes them (``--features``, default the
    three embedded feature setups; blobs ``baseline`` and ``paper-best-overlap``; every filter; models
    ``none`` and ``1sac``; every ``--pair-step``-th embedded pair), from an empty cache (features included)
    in each subprocess. Printed: per core type, the rows whose numbers differ from the first core type's
    (features, blob, pair, method, model and the columns that moved).
``masks``
    Per-filter keep masks on real candidate sets (``CTXMATCH_DATA``; the pairs of ``bench_filters_real.py``,
    ``--pairs N``): the candidate sets are computed once, under the first core type, and every core type's
    subprocess filters the same arrays, so only the filters' own decisions can move. Also printed: whether
    the blob candidate sets themselves differ between core types (computed in each subprocess).

Run::

    CTXMATCH_DATA=/work/shared/data .venv/bin/python benchmarks/bench_blas_kernels.py --what masks --pairs 2
    .venv/bin/python benchmarks/bench_blas_kernels.py --what rows --pair-step 2

The exit status is 1 when anything differs between core types.
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
              "failure", "empty_output", "n_kpts1", "n_kpts2", "n_candidates", "n_gt", "n_gt_star", "error"]
EMBEDDED_FEATURES = ("sift-rootsift", "harrisz-rootsgloh2", "harrisz-sosnet")


def blas_architecture() -> str | None:
    """The core type numpy's OpenBLAS runs with (threadpoolctl), or ``None`` when it is not OpenBLAS."""
    import threadpoolctl

    for info in threadpoolctl.threadpool_info():
        if info.get("internal_api") == "openblas" and "numpy" in info.get("filepath", ""):
            return info.get("architecture")
    return None


def _env(coretype: str | None, cache: str, numba_cache: str) -> dict:
    # numba's machine code does not depend on the BLAS kernel: one cache for every subprocess saves compiling.
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", CTXMATCH_CACHE=cache,
               PYTHONHASHSEED="0")
    env.setdefault("NUMBA_CACHE_DIR", numba_cache)
    env.pop("OPENBLAS_CORETYPE", None)
    if coretype and "+" in coretype:
        # "Haswell+npy-avx2": also numpy's own SIMD dispatch without AVX-512 (NPY_DISABLE_CPU_FEATURES), as
        # on an AVX2 machine; "+npy-base": without AVX2 either. numpy's float64 exp/log/power and float32
        # exp/tanh differ in their last bit between these (not a BLAS matter; issue 31 notes).
        coretype, npy = coretype.split("+", 1)
        env["NPY_DISABLE_CPU_FEATURES"] = {"npy-avx2": "X86_V4 AVX512_ICL AVX512_SPR",
                                           "npy-base": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"}[npy]
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    return env


# --- workers (run in the subprocesses) -------------------------------------------------------------------------

def worker_rows(out: Path, features, pair_step: int, filters: str, pairs: int) -> None:
    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs

    sel = select_pairs("embedded", step=pair_step)[:pairs or None]
    df = evaluate_cached(sel, features=list(features), blobs=["baseline", "paper-best-overlap"],
                         filters=filters.split(",") if filters != "all" else "all", models=("none", "1sac"),
                         cache=False, progress=False)
    df[ROW_KEYS + ROW_VALUES].to_parquet(out)


def worker_features(out: Path, features, pair_step: int, pairs: int) -> None:
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS

    arrays = {}
    for pair in select_pairs("embedded", step=pair_step)[:pairs or None]:
        for name in features:
            for side, f in zip((1, 2), pair_features(pair, FEATURE_PRESETS[name])):
                for field in ("kpts", "desc", "shapes"):
                    arrays[f"{name}|{pair.pair_id}|{side}|{field}"] = np.asarray(getattr(f, field))
    np.savez(out, **arrays)


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
    env = _env(coretype, cache, numba_cache)
    probe = subprocess.run([sys.executable, __file__, "--probe"], env=env, capture_output=True, text=True)
    proc = subprocess.run([sys.executable, __file__] + args_list, env=env, capture_output=True, text=True)
    if proc.returncode:
        raise RuntimeError(f"worker under OPENBLAS_CORETYPE={coretype} failed:\n{proc.stderr[-4000:]}")
    return probe.stdout.strip()


def diff_rows(a, b) -> list[str]:
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
            if not (va == vb or (isinstance(va, float) and np.isnan(va) and np.isnan(vb))):
                moved.append(f"{c} {va} -> {vb}")
        if moved:
            lines.append(f"  {' / '.join(str(r[k]) for k in ROW_KEYS)}: " + "; ".join(moved))
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--what", choices=["rows", "masks", "features"], default="masks")
    parser.add_argument("--coretypes", default=",".join(CORETYPES),
                        help="comma-separated OPENBLAS_CORETYPE values; 'default' = unset (first is the reference); "
                        "'Haswell+npy-avx2' / 'Nehalem+npy-base' also turn off numpy's AVX-512 / AVX2 dispatch")
    parser.add_argument("--features", default=",".join(EMBEDDED_FEATURES), help="rows: feature setups")
    parser.add_argument("--pair-step", type=int, default=2, help="rows: every n-th embedded pair (default 2)")
    parser.add_argument("--max-pairs", type=int, default=0, help="rows: at most this many pairs (0: all)")
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
        worker_rows(args.out, args.features.split(","), args.pair_step, args.filters, args.max_pairs)
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
            print(f"OPENBLAS_CORETYPE={c or '(unset)'}: OpenBLAS core {arch}", flush=True)
        ref = coretypes[0]
        for c in coretypes[1:]:
            a, b = feats[ref], feats[c]
            moved = [k for k in a.files if a[k].shape != b[k].shape or not np.array_equal(a[k], b[k])]
            print(f"\nfeatures {ref or 'default'} vs {c or 'default'}: {len(moved)} of {len(a.files)} arrays differ")
            for k in moved:
                x, y = a[k], b[k]
                what = (f"max |diff| {np.abs(x.astype(float) - y.astype(float)).max():.3g}, "
                        f"{int((x != y).sum())} values" if x.shape == y.shape else f"shape {x.shape} vs {y.shape}")
                print(f"  {k}: {what}")
            status = status or bool(moved)
    elif args.what == "rows":
        import pandas as pd

        frames = {}
        for c in coretypes:
            out = tmp / f"rows_{c or 'default'}.parquet"
            arch = _run(["--worker", "rows", "--out", str(out), "--features", args.features, "--pair-step",
                         str(args.pair_step), "--filters", args.filters, "--max-pairs", str(args.max_pairs)],
                        c, str(tmp / f"cache_{c or 'default'}"), str(tmp / "numba"))
            frames[c] = pd.read_parquet(out)
            print(f"OPENBLAS_CORETYPE={c or '(unset)'}: OpenBLAS core {arch}, {len(frames[c])} rows", flush=True)
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
            print(f"OPENBLAS_CORETYPE={c or '(unset)'}: OpenBLAS core {arch}", flush=True)
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
