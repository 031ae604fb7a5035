"""The paper-scale gallery's two big costs, measured on single units and projected.

`make figures-paper` spends its time in two places: extracting the paper's eight feature blocks of every
real image (from an empty feature cache), and fig_blob_bands' sweep of the 2430-setup blob grid over every
(pair, block) unit (55 pairs x 8 blocks). This script times

* the cold extraction of each block on the images of a few pairs, into one fresh cache (as a cold gallery
  run fills it: blocks sharing a step, HarrisZ or OriNet, find it kept by the block before), and
* a few grid units (one pair, one block, a fresh evaluation cache, so every candidate set, ratio, overlap
  table and AP is computed),

in CPU seconds of this process, then projects each onto the whole gallery (per image, resp. per unit, times
the number of images, resp. units, divided by the workers). The projections assume the per-unit mean of the
measured units holds for the others; the paper-scale log's other notebooks are not measured here.

Run: `CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_gallery.py [--pairs 2] [--blocks a,b]
[--jobs 2]`. To compare two versions of the library, run it under each (``PYTHONPATH=<other checkout>``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=2, help="pairs per dataset timed (evenly spread; default 2)")
    ap.add_argument("--blocks", default=None, help="feature blocks (default: the paper's eight)")
    ap.add_argument("--jobs", type=int, default=2, help="workers of the projected run (default: 2)")
    ap.add_argument("--no-sweep", action="store_true", help="time the feature extraction only")
    args = ap.parse_args(argv)

    import ctxmatch_lib
    from ctxmatch_lib.cache import data_root
    from ctxmatch_lib.evaluation import plan_sweep
    from ctxmatch_lib.evaluation.unit import run_unit
    from ctxmatch_lib.features import extract_features, paper_feature_blocks
    from ctxmatch_lib.features.config import FEATURE_PRESETS, KEYPOINT_BUDGETS

    if data_root() is None:
        print("bench_gallery: set CTXMATCH_DATA to the folder holding planar/ and nonplanar/", file=sys.stderr)
        return 2
    dataset, budget = "planar,nonplanar", KEYPOINT_BUDGETS["paper"]
    blocks = args.blocks.split(",") if args.blocks else paper_feature_blocks()
    every = plan_sweep(dataset, features=blocks[:1], blobs="baseline", max_keypoints=budget)
    n_images = len({str(im) for u in every for im in (u.pair.image1, u.pair.image2)})
    n_units = len(every) * len(blocks)
    timed = plan_sweep(dataset, features=blocks[:1], blobs="baseline", pairs=args.pairs, max_keypoints=budget)
    images = list(dict.fromkeys(str(im) for u in timed for im in (u.pair.image1, u.pair.image2)))
    print(f"library {ctxmatch_lib.__file__}")
    print(f"gallery: {len(every)} pairs, {n_images} images, {len(blocks)} blocks -> {n_units} grid units; "
          f"timed: {len(images)} images of {len(timed)} pairs, {args.jobs} workers projected")

    # Imports, numba and the networks' weights are loaded before any timing.
    with tempfile.TemporaryDirectory(prefix="bench_gallery_warm_") as warm:
        for b in blocks:
            extract_features(images[0], replace(FEATURE_PRESETS[b], max_keypoints=budget), cache_dir=warm)

    feat_total = 0.0
    with tempfile.TemporaryDirectory(prefix="bench_gallery_feat_") as cache:
        print(f"\ncold features ({budget} keypoints), CPU s per image, projected over {n_images} images:")
        for b in blocks:
            cfg = replace(FEATURE_PRESETS[b], max_keypoints=budget)
            t0 = time.process_time()
            for im in images:
                extract_features(im, cfg, cache_dir=cache)
            per = (time.process_time() - t0) / len(images)
            feat_total += per * n_images / args.jobs
            print(f"  {b:20s} {per:6.2f} s/image -> {per * n_images / args.jobs / 60:5.1f} min")
    print(f"  all blocks: {feat_total / 60:.1f} min on {args.jobs} workers")
    if args.no_sweep:
        return 0

    unit_total = 0.0
    print(f"\ngrid units (2430 setups, fresh evaluation cache), CPU s per unit, projected over {len(every)} pairs:")
    for b in blocks:
        units = plan_sweep(dataset, features=[b], blobs="grid", pairs=args.pairs, max_keypoints=budget)
        secs = []
        for u in units:
            run_unit(u, cache_dir=False)  # features into the regular feature cache, untimed
            with tempfile.TemporaryDirectory(prefix="bench_gallery_sweep_") as cache:
                t0 = time.process_time()
                run_unit(u, cache_dir=cache)
                secs.append(time.process_time() - t0)
        per = sum(secs) / len(secs)
        unit_total += per * len(every) / args.jobs
        print(f"  {b:20s} {per:6.2f} s/unit ({', '.join(f'{s:.1f}' for s in secs)}) -> "
              f"{per * len(every) / args.jobs / 60:5.1f} min")
    print(f"  all blocks: {unit_total / 60:.1f} min on {args.jobs} workers (fig_blob_bands' sweep)")
    print(f"\nprojected: features {feat_total / 60:.1f} min + grid sweep {unit_total / 60:.1f} min = "
          f"{(feat_total + unit_total) / 60:.1f} min of the cold gallery")
    return 0


if __name__ == "__main__":
    sys.exit(main())
