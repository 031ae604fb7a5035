"""``ctxmatch eval``: the evaluation engine on named presets (Sec. 5.1), one Parquet row per (pair, features,
blob setup, method, model) and a mean table; flags and cache shared with ``ctxmatch sweep`` (see
:mod:`ctxmatch_lib.cli._engine_args`)."""

from __future__ import annotations

import argparse
import sys

from . import error
from ._engine_args import add_engine_arguments, plan, resolve_args

DESCRIPTION = """\
Evaluate spatial match filters: features -> blob matching -> filters -> model (none/1sac/ransac/prosac/
magsac/essential) -> ground truth (--gt, method D by default) -> metrics. The unfiltered candidates appear as
method 'blob'; --matchers adds OpenCV's matchers (opencv_ratio, opencv_mnn) on the same descriptors. The
model is H for planar pairs, F otherwise, E for 'essential' (calibrated pairs: points normalised by the
intrinsics, MAGSAC, threshold in px over the focal).
Parquet columns (precision, recall, recall_star, ap, ap_star as fractions in [0, 1]): dataset, pair_id, kind,
features, blob (+ its fields), method, model, precision, recall, recall_star, ap, ap_star, correct,
correct_norm, output, failure (output without a correct match), empty_output (no output), time_s (the
method), model_time_s (the model step); the model's accuracy (NaN for model none): model_inliers,
corner_error (planar: mean px distance of the image-1 corners mapped by the estimated and true H; inf
without a model), epi_share_mean, epi_share_1/3/5/10 (other kinds: share of GT correspondences within
1..19 px, resp. t px, of the estimated F, WxBS symmetric epipolar distance; 0 without a model), pose_err_R,
pose_err_t, pose_err (calibrated: rotation, translation-direction error and their maximum, degrees; 180
without a pose); n_kpts1, n_kpts2, n_candidates, n_gt, n_gt_star, gt_method, error (why a pair could not be
evaluated). Recall is normalised as in Sec. 5.1 against the correct candidates of the same setup,
recall_star against their union over all --blob setups. The printed table shows means in % (*_pct).
Rows are cached per pair ($CTXMATCH_CACHE, else $XDG_CACHE_HOME/ctxmatch or ~/.cache/ctxmatch), shared with
'ctxmatch sweep': a killed run resumes, and a pair that cannot be evaluated (unreadable image, 0 keypoints,
a filter that raised) is reported, recorded, and skipped."""

EXAMPLE = """\
example:
  ctxmatch eval --dataset embedded --blob paper-best --filters dtm --model none,1sac --out results.parquet
  ctxmatch eval --filters dtm --matchers opencv_ratio,opencv_mnn --model magsac --out geometry.parquet
  CTXMATCH_DATA=/path/to/data ctxmatch eval --dataset planar,nonplanar --filters all --jobs 2
  ctxmatch eval --dataset strecha --filters dtm,adalam --matchers opencv_ratio --model magsac,essential
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "eval",
        help="evaluate blob matching, filters and 1SAC/RANSAC on datasets (one Parquet row per pair/method/model)",
        description=DESCRIPTION,
        epilog=EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_engine_arguments(p, blob="paper-best", filters="dtm", model="none,1sac", out="results.parquet")
    p.add_argument("--descriptor", default=None, choices=["rootsift", "sift"],
                   help="SIFT descriptor when --features is not given (default: rootsift)")
    p.add_argument("--upright", action="store_true", help="upright SIFT (no dominant orientation)")
    p.add_argument("--limit", type=int, default=None, help="evaluate only the first N pairs of each dataset")
    p.set_defaults(func=run)
    return p


def _sift_features(args):
    """The SIFT configuration of --descriptor/--upright (a preset name when one matches), or ``None``."""
    if args.descriptor is None and not args.upright:
        return None
    if args.features is not None:
        raise ValueError("--features replaces --descriptor/--upright: give one or the other")
    from ..features import FeatureConfig

    descriptor = args.descriptor or "rootsift"
    names = {("rootsift", False): "sift-rootsift", ("rootsift", True): "sift-rootsift-upright",
             ("sift", False): "sift"}
    name = names.get((descriptor, args.upright))
    return [name] if name else [FeatureConfig(descriptor=descriptor, upright=True)]


def run(args) -> int:
    import warnings

    from ..cache import write_parquet_atomic
    from ..evaluation.rows import SWEEP_COLUMNS
    from ..evaluation.run import run_units
    from ..pipeline import summary_table

    # Every argument (the output path included) is checked before any work, with the flag's name.
    if args.limit is not None and args.limit < 1:
        return error("eval", f"--limit must be positive, got {args.limit}")
    try:
        features = _sift_features(args)
    except ValueError as exc:
        return error("eval", str(exc))
    settings, msg = resolve_args(args, features)
    if msg:
        return error("eval", msg)
    units, msg = plan(args, settings, limit=args.limit)
    if msg:
        return error("eval", msg)
    with warnings.catch_warnings():
        # Failing pairs are printed by the progress bar and summarised below; no second copy.
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            df = run_units(units, cache_dir=args.cache_dir, n_jobs=args.jobs, dask=args.dask,
                           progress=not args.no_progress, recompute=args.recompute, desc="ctxmatch eval")
        except (ConnectionError, ImportError) as exc:
            return error("eval", f"--dask: {exc}")
    df = df[list(SWEEP_COLUMNS)]
    n_pairs = df.groupby(["dataset", "pair_id"]).ngroups
    blobs = settings["blobs"]
    meta = {
        "dataset": args.dataset, "blobs": ({k: v.kwargs() for k, v in blobs.items()} if isinstance(blobs, dict)
                                           else len(blobs)),
        "filters": list(settings["filters"]), "models": list(settings["models"]), "gt_method": args.gt,
        "gt_threshold": args.gt_threshold, "model_threshold": args.model_threshold,
        "features": {u.features_name: u.features.key() for u in units}, "seed": args.seed, "runs": args.runs,
        "pairs": n_pairs, "matchers": list(settings["matchers"]), "estimator": settings["estimator"],
        "units": "precision, recall, recall_star, ap, ap_star: fractions in [0, 1]",
    }
    write_parquet_atomic(df, settings["out"], meta)
    _print_summary(df, args, settings["out"], n_pairs, summary_table)
    # Exit 1 only when nothing at all could be evaluated.
    return 0 if (df["error"] == "").any() else 1


def _print_summary(df, args, out, n_pairs: int, summary_table) -> None:
    import pandas as pd

    errors = df.loc[df["error"] != "", ["dataset", "pair_id", "error"]].drop_duplicates()
    n_failed = errors["pair_id"].nunique()
    table = summary_table(df)
    with pd.option_context("display.max_rows", 500, "display.width", 200, "display.float_format", "{:.2f}".format):
        print(f"{n_pairs} pairs of {args.dataset!r}, {len(df)} rows -> {out}")
        print("means per pair; *_pct in % (the Parquet file holds fractions); correct_norm: normalised count "
              "(Sec. 5.1); failures: outputs without a correct match; empty_outputs: empty outputs (0 % precision and "
              "recall in the means); errors: pairs not evaluated; time_s: the method, model_time_s: the model step")
        print(table.to_string(formatters={c: "{:.4f}".format for c in ("time_s", "model_time_s")}))
        if (df["model"] != "none").any() and (df["error"] == "").any():
            from ..geometry_metrics import geometry_table

            print("\nthe model's accuracy over pairs: auc_*px_pct (planar): AUC of the mean corner error up to t px "
                  "in % (pairs without a model count as failures); epi_share_*_pct (other kinds): ground-truth "
                  "correspondences consistent with the estimated F, mean over 1..19 px and at t px, in %; "
                  "auc_*deg_pct (calibrated): AUC of the pose error up to t degrees in % (F: pose through "
                  "E = K2^T F K1, MiHo's AUC^F; essential: E on normalised points, its AUC^E), over pairs and --runs; "
                  "*_lo, *_hi: their 95 % bootstrap interval; no_model: fits without a model; "
                  "geometry_time_(median_)s: blob (or matcher) + filter + model step, mean (median) per pair")
            print(geometry_table(df).dropna(axis=1, how="all").to_string(formatters={c: "{:.4f}".format
                                                           for c in ("geometry_time_s", "geometry_time_median_s")}))
    if n_failed:
        print(f"\n{n_failed} of {n_pairs} pairs could not be fully evaluated (rows kept, 'error' column):",
              file=sys.stderr)
        for _, r in errors.iterrows():
            print(f"  {r['pair_id']}: {r['error']}", file=sys.stderr)
