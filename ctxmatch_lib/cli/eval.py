"""``ctxmatch eval``: run the evaluation pipeline of Sec. 5.1 on a dataset and write one row per
(pair, blob setup, method, model) to Parquet, then print the per-kind, per-method mean table."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

DESCRIPTION = """\
Evaluate spatial match filters: features -> blob matching -> filters -> model (none/1sac/ransac/prosac)
-> ground truth (method D) -> metrics. The unfiltered candidates appear as method 'blob'; the model is H
for planar pairs, F for non-planar and depth pairs; time_s is the method's own running time, model_time_s
the model step's. Parquet columns (fractions in [0, 1] for precision, recall, recall_star, ap, ap_star):
dataset, pair_id, kind, features, blob (+ its fields), method, model, precision, recall, recall_star, ap,
ap_star, correct, correct_norm, output, failure (output without a correct match), empty_output (no output),
time_s, model_time_s, n_kpts1, n_kpts2, n_candidates, n_gt, n_gt_star, gt_method, error (why a pair could
not be evaluated, else empty). Recall is normalised as in Sec. 5.1 (min of distinct keypoints per image)
against the correct blob candidates of the same setup; recall_star against their union over all --blob
setups. The printed table shows means in percent (*_pct columns).
Each pair's rows are kept in the evaluation cache ($CTXMATCH_CACHE, else $XDG_CACHE_HOME/ctxmatch or
~/.cache/ctxmatch): a killed run resumes where it stopped, and a pair that cannot be evaluated (unreadable
image, 0 keypoints, a filter that raised) is reported by name and recorded, and the run goes on."""

EXAMPLE = """\
example:
  ctxmatch eval --dataset embedded --blob paper-best --filters dtm --model none,1sac --out results.parquet
  CTXMATCH_DATA=/path/to/data ctxmatch eval --dataset kusvod2 --filters dtm,th --model none,1sac,ransac
"""


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "eval",
        help="evaluate blob matching, filters and 1SAC/RANSAC on a dataset (one Parquet row per pair/method/model)",
        description=DESCRIPTION,
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--dataset", default="embedded",
                   help="registered dataset name (embedded, planar, kusvod2, ...) or a folder with pairs.csv "
                        "(default: embedded)")
    p.add_argument("--data-root", default=None,
                   help="root of the real data (default: $CTXMATCH_DATA)")
    p.add_argument("--blob", default="paper-best",
                   help="comma-separated blob presets (default: paper-best); recall_star uses their union")
    p.add_argument("--filters", default="dtm",
                   help="comma-separated registered filters (dtm, dtm1, dtm2, th, lpm, ...), or 'none' for the "
                        "blob candidates only (default: dtm)")
    p.add_argument("--model", default="none,1sac",
                   help="comma-separated model steps among none, 1sac, ransac (USAC_MAGSAC), "
                        "prosac (MAGSAC++ with PROSAC sampling by score) (default: none,1sac)")
    p.add_argument("--out", default="results.parquet", help="output Parquet file (default: results.parquet)")
    p.add_argument("--gt", default="D", choices=["D", "A"], help="ground-truth method (default: D)")
    p.add_argument("--gt-threshold", type=float, default=15.0, help="ground-truth distance in px (default: 15)")
    p.add_argument("--model-threshold", type=float, default=15.0,
                   help="1SAC/RANSAC consistency threshold in px (default: 15)")
    p.add_argument("--features", default=None,
                   help="feature preset: " + ", ".join(_feature_presets()) + " (default: sift-rootsift, or "
                        "SIFT with --descriptor/--upright); the deep presets need the kornia extra and use "
                        "stand-in weights")
    p.add_argument("--max-keypoints", type=int, default=8000, help="keypoints per image (default: 8000)")
    p.add_argument("--descriptor", default=None, choices=["rootsift", "sift"],
                   help="SIFT descriptor when --features is not given (default: rootsift)")
    p.add_argument("--upright", action="store_true", help="upright SIFT (no dominant orientation)")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default: 0)")
    p.add_argument("--limit", type=int, default=None, help="evaluate only the first N pairs")
    p.add_argument("--kind", default=None, choices=["planar", "nonplanar", "depth"],
                   help="evaluate only the pairs of this kind")
    p.add_argument("--cache-dir", default=None,
                   help="evaluation cache folder (default: the ctxmatch cache, 'sweep')")
    p.add_argument("--recompute", action="store_true", help="ignore the cached rows of these pairs and settings")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=run)
    return p


def _feature_presets() -> list[str]:
    from ..features import FEATURE_PRESETS

    return list(FEATURE_PRESETS)


def _error(msg: str) -> int:
    print(f"ctxmatch eval: error: {msg}", file=sys.stderr)
    return 2


def _check_args(args) -> str | None:
    """The first invalid argument, as an error message naming it; ``None`` when all are valid."""
    import math

    for flag, value in (("--gt-threshold", args.gt_threshold), ("--model-threshold", args.model_threshold)):
        if not (math.isfinite(value) and value > 0):
            return f"{flag} must be a positive number of pixels, got {value:g}"
    if args.max_keypoints < 0:
        return f"--max-keypoints must be >= 0 (0: no cap), got {args.max_keypoints}"
    if args.seed < 0:
        return f"--seed must be >= 0, got {args.seed}"
    if args.limit is not None and args.limit < 1:
        return f"--limit must be positive, got {args.limit}"
    if Path(args.out).suffix.lower() != ".parquet":
        return f"--out must end with .parquet, got {args.out}"
    return None


def run(args) -> int:
    import warnings

    import pandas as pd

    from ..datasets import load_dataset
    from dataclasses import replace

    from ..features import FEATURE_PRESETS, FeatureConfig
    from ..pipeline import check_filters, check_models, resolve_blobs, summary_table
    from ..sweep import SWEEP_COLUMNS, plan_units, run_units, source_digest

    # Every argument is checked before any work (no feature is computed for a run that cannot finish).
    msg = _check_args(args)
    if msg:
        return _error(msg)
    filters = [] if args.filters.strip().lower() in ("", "none") else _csv(args.filters)
    try:
        filters = list(check_filters(filters))
    except ValueError as exc:
        return _error(f"--filters: {exc}")
    try:
        models = list(check_models(_csv(args.model)))
    except ValueError as exc:
        return _error(f"--model: {exc}")
    try:
        blobs = resolve_blobs(_csv(args.blob))
    except ValueError as exc:
        return _error(f"--blob: {exc}")
    try:
        if args.features is not None:
            if args.descriptor is not None or args.upright:
                raise ValueError("--features replaces --descriptor/--upright: give one or the other")
            if args.features not in FEATURE_PRESETS:
                raise ValueError(f"unknown feature preset {args.features!r}; known: {', '.join(FEATURE_PRESETS)}")
            features = replace(FEATURE_PRESETS[args.features], max_keypoints=args.max_keypoints)
            features.key()  # a deep preset fails here, before any work, if its weights are missing
        else:
            features = FeatureConfig(max_keypoints=args.max_keypoints, descriptor=args.descriptor or "rootsift",
                                     upright=args.upright)
    except (ValueError, FileNotFoundError) as exc:
        return _error(f"--features: {exc}")
    out = Path(args.out)
    try:
        dataset = load_dataset(args.dataset, root=args.data_root)
    except (ValueError, FileNotFoundError, OSError) as exc:
        return _error(f"cannot load dataset {args.dataset!r}: {exc}")
    pairs = list(dataset)
    if args.kind:
        pairs = [p for p in pairs if p.kind == args.kind]
    if args.limit:
        pairs = pairs[: args.limit]
    if not pairs:
        return _error(f"dataset {args.dataset!r} has no pairs to evaluate")
    try:
        units = plan_units(pairs, features=features, blobs=blobs, filters=filters, models=models,
                           gt_method=args.gt, gt_threshold=args.gt_threshold, model_threshold=args.model_threshold,
                           seed=args.seed, salt=source_digest())
    except ValueError as exc:
        return _error(str(exc))

    with warnings.catch_warnings():
        # Failing pairs are printed by the progress bar and summarised below; no second copy.
        warnings.simplefilter("ignore", RuntimeWarning)
        df = run_units(units, cache_dir=args.cache_dir, progress=not args.no_progress, recompute=args.recompute,
                       desc="ctxmatch eval")
    df = df[list(SWEEP_COLUMNS)]
    meta = {
        "dataset": args.dataset, "blobs": {k: v.kwargs() for k, v in blobs.items()}, "filters": filters,
        "models": models, "gt_method": args.gt, "gt_threshold": args.gt_threshold,
        "model_threshold": args.model_threshold, "features": features.key(),
        "features_preset": args.features, "seed": args.seed,
        "pairs": len(pairs), "units": "precision, recall, recall_star, ap, ap_star: fractions in [0, 1]",
    }
    from .._paths import write_parquet_atomic

    write_parquet_atomic(df, out, meta)
    errors = df.loc[df["error"] != "", ["dataset", "pair_id", "error"]].drop_duplicates()
    n_failed = errors["pair_id"].nunique()
    table = summary_table(df)
    with pd.option_context("display.max_rows", 500, "display.width", 200, "display.float_format", "{:.2f}".format):
        print(f"{len(pairs)} pairs of {args.dataset!r}, {len(df)} rows -> {out}")
        print("means per pair; *_pct in % (the Parquet file holds fractions); correct_norm: normalised count "
              "(Sec. 5.1); failures: outputs without a correct match; empty_outputs: empty outputs (0 % precision and "
              "recall in the means); errors: pairs not evaluated; time_s: the method, model_time_s: the model step")
        print(table.to_string(formatters={c: "{:.4f}".format for c in ("time_s", "model_time_s")}))
    if n_failed:
        print(f"\n{n_failed} of {len(pairs)} pairs could not be fully evaluated (rows kept, 'error' column):",
              file=sys.stderr)
        for _, r in errors.iterrows():
            print(f"  {r['pair_id']}: {r['error']}", file=sys.stderr)
    # Exit 1 only when nothing at all could be evaluated.
    return 0 if (df["error"] == "").any() else 1
