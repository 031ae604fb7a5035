"""``ctxmatch train oanet|acne``: train a learned filter here, on correspondences generated from the embedded images.

The weights are labelled "trained here" (never the authors'). Without ``--output`` they replace the shipped
weights of the installed package (``ctxmatch_lib/filters/learned/weights/<arch>_trained_here.pt``).

Examples::

    ctxmatch train oanet
    ctxmatch train acne --steps 200 --seed 1 --output /tmp/acne.pt
"""

from __future__ import annotations

import argparse


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "train", help="train the OANet or ACNe filter here (needs torch)",
        description="Train OANet or ACNe on correspondences generated from the embedded images (random "
                    "homographies and layered non-planar scenes, planted outliers, 5-60 %% inliers); never "
                    "reads CTXMATCH_DATA. Seeded; shows a progress bar.",
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
    parser.add_argument("--output", help="weights file to write (default: the package's shipped weights)")
    parser.add_argument("--max-images", type=int, default=None,
                        help="use only the first embedded images as keypoint sources (tiny runs)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(func=_train)
    return parser


def _train(args) -> int:
    from ..filters.learned import shipped_weights, train_learned_filter

    output = args.output or shipped_weights(args.arch)
    res = train_learned_filter(args.arch, steps=args.steps, batch_size=args.batch_size,
                               n_candidates=(args.k_min, args.k_max), lr=args.lr, seed=args.seed,
                               output=output, num_threads=args.threads, max_images=args.max_images,
                               progress=not args.no_progress)
    v = res.validation
    print(f"{args.arch} (trained here): {len(res.losses)} steps in {res.seconds:.0f} s, final loss "
          f"{sum(res.losses[-50:]) / len(res.losses[-50:]):.4f}; generated sets at {100 * v['inlier_ratio']:.0f} % "
          f"inliers: precision {v['precision']:.3f}, recall {v['recall']:.3f}")
    print(f"weights written to {res.path}")
    return 0
