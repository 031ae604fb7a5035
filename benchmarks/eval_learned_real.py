"""OANet / ACNe (weights trained here) on the shared real pairs, for comparing weight files side by side.

For every pair of the ``planar`` and ``nonplanar`` datasets (``$CTXMATCH_DATA``), the blob candidates of two
setups at the paper keypoint budget (1500): ``baseline`` (SIFT + RootSIFT, blob preset ``baseline``: the
paper's Table 2) and ``best`` (HarrisZ + SOSNet stand-in, ``paper-best-overlap``: Table 3), labelled by the
evaluation's ground truth (method D, :data:`~ctxmatch_lib.groundtruth.GT_THRESHOLD_PX`); then each filter
with each weight file given, no model step,
at each logit threshold given (``--thresholds``: the filters' ``threshold=``, default 0). Prints the mean precision and recall (Sec. 5.1, recall against
the setup's correct candidates, normalised by distinct keypoints) per kind, in %, as the tables do
(``ctxmatch eval``'s rows for the shipped weights), with the paper's Table 2 row for reference.

    OMP_NUM_THREADS=1 CTXMATCH_DATA=/work/shared/data python benchmarks/eval_learned_real.py \\
        [--weights oanet=OLD.npz oanet=NEW.npz acne=...] [--configs baseline best] [--thresholds 0] [--by-inlier-ratio] [--pairs N]

Without ``--weights``: the shipped weights of both filters. Features come from the feature cache; the
candidates and their labels are cached under ``cache_dir("learned-eval")`` after the first run.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from collections import defaultdict

import numpy as np

from ctxmatch_lib.cache import atomic_path, cache_dir
from ctxmatch_lib.blob import BLOB_PRESETS
from ctxmatch_lib.datasets import load_dataset
from ctxmatch_lib.evaluation.cache import digest, pair_digest
from ctxmatch_lib.evaluation.steps import blob_candidates, label_candidates, pair_features
from ctxmatch_lib.features import FEATURE_PRESETS, KEYPOINT_BUDGETS
from ctxmatch_lib.filters.learned import learned_logits
from ctxmatch_lib.metrics import evaluate_matches

CONFIGS = {"baseline": ("sift-rootsift", "baseline"), "best": ("harrisz-sosnet", "paper-best-overlap")}
#: The paper's Table 2 (baseline, no model): (P, R) per filter and kind.
PAPER_TABLE2 = {("oanet", "planar"): (86.0, 81.8), ("acne", "planar"): (77.5, 84.9),
                ("oanet", "nonplanar"): (81.7, 77.2), ("acne", "nonplanar"): (67.2, 75.6)}


def _weights(specs):
    out = []
    for s in specs or ["oanet=shipped", "acne=shipped"]:
        name, _, path = s.partition("=")
        if name not in ("oanet", "acne") or not path:
            raise SystemExit(f"--weights must be oanet=PATH or acne=PATH (or =shipped), got {s!r}")
        out.append((name, None if path == "shipped" else path, s))
    return out


def _candidates(pair, ds, cname):
    """Features, blob candidates and labels of a pair (the candidates and labels cached under the user cache:
    only the networks run again when other weights are compared)."""
    fname, bname = CONFIGS[cname]
    fcfg = dataclasses.replace(FEATURE_PRESETS[fname], max_keypoints=KEYPOINT_BUDGETS["paper"])
    f1, f2 = pair_features(pair, fcfg)
    path = cache_dir("learned-eval") / f"{digest(pair_digest(pair), fcfg.key(), bname)}.npz"
    if path.is_file():
        with np.load(path) as z:
            return f1, f2, z["matches"], z["scores"], z["lab"]
    matches, scores, _ = blob_candidates(f1, f2, BLOB_PRESETS[bname])
    lab = label_candidates(pair, f1, f2, matches)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, matches=matches, scores=scores, lab=lab)
    return f1, f2, matches, scores, lab


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--weights", nargs="*", help="oanet=PATH / acne=PATH / NAME=shipped, repeatable")
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--thresholds", nargs="*", type=float, default=[0.0],
                    help="logit thresholds of the keep rule (the filters' threshold=; default 0)")
    ap.add_argument("--by-inlier-ratio", action="store_true",
                    help="also the means within bins of the pairs' blob inlier ratio")
    ap.add_argument("--pairs", type=int, default=None, help="first N pairs of each dataset (default: all)")
    args = ap.parse_args(argv)
    specs = _weights(args.weights)
    res = defaultdict(list)  # (config, kind, spec) -> [(P, R)]
    t0 = time.perf_counter()
    for ds in ("planar", "nonplanar"):
        pairs = list(load_dataset(ds))[: args.pairs]
        for pair in pairs:
            for cname in args.configs:
                f1, f2, matches, scores, lab = _candidates(pair, ds, cname)
                ref = matches[lab]
                for name, path, spec in specs:
                    logits = learned_logits(name, f1.kpts, f2.kpts, matches, scores, image_size1=pair.image_size1,
                                            image_size2=pair.image_size2, weights=path)
                    for t in args.thresholds:
                        keep = logits > t  # the filter's rule (threshold=t)
                        mm = evaluate_matches(matches[keep], lab[keep], reference=ref)
                        res[(cname, ds, spec, t)].append((mm.precision, mm.recall, lab.mean() if len(lab) else 0))
    print(f"pairs evaluated in {time.perf_counter() - t0:.0f} s; mean per pair, %, no model step")
    _print(res)
    if args.by_inlier_ratio:
        _print_by_ratio(res)


def _print(res) -> None:
    print(f"{'config':>8} {'kind':>9} {'weights':>48} {'thr':>5} {'P':>6} {'R':>6} {'paper P':>7} {'paper R':>7} {'n':>3}")
    for (cname, ds, spec, t), v in res.items():
        a = np.array(v, float) * 100
        name = spec.partition("=")[0]
        pp = PAPER_TABLE2.get((name, ds), (np.nan, np.nan)) if cname == "baseline" else (np.nan, np.nan)
        print(f"{cname:>8} {ds:>9} {spec[-48:]:>48} {t:5.1f} {np.nanmean(a[:, 0]):6.1f} {np.nanmean(a[:, 1]):6.1f} "
              f"{pp[0]:7.1f} {pp[1]:7.1f} {len(a):3d}")


def _print_by_ratio(res) -> None:
    """The same means within bins of the pairs' blob inlier ratio (the fraction of correct candidates)."""
    bins = ((0, 0.1), (0.1, 0.2), (0.2, 0.4), (0.4, 1.01))
    print("\nby the pair's blob inlier ratio: P / R (pairs)")
    print(f"{'config':>8} {'kind':>9} {'weights':>48} {'thr':>5} " + " ".join(f"{f'{lo:.0%}-{min(hi, 1):.0%}':>17}"
                                                                       for lo, hi in bins))
    for (cname, ds, spec, t), v in res.items():
        a = np.array(v, float)
        cells = []
        for lo, hi in bins:
            sel = (a[:, 2] >= lo) & (a[:, 2] < hi)
            cells.append(f"{100 * np.nanmean(a[sel, 0]):5.1f} /{100 * np.nanmean(a[sel, 1]):5.1f} ({sel.sum():2d})"
                         if sel.any() else f"{'-':>17}")
        print(f"{cname:>8} {ds:>9} {spec[-48:]:>48} {t:5.1f} " + " ".join(cells))


if __name__ == "__main__":
    main()
