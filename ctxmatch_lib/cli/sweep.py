"""``ctxmatch sweep``: run (or resume) a grid of dataset × features × blob setup × filter × model and write
one Parquet row per (pair, features, blob setup, method, model); print the best setups by mAP."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DESCRIPTION = """\
Sweep blob-matching setups (default: the 2430 of Sec. 5.2) and optionally filters and model steps over a
dataset. Each (pair, features) is one work unit whose rows are cached as an atomic Parquet part under the
sweep cache, so an interrupted run resumes where it stopped (no lost, no duplicated rows) and a rerun is
instant. Intermediates (features, candidate sets, FGINN overlap tables, filter masks) are cached too.
The AP of a row ranks the setup's candidates by its score, with method-D labels: 'ap' against the setup's own
correct candidates, 'ap_star' against the correct candidates of all setups of the sweep on the pair; the mAP
printed (and drawn in the heat map of Fig. 5) is the mean of ap_star over pairs."""

EXAMPLE = """\
examples:
  ctxmatch sweep                                   # embedded dataset, full grid, SIFT+RootSIFT
  ctxmatch sweep --features sift-rootsift,sift --pairs 6 --jobs 2 --out sweep.parquet
  ctxmatch sweep --blob paper-best,baseline --filters dtm,th --model none,1sac
  CTXMATCH_DATA=/path/to/data ctxmatch sweep --dataset planar,nonplanar --jobs 2
  ctxmatch sweep --dask tcp://scheduler:8786       # scale out on a Dask cluster
"""


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "sweep",
        help="sweep blob setups (the 2430-setup grid of Sec. 5.2), filters and models; cached and resumable",
        description=DESCRIPTION,
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--dataset", default="embedded",
                   help="comma-separated registered datasets or custom folders (default: embedded)")
    p.add_argument("--data-root", default=None, help="root of the real data (default: $CTXMATCH_DATA)")
    p.add_argument("--features", default="sift-rootsift",
                   help="comma-separated feature presets: " + ", ".join(_feature_presets())
                        + " (default: sift-rootsift); the deep presets need the kornia extra and use stand-in "
                          "weights")
    p.add_argument("--max-keypoints", type=int, default=None,
                   help="override the keypoint cap of every feature preset (presets: 8000)")
    p.add_argument("--blob", default="grid",
                   help="'grid' (2430 setups) or comma-separated blob presets (default: grid)")
    p.add_argument("--filters", default="none",
                   help="comma-separated registered filters, or 'none' for the blob candidates only (default)")
    p.add_argument("--model", default="none", help="comma-separated model steps: none, 1sac, ransac, prosac "
                                                   "(default: none)")
    p.add_argument("--pairs", default=None,
                   help="an integer N (N pairs evenly spread over each dataset) or comma-separated pair ids")
    p.add_argument("--kind", default=None, help="comma-separated pair kinds to keep: planar, nonplanar, depth")
    p.add_argument("--gt", default="D", choices=["D", "A"], help="ground-truth method (default: D)")
    p.add_argument("--gt-threshold", type=float, default=15.0, help="ground-truth distance in px (default: 15)")
    p.add_argument("--model-threshold", type=float, default=15.0,
                   help="1SAC/RANSAC consistency threshold in px (default: 15)")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default: 0)")
    p.add_argument("--jobs", type=int, default=1, help="local worker processes (joblib); -1: all cores (default: 1)")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster at this scheduler address, e.g. tcp://host:8786")
    p.add_argument("--cache-dir", default=None, help="sweep cache folder (default: the ctxmatch cache, 'sweep')")
    p.add_argument("--recompute", action="store_true", help="ignore the cached result parts of this sweep")
    p.add_argument("--out", default="sweep.parquet", help="output Parquet file (default: sweep.parquet)")
    p.add_argument("--top", type=int, default=10, help="print the N best setups by mAP (default: 10)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)
    return p


def _feature_presets() -> list[str]:
    from ..features import FEATURE_PRESETS

    return list(FEATURE_PRESETS)


def _error(msg: str) -> int:
    print(f"ctxmatch sweep: error: {msg}", file=sys.stderr)
    return 2


def run(args) -> int:
    import pandas as pd

    from ..features import FEATURE_PRESETS
    from ..sweep import blob_map, run_sweep

    import math

    # Every argument is checked before any work, with the flag's name in the message.
    for flag, value in (("--gt-threshold", args.gt_threshold), ("--model-threshold", args.model_threshold)):
        if not (math.isfinite(value) and value > 0):
            return _error(f"{flag} must be a positive number of pixels, got {value:g}")
    if args.seed < 0:
        return _error(f"--seed must be >= 0, got {args.seed}")
    if args.top < 1:
        return _error(f"--top must be positive, got {args.top}")
    filters = [] if args.filters.strip().lower() in ("", "none") else _csv(args.filters)
    features = _csv(args.features)
    unknown = [f for f in features if f not in FEATURE_PRESETS]
    if unknown:
        return _error(f"unknown feature preset(s) {', '.join(unknown)}; known: {', '.join(FEATURE_PRESETS)}")
    if args.max_keypoints is not None and args.max_keypoints < 0:
        return _error(f"--max-keypoints must be >= 0, got {args.max_keypoints}")
    pairs = None
    if args.pairs is not None:
        pairs = int(args.pairs) if args.pairs.strip().isdigit() else _csv(args.pairs)
    blobs = "grid" if args.blob.strip() == "grid" else _csv(args.blob)
    kinds = _csv(args.kind) if args.kind else None
    out = Path(args.out)
    if out.suffix.lower() != ".parquet":
        return _error(f"--out must end with .parquet, got {out}")
    try:
        df = run_sweep(_csv(args.dataset), features=features, blobs=blobs, filters=filters,
                       models=_csv(args.model), max_keypoints=args.max_keypoints, pairs=pairs, kinds=kinds,
                       gt_method=args.gt, gt_threshold=args.gt_threshold, model_threshold=args.model_threshold, seed=args.seed,
                       n_jobs=args.jobs, dask=args.dask, cache_dir=args.cache_dir, out=out,
                       progress=not args.no_progress, data_root=args.data_root, recompute=args.recompute)
    except (ValueError, FileNotFoundError, ConnectionError, ImportError, MemoryError) as exc:
        return _error(str(exc))
    maps = blob_map(df)
    n_pairs = df.groupby(["dataset", "pair_id"]).ngroups
    print(f"{n_pairs} pairs, {len(df)} rows -> {out}")
    with pd.option_context("display.width", 160, "display.max_colwidth", 60, "display.float_format",
                           "{:.2f}".format):
        for name, grp in maps.groupby("features", sort=False):
            print(f"\n{name}: best {min(args.top, len(grp))} of {len(grp)} blob setups by mAP (%, mean ap_star)")
            print(grp.nlargest(args.top, "mAP")[["blob", "mAP", "pairs"]].to_string(index=False))
    return 0
