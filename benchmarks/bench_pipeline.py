"""The whole pipeline against OpenCV's, per pair, on the shared planar pairs.

Per pair of ``--dataset`` (default ``planar``: the 31 shared HPatches / Oxford / homogr pairs under
``CTXMATCH_DATA``), in one process and one run:

* **features** (shared by both pipelines, timed separately): SIFT + RootSIFT of both images with the
  default :class:`~ctxmatch_lib.features.FeatureConfig` (8 000 keypoints), extracted without the disk cache
  so that the time is the extraction's (``--cached-features`` reuses the cache and prints no feature time);
* **ctxmatch**: blob matching ``--blob`` (default ``paper-best``), then DTM (the paper's alpha boundary, DTM2),
  then the estimator on DTM's output;
* **OpenCV**: ``cv2.BFMatcher(NORM_L2).knnMatch(k=2)`` on the same descriptors with Lowe's ratio ``--ratio``
  (0.8; :func:`~ctxmatch_lib.opencv_matchers.opencv_ratio_matches`), then the same estimator, the matches
  ranked by their ratio;
* **blob+est** (for reference, ``--no-raw`` leaves it out): the estimator straight on the blob candidates,
  without DTM, ranked by the blob score: what the estimator costs on 10 000 - 33 000 many-to-many rows.

The estimator (``--estimator``, default ``prosac``) is a model step of :mod:`ctxmatch_lib.geometry`
(:func:`~ctxmatch_lib.geometry.apply_model_step`): OpenCV's USAC with MAGSAC++ scoring, sigma-consensus
local optimisation and early termination at the confidence; ``prosac`` samples the best-ranked matches first
(PROSAC, what the field uses on large candidate sets), ``ransac`` / ``magsac`` sample uniformly. The same step,
settings and seed serve both pipelines.

Times are CPU process times of one thread (BLAS and OpenCV limited to ``--threads``, default 1), the median
of ``--repeat`` runs of each step (default 3) after an untimed warm-up on the first pair; the time to
geometry is matching + filtering + estimator, features excluded (they are shared). Accuracy: the mean
corner error of the estimated homography against the ground truth (the four image-1 corners mapped by both,
the mean distance in image-2 pixels; ``inf`` without a model), and its AUC over pairs at 1 / 3 / 5 / 10 px
(the area under the cumulative error curve up to the threshold, divided by it; failures count as ``inf``),
averaged over ``--seeds`` estimator seeds (default 5): one sample of a randomised estimator moves the AUC of
31 pairs by a point or more, as much as the difference the comparison looks for.

The matcher and the metrics are the library's: :func:`ctxmatch_lib.opencv_matchers.opencv_ratio_matches`,
:func:`ctxmatch_lib.geometry_metrics.homography_corner_error` and :func:`~ctxmatch_lib.geometry_metrics.pose_auc`
(the engine's ``opencv_ratio`` rows and geometry columns).

Run::

    CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_pipeline.py
    CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_pipeline.py --pairs 5 --repeat 1 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path



def _set_threads(n: int) -> None:
    """BLAS / OpenMP threads, set before numpy loads its BLAS (OpenCV's are set in :func:`main`)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(n)


def _threads_arg(argv) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    for i, a in enumerate(argv):
        if a == "--threads" and i + 1 < len(argv):
            return int(argv[i + 1])
        if a.startswith("--threads="):
            return int(a.split("=", 1)[1])
    return 1


# ------------------------------------------------------------------------------------------ steps


def _clock(fn, repeat: int):
    """``(median CPU seconds, result of the last call)`` of ``repeat`` calls of ``fn``."""
    import numpy as np

    times, out = [], None
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return float(np.median(times)), out


def _run_pair(pair, f1, f2, args, blob_cfg):
    """Every timed step of one pair; returns a dict of times (s), sizes and corner errors."""
    from ctxmatch_lib.dtm import dtm
    from ctxmatch_lib.evaluation.steps import blob_candidates
    from ctxmatch_lib.geometry import apply_model_step
    from ctxmatch_lib.geometry_metrics import homography_corner_error as corner_error
    from ctxmatch_lib.opencv_matchers import opencv_ratio_matches

    def estimate(matches, scores, seed=args.seed):
        fit = apply_model_step(args.estimator, f1.kpts, f2.kpts, matches, scores, kind="H", rng=seed)
        return fit.model

    def errors(H, matches, scores):
        """Corner errors of the timed fit (seed ``--seed``) and of the other ``--seeds`` seeds."""
        rest = [estimate(matches, scores, args.seed + k) for k in range(1, args.seeds)]
        return [corner_error(h, gt, size) for h in [H, *rest]]

    rec = {"pair": pair.pair_id, "kpts": [len(f1.kpts), len(f2.kpts)]}
    gt = pair.gt.H
    size = tuple(pair.image_size1)
    # OpenCV
    t, (m, r) = _clock(lambda: opencv_ratio_matches(f1.desc, f2.desc, ratio=args.ratio), args.repeat)
    te, H = _clock(lambda: estimate(m, r), args.repeat)
    errs = errors(H, m, r)
    rec["opencv"] = dict(match=t, est=te, total=t + te, rows=len(m), err=errs[0], errs=errs)
    # ctxmatch
    t, (m, s, _) = _clock(lambda: blob_candidates(f1, f2, blob_cfg), args.repeat)
    td, res = _clock(lambda: dtm(f1.kpts, f2.kpts, m, s, image_size1=tuple(pair.image_size1),
                                 image_size2=tuple(pair.image_size2)), args.repeat)
    keep = res.keep
    te, H = _clock(lambda: estimate(m[keep], s[keep]), args.repeat)
    errs = errors(H, m[keep], s[keep])
    rec["ctxmatch"] = dict(match=t, dtm=td, est=te, total=t + td + te, rows=len(m), kept=int(keep.sum()),
                           err=errs[0], errs=errs)
    if not args.no_raw:
        te, H = _clock(lambda: estimate(m, s), args.repeat)
        errs = errors(H, m, s)
        rec["blob+est"] = dict(match=t, est=te, total=t + te, rows=len(m), err=errs[0], errs=errs)
    return rec


def main(argv=None) -> int:
    _set_threads(_threads_arg(argv))
    import cv2
    import numpy as np

    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.features import FeatureConfig, extract_features
    from ctxmatch_lib.geometry import ROBUST_STEPS
    from ctxmatch_lib.geometry_metrics import CORNER_AUC_THRESHOLDS_PX as AUC_THRESHOLDS
    from ctxmatch_lib.geometry_metrics import pose_auc

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", default="planar", help="dataset or group of CTXMATCH_DATA (default planar)")
    parser.add_argument("--pairs", type=int, default=None, help="the first N pairs only")
    parser.add_argument("--blob", default="paper-best", choices=list(BLOB_PRESETS))
    parser.add_argument("--estimator", default="prosac", choices=list(ROBUST_STEPS),
                        help="model step of ctxmatch_lib.geometry for both pipelines (default prosac)")
    parser.add_argument("--ratio", type=float, default=0.8, help="Lowe's ratio of the OpenCV pipeline")
    parser.add_argument("--repeat", type=int, default=3, help="runs per step, the median kept (default 3)")
    parser.add_argument("--threads", type=int, default=1, help="BLAS and OpenCV threads (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="the estimator's seed (the timed fits)")
    parser.add_argument("--seeds", type=int, default=5,
                        help="accuracy over this many estimator seeds, --seed onwards (default 5): the AUC is "
                             "their mean, so that one lucky or unlucky sample does not decide the comparison")
    parser.add_argument("--cached-features", action="store_true", help="reuse the feature cache (no feature time)")
    parser.add_argument("--no-raw", action="store_true", help="leave out the estimator on raw blob candidates")
    parser.add_argument("--json", type=Path, help="also write the per-pair numbers here")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat must be a positive integer, got {args.repeat}")
    if args.seeds < 1:
        parser.error(f"--seeds must be a positive integer, got {args.seeds}")
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: no real pairs to time", file=sys.stderr)
        return 2
    cv2.setNumThreads(args.threads)
    pairs = [p for p in select_pairs(args.dataset) if p.kind == "planar"][:args.pairs]
    if not pairs:
        print(f"no planar pair in {args.dataset!r}", file=sys.stderr)
        return 2
    config = FeatureConfig()
    blob_cfg = BLOB_PRESETS[args.blob]
    methods = ["opencv", "ctxmatch"] + ([] if args.no_raw else ["blob+est"])
    print(f"{len(pairs)} planar pairs; features {config.detector}+{config.descriptor} at {config.max_keypoints} "
          f"keypoints; blob {args.blob}; estimator {args.estimator}; ratio {args.ratio}; {args.threads} thread(s); "
          f"CPU seconds, median of {args.repeat}")
    print(f"{'pair':<26} {'feat s':>6} | {'cv rows':>7} {'match':>6} {'est':>6} {'total':>6} {'err px':>7} | "
          f"{'blob rows':>9} {'kept':>5} {'blob':>6} {'dtm':>6} {'est':>6} {'total':>6} {'err px':>7}"
          + ("" if args.no_raw else f" | {'raw est':>7} {'err px':>7}") + f" | {'ctx/cv':>6}")
    recs = []
    cache = None if args.cached_features else False
    for i, pair in enumerate(pairs):
        t0 = time.process_time()
        f1 = extract_features(pair.image1, config, cache_dir=cache)
        f2 = extract_features(pair.image2, config, cache_dir=cache)
        tf = time.process_time() - t0
        if i == 0:  # untimed warm-up: numba kernels load, imports happen
            _run_pair(pair, f1, f2, argparse.Namespace(**{**vars(args), "repeat": 1}), blob_cfg)
        rec = _run_pair(pair, f1, f2, args, blob_cfg)
        rec["features"] = None if args.cached_features else tf
        recs.append(rec)
        cv, cx = rec["opencv"], rec["ctxmatch"]
        feat = "     -" if rec["features"] is None else f"{tf:>6.2f}"
        line = (f"{pair.pair_id:<26} {feat} | {cv['rows']:>7} {cv['match']:>6.3f} {cv['est']:>6.3f} "
                f"{cv['total']:>6.3f} {cv['err']:>7.2f} | {cx['rows']:>9} {cx['kept']:>5} {cx['match']:>6.3f} "
                f"{cx['dtm']:>6.3f} {cx['est']:>6.3f} {cx['total']:>6.3f} {cx['err']:>7.2f}")
        if not args.no_raw:
            line += f" | {rec['blob+est']['est']:>7.3f} {rec['blob+est']['err']:>7.2f}"
        print(line + f" | {cx['total'] / cv['total']:>5.2f}x", flush=True)

    print(f"\n{'pipeline':<10} {'time to geometry s':>18} {'match':>7} {'dtm':>6} {'est':>6} {'median err':>10} "
          + " ".join(f"{'AUC@' + format(t, 'g'):>7}" for t in AUC_THRESHOLDS) + f" {'no model':>8}")
    summary = {}
    for name in methods:
        rows = [r[name] for r in recs]
        err = np.array([r["err"] for r in rows])
        per_seed = np.array([[r["errs"][k] for r in rows] for k in range(args.seeds)])
        auc = [float(a) for a in np.mean([pose_auc(e, AUC_THRESHOLDS) for e in per_seed], axis=0)]
        tot = sum(r["total"] for r in rows)
        summary[name] = dict(total=tot, auc=auc, median_err=float(np.median(err)))
        print(f"{name:<10} {tot:>18.2f} {sum(r['match'] for r in rows):>7.2f} "
              f"{sum(r.get('dtm', 0.0) for r in rows):>6.2f} {sum(r['est'] for r in rows):>6.2f} "
              f"{np.median(err):>10.2f} " + " ".join(f"{100 * a:>7.1f}" for a in auc)
              + f" {int(np.isinf(err).sum()):>8}")
    if not args.cached_features:
        print(f"features (shared, not in the totals): {sum(r['features'] for r in recs):.2f} s")
    cx, cv = summary["ctxmatch"], summary["opencv"]
    faster = cx["total"] <= cv["total"]
    as_good = all(a >= b for a, b in zip(cx["auc"], cv["auc"]))
    print(f"ctxmatch / OpenCV time to geometry: {cx['total'] / cv['total']:.2f}x "
          f"({'met' if faster else 'NOT met'}: target <= 1); AUC at every threshold "
          f"{'equal or better' if as_good else 'NOT all equal or better'}")
    print("err px: mean corner error of the estimated H against the ground truth (seed --seed); AUC in percent over "
          f"the pairs (pairs without a model count as failures), the mean over {args.seeds} estimator seed(s)")
    if args.json:
        args.json.write_text(json.dumps(dict(args={k: str(v) for k, v in vars(args).items()}, pairs=recs,
                                             summary=summary), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
