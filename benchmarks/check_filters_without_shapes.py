"""Every registered filter called with and without the keypoint shapes on the blob candidates of the shared pairs.

A filter called as the README calls DTM (no ``shapes1`` / ``shapes2``) must either decide or say that it cannot
(an error or a warning naming the argument); an empty mask where the same call with the shapes keeps matches
looks like a verdict and is not one. For every filter of :data:`ctxmatch_lib.filters.FILTERS` (or
``--filters a,b``) and every pair (``--pairs N`` evenly spread over ``planar`` and ``nonplanar``; default all
of them), this prints the candidates kept with the shapes and without them, the pairs where the call without
the shapes keeps nothing although the call with them keeps some (``empty``), and what the call without them
said: ``warns`` (a ``UserWarning`` naming ``shapes1``), ``raises`` (a ``ValueError`` naming it) or nothing.

The candidates: ``--features`` (default ``sift-rootsift``) at ``--max-keypoints`` (default ``paper``, 1500)
under the ``--blob`` preset (default ``paper-best``); the scores carry their blob ratio and the filters with
``uses_blob_ratio`` get it, as the evaluation engine calls them.

Run::

    CTXMATCH_DATA=/path/to/data OMP_NUM_THREADS=1 .venv/bin/python benchmarks/check_filters_without_shapes.py \\
        --pairs 10
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from dataclasses import replace

import numpy as np


def _call(func, f1, f2, m, s, pair, ratio, with_shapes: bool):
    """``(keep or None, what was said)``: the mask (None when the call raised) and ``"warns"`` / ``"raises"``
    when a warning or error named the shapes, else ``""``."""
    params = {"ratio": ratio} if getattr(func, "uses_blob_ratio", False) else {}
    shapes = dict(shapes1=f1.shapes, shapes2=f2.shapes) if with_shapes else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            keep = func(f1.kpts, f2.kpts, m, s, image_size1=tuple(pair.image_size1),
                        image_size2=tuple(pair.image_size2), **shapes, **params)
        except ValueError as exc:
            if "shapes1" in str(exc):
                return None, "raises"
            raise
    said = "warns" if any("shapes1" in str(w.message) for w in caught) else ""
    return np.asarray(getattr(keep, "keep", keep), bool), said


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=0, help="pairs evenly spread (default 0: all)")
    parser.add_argument("--features", default="sift-rootsift")
    parser.add_argument("--max-keypoints", default="paper")
    parser.add_argument("--blob", default="paper-best")
    parser.add_argument("--filters", default="", help="comma-separated names (default: every registered filter)")
    args = parser.parse_args(argv)
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to check", file=sys.stderr)
        return 2
    from ctxmatch_lib._numerics.scores import score_ratio
    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import blob_candidates, pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget
    from ctxmatch_lib.filters import FILTERS, nnr_scores

    names = [n for n in args.filters.split(",") if n] or list(FILTERS)
    fcfg = FEATURE_PRESETS[args.features]
    budget = keypoint_budget(args.max_keypoints, argument="--max-keypoints")
    if budget is not None:
        fcfg = replace(fcfg, max_keypoints=budget)
    cfg = BLOB_PRESETS[args.blob]
    pairs = select_pairs(["planar", "nonplanar"], args.pairs or None)
    data = []
    for pair in pairs:
        f1, f2 = pair_features(pair, fcfg)
        m, s, _ = blob_candidates(f1, f2, cfg)
        s = s if score_ratio(s) is not None else nnr_scores(s, cfg.ratio)
        data.append((pair, f1, f2, m, s))
    print(f"{len(data)} pairs, {args.features} at {args.max_keypoints} keypoints, {args.blob} candidates "
          f"(mean {np.mean([len(d[3]) for d in data]):.0f})")
    print(f"{'filter':<9} {'kept with shapes':>16} {'kept without':>12} {'empty':>9} {'said':>7}")
    for name in names:
        func = FILTERS[name]
        with_, without, empty, said = [], [], 0, 0
        for pair, f1, f2, m, s in data:
            keep, _ = _call(func, f1, f2, m, s, pair, cfg.ratio, True)
            bare, told = _call(func, f1, f2, m, s, pair, cfg.ratio, False)
            with_.append(keep.sum())
            said += bool(told)
            if bare is not None:
                without.append(bare.sum())
                empty += int(bare.sum() == 0 and keep.sum() > 0)
        wo = f"{np.mean(without):.0f}" if without else "-"
        print(f"{name:<9} {np.mean(with_):>16.0f} {wo:>12} {f'{empty}/{len(data)}':>9} "
              f"{f'{said}/{len(data)}':>7}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
