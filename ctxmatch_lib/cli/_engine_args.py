"""The flags ``ctxmatch eval`` and ``ctxmatch sweep`` share (the same engine with other defaults), their checks
(before any work, naming the flag) and the plan (:func:`~ctxmatch_lib.evaluation.plan.plan_sweep`): the same
settings give the same unit keys, so either command reuses what the other computed."""

from __future__ import annotations

import math


def csv(text: str) -> list[str]:
    """Comma-separated values, stripped, empty ones dropped."""
    return [t.strip() for t in text.split(",") if t.strip()]


def add_engine_arguments(p, *, blob: str, filters: str, model: str, out: str) -> None:
    """Add the shared flags to the sub-parser ``p``, with the command's defaults."""
    from ..features import FEATURE_PRESETS, KEYPOINT_BUDGETS
    from ..groundtruth import GT_METHODS

    p.add_argument("--dataset", default="embedded",
                   help="comma-separated registered datasets (embedded, planar, kusvod2, ...) or folders with "
                        "pairs.csv (default: embedded)")
    p.add_argument("--data-root", default=None, help="root of the real data (default: $CTXMATCH_DATA)")
    p.add_argument("--features", default=None,
                   help="comma-separated feature presets: " + ", ".join(FEATURE_PRESETS) + " (default: "
                        "sift-rootsift); the deep presets use stand-in weights, shipped and run in numpy")
    p.add_argument("--max-keypoints", default=None,
                   help="override the keypoint cap of every feature preset: an integer (0: no cap) or a budget "
                        "name: " + ", ".join(f"{k} ({v})" for k, v in KEYPOINT_BUDGETS.items())
                        + "; 'paper' is calibrated on the paper's Table 2 counts (presets: 8000)")
    p.add_argument("--blob", default=blob,
                   help=f"'grid' (the 2430 setups of Sec. 5.2) or comma-separated blob presets (default: {blob}); "
                        "recall_star uses the union of their correct candidates")
    p.add_argument("--filters", default=filters,
                   help="comma-separated registered filters (dtm, dtm1, dtm2, th, lpm, ..., mop, mop_miho) or "
                        "import paths module:function, 'all' (every filter that can run here, in the paper's order, "
                        f"mop and mop_miho named only) or 'none' (the blob candidates only) (default: {filters})")
    p.add_argument("--model", default=model,
                   help="comma-separated model steps among none, 1sac, ransac (USAC_MAGSAC, 3 px), prosac (MAGSAC++ "
                        "with PROSAC sampling by score, 3 px), magsac (USAC_MAGSAC with fb82/MiHo's 1 px, 0.9999, "
                        "100000 iterations), essential (the same on E, points normalised by K: calibrated pairs "
                        "only), poselib and poselib_essential (PoseLib's LO-RANSAC on H/F and on E, MAGSAC's "
                        f"settings); rows with a model carry its accuracy (default: {model})")
    p.add_argument("--matchers", default="none",
                   help="comma-separated alternative matchers evaluated as methods on the same descriptors: "
                        "opencv_ratio (BFMatcher.knnMatch + Lowe's 0.8 ratio), opencv_mnn (mutual nearest "
                        "neighbours), or 'none' (default: none)")
    p.add_argument("--estimator-threshold", type=float, default=None,
                   help="estimator threshold in px of the random model steps (default: each step's preset)")
    p.add_argument("--estimator-confidence", type=float, default=None,
                   help="confidence of the random model steps (default: each step's preset)")
    p.add_argument("--estimator-iterations", type=int, default=None,
                   help="iteration cap of the random model steps (default: each step's preset)")
    p.add_argument("--pairs", default=None,
                   help="an integer N (N pairs evenly spread over each dataset) or comma-separated pair ids")
    p.add_argument("--kind", default=None,
                   help="comma-separated pair kinds to keep: planar, nonplanar, depth, calibrated")
    p.add_argument("--gt", default="D", choices=list(GT_METHODS), help="ground-truth method (default: D)")
    p.add_argument("--gt-threshold", type=float, default=15.0,
                   help="ground-truth distance in px for --gt D and A (default: 15)")
    p.add_argument("--model-threshold", type=float, default=15.0,
                   help="1SAC/RANSAC consistency threshold in px (default: 15)")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default: 0)")
    p.add_argument("--runs", type=int, default=1,
                   help="seeded runs of each random model step (ransac, prosac, magsac, essential, poselib*) per "
                        "pair and method, one row each (column run); the tables give means over pairs and runs "
                        "with 95 %% bootstrap intervals (default: 1)")
    p.add_argument("--jobs", type=int, default=1, help="local worker processes (joblib); -1: all cores (default: 1)")
    p.add_argument("--dask", default=None, metavar="ADDRESS",
                   help="run on a Dask cluster at this scheduler address, e.g. tcp://host:8786")
    p.add_argument("--cache-dir", default=None,
                   help="evaluation cache folder, shared by eval and sweep (default: the ctxmatch cache, 'sweep')")
    p.add_argument("--recompute", action="store_true", help="ignore (and overwrite) the cached rows of these units")
    p.add_argument("--out", default=out, help=f"output Parquet file (default: {out})")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def check_numbers(args) -> str | None:
    """The first invalid numeric flag, as a message naming it; ``None`` when all are valid (``--max-keypoints``
    is resolved to an int in place: a budget name of :data:`~ctxmatch_lib.features.KEYPOINT_BUDGETS` or a number)."""
    from ..features import keypoint_budget

    for flag, value in (("--gt-threshold", args.gt_threshold), ("--model-threshold", args.model_threshold),
                        ("--estimator-threshold", args.estimator_threshold)):
        if value is not None and not (math.isfinite(value) and value > 0):
            return f"{flag} must be a positive number of pixels, got {value:g}"
    if args.estimator_confidence is not None and not 0 < args.estimator_confidence < 1:
        return f"--estimator-confidence must lie strictly between 0 and 1, got {args.estimator_confidence:g}"
    if args.estimator_iterations is not None and args.estimator_iterations < 1:
        return f"--estimator-iterations must be a positive number of iterations, got {args.estimator_iterations}"
    if args.gt in ("B", "C") and args.gt_threshold != 15.0:
        return (f"--gt-threshold applies to --gt D and A only; --gt {args.gt} uses its own thresholds "
                f"(overlap error 50 %, C's centre 30 px), got {args.gt_threshold:g}")
    try:
        args.max_keypoints = keypoint_budget(args.max_keypoints, argument="--max-keypoints")
    except ValueError as exc:
        return str(exc)
    if args.seed < 0:
        return f"--seed must be >= 0, got {args.seed}"
    if args.runs < 1:
        return f"--runs must be a positive number of estimator runs, got {args.runs}"
    if args.jobs == 0 or args.jobs < -1:
        return f"--jobs must be a positive number of processes or -1 (all cores), got {args.jobs}"
    if args.dask is not None and args.jobs != 1:
        return "give either --jobs (local processes) or --dask (a cluster), not both"
    if args.dask is not None and "://" not in args.dask:
        return f"--dask must be a scheduler address like tcp://host:8786, got {args.dask!r}"
    return None


def resolve_args(args, features=None) -> tuple[dict | None, str | None]:
    """``(settings, None)`` for the planner, or ``(None, message naming the flag)``; ``--out`` is checked too.
    ``features`` replaces ``--features`` (eval's ``--descriptor``/``--upright``)."""
    from ..datasets.base import PAIR_KINDS
    from ..evaluation.frontends import check_output
    from ..evaluation.plan import resolve_blob_configs, resolve_feature_configs
    from ..evaluation.steps import check_estimator, check_matchers, check_models, resolve_blobs, resolve_filters

    msg = check_numbers(args)
    if msg:
        return None, msg
    out = {}
    names, matchers = csv(args.filters), csv(args.matchers)
    lowered = [n.lower() for n in names]
    if len(names) > 1 and {"all", "none"} & set(lowered):
        return None, f"--filters: 'all' and 'none' stand alone, got {args.filters!r}"
    filters = "all" if lowered == ["all"] else [] if lowered == ["none"] else names
    if [m.lower() for m in matchers] == ["none"]:
        matchers = []
    steps = (
        ("--out", lambda: check_output(args.out, "--out")),
        ("--filters", lambda: resolve_filters(filters)),
        ("--model", lambda: check_models(csv(args.model))),
        ("--matchers", lambda: check_matchers(matchers)),
        ("--estimator", lambda: check_estimator(estimator_overrides(args))),
        # Named presets keep their names in the blob column; the grid is labelled by each setup's fields.
        ("--blob", lambda: resolve_blob_configs("grid") if args.blob.strip() == "grid"
                   else resolve_blobs(csv(args.blob))),
        ("--features", lambda: resolve_feature_configs(features if features is not None
                                                       else csv(args.features or "sift-rootsift"))),
    )
    for flag, step in steps:
        try:
            out[flag] = step()
        except (ValueError, KeyError, FileNotFoundError) as exc:
            text = str(exc.args[0] if isinstance(exc, KeyError) and exc.args else exc)
            return None, text if text.startswith(flag) else f"{flag}: {text}"
    pairs = None
    if args.pairs is not None:
        pairs = int(args.pairs) if args.pairs.strip().isdigit() else csv(args.pairs)
        if pairs == 0:
            return None, "--pairs must be a positive number of pairs or pair ids, got 0"
    kinds = csv(args.kind) if args.kind else None
    unknown = sorted(set(kinds or ()) - set(PAIR_KINDS))
    if unknown:
        return None, f"--kind must be among {', '.join(PAIR_KINDS)}, got {', '.join(unknown)}"
    for cfg in out["--features"].values():
        try:
            cfg.key()  # a deep preset fails here, before any work, if its weights are missing
        except (ValueError, FileNotFoundError) as exc:
            return None, f"--features: {exc}"
    return dict(out=out["--out"], filters=out["--filters"], models=out["--model"], blobs=out["--blob"],
                features=out["--features"], pairs=pairs, kinds=kinds, matchers=out["--matchers"],
                estimator=dict(out["--estimator"])), None


def estimator_overrides(args) -> dict:
    """The ``--estimator-*`` flags that were given, as :func:`~ctxmatch_lib.geometry.usac_settings` keys."""
    flags = (("threshold", args.estimator_threshold), ("confidence", args.estimator_confidence),
             ("max_iters", args.estimator_iterations))
    return {key: value for key, value in flags if value is not None}


def plan(args, settings: dict, *, limit: int | None = None):
    """``(units, None)`` of :func:`~ctxmatch_lib.evaluation.plan.plan_sweep`, or ``(None, message)``; ``limit``
    keeps the first N selected pairs of each dataset (eval's ``--limit``)."""
    from ..datasets import load_dataset
    from ..evaluation.plan import plan_sweep, select_pairs

    kw = dict(features=settings["features"], blobs=settings["blobs"], filters=settings["filters"],
              models=settings["models"], gt_method=args.gt, gt_threshold=args.gt_threshold,
              model_threshold=args.model_threshold, seed=args.seed, max_keypoints=args.max_keypoints,
              data_root=args.data_root, matchers=settings["matchers"], estimator=settings["estimator"],
              runs=args.runs)
    units = []
    for name in csv(args.dataset) or ["embedded"]:
        try:
            ds = load_dataset(name, root=args.data_root)
        except (ValueError, FileNotFoundError, OSError) as exc:
            return None, f"--dataset: cannot load dataset {name!r}: {exc}"
        try:
            chosen = select_pairs(ds.pairs, settings["pairs"], kinds=settings["kinds"])
        except ValueError as exc:
            return None, f"--pairs: {exc}"
        if limit is not None:
            chosen = chosen[:limit]
        if not chosen:
            return None, f"--dataset {name!r} has no pairs left to evaluate (--pairs, --kind, --limit)"
        try:
            units.extend(plan_sweep([name], pairs=[p.pair_id for p in chosen], **kw))
        except ValueError as exc:
            return None, str(exc)
    return units, None
