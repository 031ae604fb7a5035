"""How much the geometry ranking of the methods depends on the robust estimator.

Every method's output (the blob candidates, the filters, OpenCV's ratio test and mutual nearest neighbours on
the same descriptors) goes to each estimator at each threshold: OpenCV's USAC as the ``ransac`` (uniform
sampling), ``prosac`` (PROSAC by the match ranking) and ``magsac`` (confidence 0.9999, 100 000 iterations)
model steps, and PoseLib's LO-RANSAC (``estimate_homography`` / ``estimate_fundamental``, confidence 0.9999,
100 000 iterations) (``poselib``, a dependency pinned at 2.0.5). The score of a method
is the AUC of the mean corner error at 5 px on planar pairs (failures at infinity) and the mean share of the
ground-truth correspondences within 1 ... 19 px of the estimated F on the others (the metrics of ``geometry_metrics``,
:mod:`ctxmatch_lib.geometry_metrics`). For each (estimator, threshold) the methods are ranked per kind, and the
ranking is compared with that of the default, ``magsac`` at 1 px (fb82/MiHo's MAGSAC settings), by Spearman's
rho. The default is fixed from that source, not chosen here: this script shows how far the conclusions move
when it changes; it does not pick a threshold.

    python benchmarks/bench_geometry_sensitivity.py                       # embedded pairs, 1000 keypoints
    CTXMATCH_DATA=/path python benchmarks/bench_geometry_sensitivity.py --dataset planar,nonplanar \\
        --pairs 12 --max-keypoints paper --filters dtm,adalam,gms,th

Estimator times are printed per (estimator, method): mean seconds per pair in this process.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pandas as pd
from scipy.stats import spearmanr

from ctxmatch_lib.blob import BLOB_PRESETS
from ctxmatch_lib.evaluation import select_pairs
from ctxmatch_lib.evaluation.steps import blob_candidates, pair_features, run_filter, run_matcher
from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget
from ctxmatch_lib.geometry import apply_model_step, model_kind_for
from ctxmatch_lib.geometry_metrics import epipolar_consistency, gt_correspondences, homography_corner_error, pose_auc

DEFAULT = ("magsac", 1.0)


def method_outputs(pair, feats, blob, filters, matchers):
    """(name, kpts1, kpts2, matches, scores) of every method on one pair."""
    f1, f2 = pair_features(pair, feats)
    matches, scores, _ = blob_candidates(f1, f2, blob)
    out = [("blob", matches, scores)]
    for name in filters:
        keep, _ = run_filter(name, f1, f2, matches, scores, image_size1=pair.image_size1,
                             image_size2=pair.image_size2, blob_ratio=blob.ratio)
        out.append((name, matches[keep], scores[keep]))
    for name in matchers:
        m, s, _ = run_matcher(name, f1, f2)
        out.append((name, m, s))
    return f1, f2, out


def poselib_fit(kind, p1, p2, threshold, seed):
    import poselib

    opt = {"success_prob": 0.9999, "max_iterations": 100_000, "seed": int(seed)}
    if len(p1) < (4 if kind == "H" else 8):
        return None
    if kind == "H":
        model, info = poselib.estimate_homography(p1, p2, {**opt, "max_reproj_error": threshold}, {})
    else:
        model, info = poselib.estimate_fundamental(p1, p2, {**opt, "max_epipolar_error": threshold}, {})
    return model if info.get("num_inliers", 0) > 0 and np.isfinite(model).all() else None


def score(pair, kind, model, corr):
    if kind == "H":
        return homography_corner_error(model, pair.gt.H, pair.image_size1)
    return float(epipolar_consistency(model, *corr).mean()) if corr is not None else float("nan")


def run(args) -> pd.DataFrame:
    estimators = list(args.steps)
    if "poselib" in estimators:
        try:
            import poselib  # noqa: F401
        except ImportError:
            estimators.remove("poselib")
            print("poselib not installed (a core dependency: pip install -r environment.txt): PoseLib skipped")
    feats = FEATURE_PRESETS["sift-rootsift"]
    budget = keypoint_budget(args.max_keypoints)
    if budget is not None:
        from dataclasses import replace

        feats = replace(feats, max_keypoints=int(budget))
    blob = BLOB_PRESETS[args.blob]
    pairs = select_pairs(args.dataset.split(","), args.pairs)
    records = []
    for i, pair in enumerate(pairs):
        kind = model_kind_for(pair.kind)
        corr = gt_correspondences(pair.gt)
        f1, f2, outputs = method_outputs(pair, feats, blob, args.filters, args.matchers)
        for method, m, s in outputs:
            p1, p2 = f1.kpts[m[:, 0]], f2.kpts[m[:, 1]]
            for est in estimators:
                for t in args.thresholds:
                    t0 = time.perf_counter()
                    if est == "poselib":
                        model = poselib_fit(kind, p1, p2, t, args.seed + i)
                    else:
                        model = apply_model_step(est, f1.kpts, f2.kpts, m, s, kind=kind, rng=args.seed + i,
                                                 estimator={"threshold": t}).model
                    records.append(dict(pair_id=pair.pair_id, kind=pair.kind, method=method, estimator=est,
                                        threshold=t, n_matches=len(m), score=score(pair, kind, model, corr),
                                        time_s=time.perf_counter() - t0))
        print(f"[{i + 1}/{len(pairs)}] {pair.dataset}/{pair.pair_id}", flush=True)
    return pd.DataFrame(records)


def summarise(df: pd.DataFrame) -> None:
    rows = []
    for (kind, est, t, method), g in df.groupby(["kind", "estimator", "threshold", "method"], sort=False):
        value = pose_auc(g["score"].to_numpy(), [5.0])[0] if kind == "planar" else g["score"].mean()
        rows.append(dict(kind=kind, estimator=est, threshold=t, method=method, value=100 * value,
                         time_s=g["time_s"].mean(), pairs=len(g)))
    s = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    for kind, g in s.groupby("kind", sort=False):
        what = "AUC of the corner error at 5 px (%)" if kind == "planar" else "mean epipolar consistency 1..19 px (%)"
        table = g.pivot_table(index="method", columns=["estimator", "threshold"], values="value", sort=False)
        print(f"\n{kind}, {g['pairs'].iloc[0]} pairs: {what}")
        print(table.round(1).to_string())
        ref = table[DEFAULT] if DEFAULT in table.columns else table.iloc[:, 0]
        ranks = table.rank(ascending=False, method="min")
        print(f"ranks (1 = best) and Spearman's rho of each ranking against {DEFAULT[0]} at {DEFAULT[1]:g} px:")
        rho = {c: spearmanr(ref, table[c]).statistic for c in table.columns}
        print(pd.concat([ranks, pd.DataFrame([rho], index=["rho"])]).round(2).to_string())
        times = g.pivot_table(index="method", columns=["estimator", "threshold"], values="time_s", sort=False)
        print("estimator seconds per pair:")
        print(times.round(4).to_string())


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", default="embedded")
    p.add_argument("--pairs", type=int, default=None, help="N pairs evenly spread (default: all)")
    p.add_argument("--max-keypoints", default="1000", help="an integer or a budget name ('paper')")
    p.add_argument("--blob", default="paper-best")
    p.add_argument("--filters", default="dtm,adalam,gms", type=lambda s: [x for x in s.split(",") if x])
    p.add_argument("--matchers", default="opencv_ratio,opencv_mnn", type=lambda s: [x for x in s.split(",") if x])
    p.add_argument("--steps", default="ransac,prosac,magsac,poselib", type=lambda s: [x for x in s.split(",") if x],
                   help="estimators: OpenCV model steps and 'poselib' (skipped when not installed)")
    p.add_argument("--thresholds", default="0.5,1,2,3", type=lambda s: [float(x) for x in s.split(",")])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--csv", default=None, help="also write the per-pair records here")
    args = p.parse_args(argv)
    df = run(args)
    if args.csv:
        df.to_csv(args.csv, index=False)
    summarise(df)


if __name__ == "__main__":
    main()
