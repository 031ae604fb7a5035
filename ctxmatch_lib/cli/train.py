"""``ctxmatch train oanet|acne``: train a learned filter on correspondences generated from the embedded images.

The weights ("trained here", never the authors') go to :func:`default_output` unless ``--output`` names a
file (the only way to replace the shipped ones); use them with ``weights=``::

    match_images(img1, img2, filters=["oanet"], filter_params={"oanet": {"weights": path}})
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from . import error


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "train", help="train the OANet or ACNe filter here (needs torch)",
        description="Train OANet or ACNe on correspondences generated from the embedded images (random "
                    "homographies and layered non-planar scenes, planted outliers, 5-60 % inliers); never "
                    "reads CTXMATCH_DATA. Seeded; shows a progress bar. The weights go to the user's cache "
                    "unless --output names a file; use them with weights=PATH (FILTERS['oanet'](..., "
                    "weights=PATH) or match_images(..., filter_params={'oanet': {'weights': PATH}})).",
    )
    parser.add_argument("arch", choices=["oanet", "acne"])
    parser.add_argument("--steps", type=int, default=None,
                        help="optimisation steps (default: as the shipped weights, 400 for oanet, 2000 for acne)")
    parser.add_argument("--batch-size", type=int, default=8, help="candidate sets per step (default 8)")
    parser.add_argument("--k-min", type=int, default=500, help="fewest candidates per set (default 500)")
    parser.add_argument("--k-max", type=int, default=1500, help="most candidates per set (default 1500)")
    parser.add_argument("--lr", type=float, default=1e-3, help="initial learning rate (default 1e-3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of data and initialisation (default 0)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1: reproducible)")
    parser.add_argument("--output",
                        help="weights file to write: .npz (numpy, what the filters load without torch) or any "
                             "other suffix for a torch checkpoint (default: "
                             "<cache>/weights/<arch>_trained_here_seed<seed>[_steps<steps>].npz; never the "
                             "shipped weights unless named here)")
    parser.add_argument("--max-images", type=int, default=None,
                        help="use only the first embedded images as keypoint sources (tiny runs)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=_train)
    return parser


def default_output(arch: str, seed: int = 0, steps: int | None = None) -> Path:
    """Where ``ctxmatch train`` writes without ``--output``, never the package:
    ``cache_dir("weights") / "<arch>_trained_here_seed<seed>[_steps<steps>].npz"`` (steps only when given)."""
    from ..cache import cache_dir

    name = f"{arch}_trained_here_seed{seed}" + (f"_steps{steps}" if steps is not None else "")
    return cache_dir("weights") / f"{name}.npz"


def _check_args(args) -> str | None:
    """The first bad flag, as a message, or ``None``; checked before torch is imported or anything runs."""
    for flag, value, least in (("--steps", args.steps, 1), ("--batch-size", args.batch_size, 1),
                               ("--k-min", args.k_min, 1), ("--k-max", args.k_max, 1),
                               ("--threads", args.threads, 1), ("--max-images", args.max_images, 1)):
        if value is not None and value < least:
            return f"{flag} must be >= {least}, got {value}"
    if args.k_min > args.k_max:
        return f"--k-min must be <= --k-max, got {args.k_min} > {args.k_max}"
    if not (math.isfinite(args.lr) and args.lr > 0):
        return f"--lr must be a positive number, got {args.lr}"
    return None


def _train(args) -> int:
    from ..cache import check_writable
    from ..filters.learned import TORCH_HINT, torch_available

    problem = _check_args(args)
    if problem:
        return error("train", problem)
    output = Path(args.output) if args.output else default_output(args.arch, args.seed, args.steps)
    try:
        check_writable(output, "--output")
    except ValueError as exc:
        return error("train", str(exc))
    if not torch_available():
        return error("train", TORCH_HINT)

    from ..filters.learned import train_learned_filter

    res = train_learned_filter(args.arch, steps=args.steps, batch_size=args.batch_size,
                               n_candidates=(args.k_min, args.k_max), lr=args.lr, seed=args.seed,
                               output=output, num_threads=args.threads, max_images=args.max_images,
                               progress=not args.no_progress)
    v = res.validation
    print(f"{args.arch} (trained here): {len(res.losses)} steps in {res.seconds:.0f} s, final loss "
          f"{sum(res.losses[-50:]) / len(res.losses[-50:]):.4f}; generated sets at {100 * v['inlier_ratio']:.0f} % "
          f"inliers: precision {v['precision']:.3f}, recall {v['recall']:.3f}")
    print(f"weights written to {res.path}")
    print(f"use them with weights='{res.path}' (FILTERS['{args.arch}'](..., weights=...) or "
          f"match_images(..., filter_params={{'{args.arch}': {{'weights': ...}}}}))")
    return 0
