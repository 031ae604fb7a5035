"""``ctxmatch sweep``: run (or resume) a grid of dataset × features × blob setup × filter × model, one Parquet
row per unit and method, and print the best setups by mAP; flags and cache shared with ``ctxmatch eval``."""

from __future__ import annotations

import argparse

from . import error
from ._engine_args import add_engine_arguments, plan, resolve_args

DESCRIPTION = """\
Sweep blob-matching setups (default: the 2430 of Sec. 5.2) and optionally filters and model steps over a
dataset. Each (pair, features) unit's rows are cached as an atomic Parquet part (shared with 'ctxmatch eval'),
so an interrupted run resumes with no lost or duplicated rows and a rerun is instant; features, candidate
sets, FGINN overlap tables and filter masks are cached too.
AP ranks a setup's candidates by score with the --gt labels (default D): 'ap' against the setup's own correct
candidates, 'ap_star' against those of all setups on the pair; the printed mAP (Fig. 5) averages ap_star."""

EXAMPLE = """\
examples:
  ctxmatch sweep                                   # embedded dataset, full grid, SIFT+RootSIFT
  ctxmatch sweep --features sift-rootsift,sift --pairs 6 --jobs 2 --out sweep.parquet
  ctxmatch sweep --blob paper-best,baseline --filters dtm,th --model none,1sac
  CTXMATCH_DATA=/path/to/data ctxmatch sweep --dataset planar,nonplanar --jobs 2
  ctxmatch sweep --dask tcp://scheduler:8786       # scale out on a Dask cluster
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "sweep",
        help="sweep blob setups (the 2430-setup grid of Sec. 5.2), filters and models; cached and resumable",
        description=DESCRIPTION,
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_engine_arguments(p, blob="grid", filters="none", model="none", out="sweep.parquet")
    p.add_argument("--top", type=int, default=10, help="print the N best setups by mAP (default: 10)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import pandas as pd

    from ..cache import write_parquet_atomic
    from ..evaluation.cache import FORMAT
    from ..evaluation.run import run_units
    from ..report.blob import blob_map

    # Every argument (the output path included) is checked before any work, with the flag's name.
    if args.top < 1:
        return error("sweep", f"--top must be positive, got {args.top}")
    settings, msg = resolve_args(args)
    if msg:
        return error("sweep", msg)
    units, msg = plan(args, settings)
    if msg:
        return error("sweep", msg)
    try:
        df = run_units(units, cache_dir=args.cache_dir, n_jobs=args.jobs, dask=args.dask,
                       progress=not args.no_progress, recompute=args.recompute, desc="ctxmatch sweep")
    except (ConnectionError, ImportError) as exc:
        return error("sweep", f"--dask: {exc}")
    except MemoryError as exc:
        return error("sweep", f"out of memory: {exc}")
    meta = {"datasets": args.dataset, "features": {u.features_name: u.features.key() for u in units},
            "blobs": len(units[0].blobs), "filters": list(units[0].filters), "models": list(units[0].models),
            "pairs": len({(u.dataset, u.pair.pair_id) for u in units}), "gt_method": args.gt,
            "gt_threshold": args.gt_threshold, "model_threshold": args.model_threshold, "seed": args.seed,
            "runs": args.runs, "format": FORMAT}
    out = settings["out"]
    write_parquet_atomic(df, out, meta)
    maps = blob_map(df)
    n_pairs = df.groupby(["dataset", "pair_id"]).ngroups
    print(f"{n_pairs} pairs, {len(df)} rows -> {out}")
    with pd.option_context("display.width", 160, "display.max_colwidth", 60, "display.float_format",
                           "{:.2f}".format):
        for name, grp in maps.groupby("features", sort=False):
            print(f"\n{name}: best {min(args.top, len(grp))} of {len(grp)} blob setups by mAP (%, mean ap_star)")
            print(grp.nlargest(args.top, "mAP")[["blob", "mAP", "pairs"]].to_string(index=False))
    return 0
