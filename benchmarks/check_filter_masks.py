"""Keep masks of every registered filter on real and planted candidate sets: save them, or compare with saved ones.

The check that a refactoring of the filters (one wrapper around each filter's core) left every
decision unchanged. ``--save OUT.npz`` writes, for every filter of :data:`ctxmatch_lib.filters.FILTERS` (or
``--filters a,b``), its keep mask on every candidate set; ``--compare OUT.npz`` recomputes them and prints, per
filter, whether every mask is identical (exit status 1 if one differs).

The candidate sets are

- real: the blob candidates of ``--features`` (default ``sift-rootsift``) at ``--max-keypoints`` (default
  ``paper``, the paper's budget) under each ``--blobs`` setup (default ``paper-best baseline``) on the first
  ``--pairs`` shared pairs (``CTXMATCH_DATA``; planar and non-planar, every ``--step``-th pair);
- planted: :func:`ctxmatch_lib.testing.planted_homography_matches` cases (several seeds, inlier ratios and
  sizes), each also with coincident copies of some rows (new keypoint indices at the same coordinates) and
  with repeated rows, so that the coincident-row merging of the filters that ask for it is exercised.

The filters are called as the evaluation engine calls them (keypoint shapes, the blob setup's ``ratio`` for
the filters with ``uses_blob_ratio``; with ``--tag-scores`` the scores of a real set carry the ratio that
made them, as :func:`ctxmatch_lib.blob.blob_matching` returns them). The inputs are saved next to the masks (``--save``), and ``--compare``
reads them back from there, so a change of the feature or blob code between the two runs does not show as
a filter change.

Run::

    CTXMATCH_DATA=/path/to/data nice .venv/bin/python benchmarks/check_filter_masks.py --pairs 24 \\
        --save /tmp/masks_before.npz
    CTXMATCH_DATA=/path/to/data nice .venv/bin/python benchmarks/check_filter_masks.py \\
        --compare /tmp/masks_before.npz
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def planted_sets():
    """Planted candidate sets: name -> dict of filter inputs (keypoints, matches, scores, sizes)."""
    from ctxmatch_lib.testing import planted_homography_matches

    out = {}
    for seed, (n, inl) in enumerate([(300, 0.5), (800, 0.3), (1500, 0.4), (120, 0.8), (2000, 0.15)]):
        pm = planted_homography_matches(n, inl, informative_scores=bool(seed % 2), rng=seed)
        base = dict(kpts1=pm.kpts1, kpts2=pm.kpts2, matches=pm.matches, scores=pm.scores,
                    image_size1=np.asarray(pm.image_size), image_size2=np.asarray(pm.image_size))
        out[f"planted{seed}"] = base
        rng = np.random.default_rng(100 + seed)
        # Coincident copies: new keypoint indices at the coordinates of some rows, with their own scores.
        rows = rng.choice(n, size=max(n // 10, 3), replace=False)
        k1 = np.vstack([pm.kpts1, pm.kpts1[pm.matches[rows, 0]]])
        k2 = np.vstack([pm.kpts2, pm.kpts2[pm.matches[rows, 1]]])
        new = np.c_[len(pm.kpts1) + np.arange(len(rows)), len(pm.kpts2) + np.arange(len(rows))]
        m = np.vstack([pm.matches, new]).astype(np.int64)
        s = np.r_[pm.scores, rng.uniform(size=len(rows))]
        perm = rng.permutation(len(m))
        out[f"planted{seed}-coincident"] = dict(base, kpts1=k1, kpts2=k2, matches=m[perm], scores=s[perm])
        # Repeated rows (same keypoint indices), and many-to-many rows (one keypoint, several partners).
        rep = rng.choice(n, size=max(n // 20, 2), replace=False)
        other = rng.choice(n, size=len(rep))
        m2 = np.vstack([pm.matches, pm.matches[rep], np.c_[pm.matches[rep, 0], other]]).astype(np.int64)
        s2 = np.r_[pm.scores, pm.scores[rep], rng.uniform(size=len(rep))]
        perm = rng.permutation(len(m2))
        out[f"planted{seed}-repeated"] = dict(base, matches=m2[perm], scores=s2[perm])
    return out


def real_sets(n_pairs: int, step: int, features: str, blobs, max_keypoints):
    """Real candidate sets: name -> dict of filter inputs (with keypoint shapes and the blob ratio)."""
    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import blob_candidates, pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget

    fcfg = FEATURE_PRESETS[features]
    budget = keypoint_budget(max_keypoints, argument="--max-keypoints")
    if budget is not None:
        fcfg = replace(fcfg, max_keypoints=budget)
    pairs = select_pairs(["planar", "nonplanar"], step=step)[:n_pairs]
    out = {}
    for pair in pairs:
        f1, f2 = pair_features(pair, fcfg)
        for blob in blobs:
            cfg = BLOB_PRESETS[blob]
            m, s, _ = blob_candidates(f1, f2, cfg)
            d = dict(kpts1=f1.kpts, kpts2=f2.kpts, matches=m, scores=np.asarray(s, np.float64),
                     image_size1=np.asarray(pair.image_size1), image_size2=np.asarray(pair.image_size2),
                     ratio=np.asarray(cfg.ratio))
            if f1.shapes is not None and f2.shapes is not None:
                d.update(shapes1=f1.shapes, shapes2=f2.shapes)
            out[f"{pair.pair_id.replace('/', '__')}@{blob}"] = d
        print(f"  {pair.pair_id}: {len(f1.kpts)} / {len(f2.kpts)} keypoints, "
              + ", ".join(f"{b} {len(out[pair.pair_id.replace('/', '__') + '@' + b]['matches'])}" for b in blobs),
              flush=True)
    return out


def keep_mask(name: str, d: dict, tag_scores: bool = False) -> np.ndarray:
    """``FILTERS[name]`` on one candidate set, called as the evaluation engine calls it (``tag_scores``: the
    scores of a real set carry the blob ratio that made them, as ``blob_matching`` returns them)."""
    from ctxmatch_lib.filters import FILTERS

    func = FILTERS[name]
    params = {}
    if "ratio" in d and getattr(func, "uses_blob_ratio", False):
        params["ratio"] = str(d["ratio"])
    if len(d["matches"]) == 0:
        return np.zeros(0, bool)
    scores = d["scores"]
    if tag_scores and "ratio" in d:
        from ctxmatch_lib.filters import nnr_scores

        scores = nnr_scores(scores, str(d["ratio"]))
    out = func(d["kpts1"], d["kpts2"], d["matches"], scores, image_size1=tuple(int(v) for v in d["image_size1"]),
               image_size2=tuple(int(v) for v in d["image_size2"]), shapes1=d.get("shapes1"),
               shapes2=d.get("shapes2"), **params)
    keep = np.asarray(getattr(out, "keep", out))
    if keep.shape != (len(d["matches"]),) or keep.dtype != bool:
        raise ValueError(f"filter {name!r} returned {keep.dtype} {keep.shape}, not a ({len(d['matches'])},) mask")
    return keep


def _flatten(sets: dict) -> dict:
    return {f"in|{s}|{k}": v for s, d in sets.items() for k, v in d.items()}


def _unflatten(z) -> dict:
    sets: dict = {}
    for key in z.files:
        if key.startswith("in|"):
            _, s, k = key.split("|")
            sets.setdefault(s, {})[k] = z[key]
    return sets


def main(argv=None) -> int:
    from ctxmatch_lib.filters import FILTERS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--save", type=Path, metavar="OUT.npz", help="write the inputs and keep masks here")
    mode.add_argument("--compare", type=Path, metavar="OUT.npz", help="compare with the masks saved there")
    parser.add_argument("--pairs", type=int, default=24, help="real pairs (default 24; 0: planted sets only)")
    parser.add_argument("--step", type=int, default=2, help="every STEP-th shared pair (default 2)")
    parser.add_argument("--features", default="sift-rootsift")
    parser.add_argument("--blobs", nargs="+", default=["paper-best", "baseline"])
    parser.add_argument("--max-keypoints", default="paper")
    parser.add_argument("--filters", default="", help="comma-separated names (default: every registered filter)")
    parser.add_argument("--inputs", type=Path, metavar="IN.npz",
                        help="with --save: take the candidate sets saved in IN.npz instead of building them")
    parser.add_argument("--tag-scores", action="store_true",
                        help="the real sets' scores carry their blob ratio (as blob_matching returns them)")
    args = parser.parse_args(argv)
    names = [n for n in args.filters.split(",") if n] if args.filters else list(FILTERS)
    unknown = [n for n in names if n not in FILTERS]
    if unknown:
        parser.error(f"--filters: unknown filter(s) {', '.join(unknown)}")

    if args.compare is not None:
        if not args.compare.is_file():
            parser.error(f"--compare: no file {args.compare}")
        saved = np.load(args.compare)
        sets = _unflatten(saved)
        print(f"{len(sets)} candidate sets read from {args.compare}")
    elif args.inputs is not None:
        sets = _unflatten(np.load(args.inputs))
        print(f"{len(sets)} candidate sets read from {args.inputs}")
    else:
        sets = planted_sets()
        if args.pairs > 0:
            if not os.environ.get("CTXMATCH_DATA"):
                print("CTXMATCH_DATA is not set: planted sets only", file=sys.stderr)
            else:
                sets.update(real_sets(args.pairs, args.step, args.features, args.blobs, args.max_keypoints))
    n_real = sum("@" in s for s in sets)
    print(f"{len(sets)} candidate sets ({n_real} real, {len(sets) - n_real} planted), "
          f"{sum(len(d['matches']) for d in sets.values())} rows")

    masks = {}
    status = 0
    for name in names:
        t0 = time.process_time()
        diffs = []
        for s, d in sets.items():
            keep = keep_mask(name, d, args.tag_scores)
            masks[f"mask|{name}|{s}"] = keep
            if args.compare is not None:
                key = f"mask|{name}|{s}"
                if key not in saved.files:
                    diffs.append(f"{s}: not saved")
                elif saved[key].shape != keep.shape or not np.array_equal(saved[key], keep):
                    diffs.append(f"{s}: {int((saved[key] != keep).sum()) if saved[key].shape == keep.shape else -1}"
                                 " rows differ")
        cpu = time.process_time() - t0
        if args.compare is None:
            print(f"{name:<9} {len(sets)} sets, {cpu:.1f} s CPU", flush=True)
        else:
            print(f"{name:<9} {len(sets)} sets, {cpu:.1f} s CPU: "
                  + ("identical on every set" if not diffs else f"DIFFERS on {len(diffs)}: " + "; ".join(diffs[:5])),
                  flush=True)
            status = status or int(bool(diffs))
    if args.save is not None:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(args.save, **_flatten(sets), **masks)
        print(f"inputs and keep masks written to {args.save}")
    return status


if __name__ == "__main__":
    sys.exit(main())
