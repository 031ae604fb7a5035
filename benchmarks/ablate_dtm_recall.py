"""Ablation of DTM's recall gap against the paper: DTM1 / DTM2 next to Tables 2 and 3.

DTM1 recall was 6-28 points below the paper's in every cell at the earlier budget of 8000 keypoints per image.
This script asks which input factor moves DTM1 and DTM2 (no model) toward the paper. For the paper's baseline
(SIFT + RootSIFT, one-to-one NNR, blob preset ``baseline``; Table 2) and best configuration (HarrisZ + SOSNet
with stand-in weights, blob preset ``paper-best-overlap``; Table 3) it evaluates, per kind (planar, non-planar),
the like-for-like reference (keypoint budget ``"paper"``, 1500 per image, :data:`ctxmatch_lib.features.
KEYPOINT_BUDGETS`) and variants that each change one factor:

* ``k1000`` / ``k3000`` / ``k8000``: the candidate count, through the keypoint budget;
* ``upright``: one keypoint per location through ``FeatureConfig(upright=True)``: SIFT's keypoints that only
  differ by orientation are merged before the cap, but the descriptor also loses its rotation invariance
  (two factors at once; baseline only: HarrisZ has no orientation duplicates);
* ``dedup``: one keypoint per location, nothing else changed: within the capped keypoints of each image, a
  keypoint whose (x, y) coincides exactly with a stronger one is dropped (with its SIFT orientation and
  descriptor) before blob matching. The engine cannot take modified features, so this variant and its own
  reference (``ref*``, which must equal ``ref``) run the steps of :mod:`ctxmatch_lib.evaluation.steps` here;
* ``f'=1``: the best configuration's blob setup with f' = 1 instead of 5 (one-to-one candidates);
* ``half``: both images downscaled by 0.5 (``cv2.INTER_AREA``, PNG copies in the user cache under
  ``ablation/half``), the ground truth mapped to the new pixels (x' = s (x + 0.5) - 0.5: H' = T2 H T1^-1,
  F' = T2^-T F T1^-1, hand points mapped) and the ground-truth threshold of method D halved (7.5 px), so that
  the labels stay geometrically the same and only what the filters see changes.

Columns: mean candidates and correct candidates (the recall reference) per pair, the blob candidates' inlier
ratio (the blob row's precision), DTM1 and DTM2 precision and recall in %, and DTM1 / DTM2 recall minus the
paper's (points). ``R1reach`` (rows ``ref*`` and ``dedup`` only) is DTM1's recall among the correct candidates
it could reach: those whose keypoints lie inside the convex hull of DTM1's output in both images (a correct
candidate outside it lies in a region DTM1 dropped whole; inside it, it was dropped locally). Means follow
the paper's tables: an empty output counts as 0 % precision and 0 % recall; pairs without a correct candidate
are left out of the recall mean. Rows computed by the engine read and write the shared evaluation cache.

Run: ``CTXMATCH_DATA=/path/to/data OMP_NUM_THREADS=1 .venv/bin/python benchmarks/ablate_dtm_recall.py
[--pairs 24 | --pairs all] [--jobs 1] [--setups baseline,best]``. The default, 24 pairs evenly spread over the
55 shared real pairs, took 9 min on one process (2 cores shared with another evaluation) with the baseline's
features cached, and ``--pairs all`` 12 min more after it; a cold run adds the HarrisZ + SOSNet stand-in features (about 1.3 s per image and budget).
"""

from __future__ import annotations

import argparse
import hashlib
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from ctxmatch_lib.cache import cache_dir
from ctxmatch_lib.blob import BLOB_PRESETS
from ctxmatch_lib.datasets.base import EpipolarGT, HomographyGT, Pair
from ctxmatch_lib.evaluation import evaluate_cached, select_pairs
from ctxmatch_lib.evaluation.steps import blob_candidates, label_candidates, pair_features, run_filter
from ctxmatch_lib.features import FEATURE_PRESETS, KEYPOINT_BUDGETS
from ctxmatch_lib.features.base import Features
from ctxmatch_lib.groundtruth.core import GT_THRESHOLD_PX
from ctxmatch_lib.metrics import evaluate_matches, recall
from ctxmatch_lib.report import PAPER_GT_COUNTS, paper_table

KINDS = ("planar", "nonplanar")
SETUPS = {"baseline": ("sift-rootsift", "baseline"), "best": ("harrisz-sosnet", "paper-best-overlap")}
REF = KEYPOINT_BUDGETS["paper"]
SCALE = 0.5


# ----------------------------------------------------------------------------------------------- inputs


def _scale_matrix(size_old, size_new) -> np.ndarray:
    """Pixel-centre map of a resize: x' = s (x + 0.5) - 0.5, with s = new / old per axis."""
    sx, sy = size_new[0] / size_old[0], size_new[1] / size_old[1]
    return np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1.0]])


def _map(T: np.ndarray, pts):
    if pts is None:
        return None
    p = np.c_[np.asarray(pts, np.float64), np.ones(len(pts))] @ T.T
    return p[:, :2] / p[:, 2:]


def scaled_pairs(pairs, scale: float) -> list[Pair]:
    """Copies of ``pairs`` with both images resized by ``scale`` and the ground truth mapped to them."""
    import cv2

    from ctxmatch_lib.features.io import load_image

    root = cache_dir("ablation") / f"scale{scale:g}"
    out = []
    for p in pairs:
        images, sizes, Ts = [], [], []
        for path, size in ((p.image1, p.image_size1), (p.image2, p.image_size2)):
            new = (max(1, round(size[0] * scale)), max(1, round(size[1] * scale)))
            # Named by the source file (path, size, time), not the pair's position in the selection.
            st = Path(path).stat()
            name = f"{Path(path).resolve()}|{st.st_size}|{st.st_mtime_ns}|{scale}"
            dst = root / (hashlib.sha1(name.encode()).hexdigest()[:16] + ".png")
            if not dst.is_file():
                dst.parent.mkdir(parents=True, exist_ok=True)
                img = cv2.resize(load_image(path, gray=True), new, interpolation=cv2.INTER_AREA)
                tmp = dst.with_suffix(".tmp.png")
                cv2.imwrite(str(tmp), img)
                tmp.replace(dst)
            images.append(dst)
            sizes.append(new)
            Ts.append(_scale_matrix(size, new))
        T1, T2 = Ts
        if isinstance(p.gt, HomographyGT):
            H = T2 @ p.gt.H @ np.linalg.inv(T1)
            gt = HomographyGT(H / H[2, 2], _map(T1, p.gt.pts1), _map(T2, p.gt.pts2))
        elif isinstance(p.gt, EpipolarGT):
            F = np.linalg.inv(T2).T @ p.gt.F @ np.linalg.inv(T1)
            gt = EpipolarGT(F / np.linalg.norm(F), _map(T1, p.gt.pts1), _map(T2, p.gt.pts2))
        else:
            raise ValueError(f"pair {p.pair_id!r}: cannot scale ground truth {type(p.gt).__name__}")
        out.append(Pair(p.pair_id, images[0], images[1], sizes[0], sizes[1], p.kind, gt,
                        dataset=f"{p.dataset}-x{scale:g}"))
    return out


def one_per_location(f: Features) -> tuple[Features, int]:
    """``f`` without the keypoints whose (x, y) repeats a stronger one (rows are strongest first)."""
    _, first = np.unique(f.kpts, axis=0, return_index=True)
    keep = np.sort(first)
    g = Features(f.kpts[keep], f.shapes[keep], f.desc[keep], f.scales[keep], f.angles[keep], f.responses[keep],
                 f.metric, f.image_size)
    return g, len(f) - len(keep)


# ------------------------------------------------------------------------------------------ evaluation


def engine_rows(pairs, features, blob_cfg, budget, **kwargs) -> pd.DataFrame:
    df = evaluate_cached(pairs, features=[features], blobs=[blob_cfg], filters=["dtm1", "dtm2"],
                         models=["none"], max_keypoints=budget, n_jobs=kwargs.pop("n_jobs"), **kwargs)
    return df[df.model == "none"]


def _inside_hull(pts: np.ndarray, hull_pts: np.ndarray) -> np.ndarray:
    from scipy.spatial import Delaunay, QhullError

    hull_pts = np.unique(hull_pts, axis=0)
    if len(hull_pts) < 3:
        return np.zeros(len(pts), bool)
    try:
        return Delaunay(hull_pts).find_simplex(pts) >= 0
    except QhullError:  # collinear output: no area to be inside
        return np.zeros(len(pts), bool)


def steps_rows(pairs, features, blob_cfg, budget, *, dedup: bool) -> tuple[pd.DataFrame, float]:
    """The engine's rows recomputed step by step (optionally with one keypoint per location), plus
    DTM1's recall among the correct candidates inside the hull of its output; and the share of keypoints
    dropped as coincident."""
    cfg = replace(FEATURE_PRESETS[features], max_keypoints=budget)
    rows, dropped, total = [], 0, 0
    for p in pairs:
        f1, f2 = pair_features(p, cfg)
        total += len(f1) + len(f2)
        if dedup:
            (f1, d1), (f2, d2) = one_per_location(f1), one_per_location(f2)
            dropped += d1 + d2
        mt, sc, _ = blob_candidates(f1, f2, blob_cfg)
        lab = label_candidates(p, f1, f2, mt)
        ref = mt[lab]
        base = {"pair_id": p.pair_id, "kind": p.kind, "model": "none", "error": "", "n_candidates": len(mt)}
        mm = evaluate_matches(mt, lab, reference=ref)
        rows.append({**base, "method": "blob", "precision": mm.precision, "recall": mm.recall,
                     "output": mm.output, "n_gt": mm.n_gt})
        for name in ("dtm1", "dtm2"):
            keep, _ = run_filter(name, f1, f2, mt, sc, image_size1=p.image_size1, image_size2=p.image_size2,
                                 blob_ratio=blob_cfg.ratio)
            mm = evaluate_matches(mt[keep], lab[keep], reference=ref)
            row = {**base, "method": name, "precision": mm.precision, "recall": mm.recall, "output": mm.output,
                   "n_gt": mm.n_gt}
            if name == "dtm1":
                out = mt[keep]
                inside = (_inside_hull(f1.kpts[ref[:, 0]], f1.kpts[out[:, 0]])
                          & _inside_hull(f2.kpts[ref[:, 1]], f2.kpts[out[:, 1]]))
                reach = ref[inside]
                row["recall_reach"] = recall(out[lab[keep]], np.ones(int(lab[keep].sum()), bool), reach) \
                    if len(reach) else np.nan
            rows.append(row)
    return pd.DataFrame(rows), dropped / max(total, 1)


def summary(df: pd.DataFrame) -> dict:
    """Means per kind, the paper's conventions (empty output: 0 % precision and recall)."""
    df = df[df.error == ""]
    out = {}
    for kind in KINDS:
        d = df[df.kind == kind]
        if d.empty:
            continue
        s = {}
        for method in ("blob", "dtm1", "dtm2"):
            m = d[d.method == method]
            empty = m.output == 0
            prec = m.precision.where(~empty, 0.0)
            rec = m.recall.where(~empty | m.recall.isna(), 0.0)
            s[method] = (100 * prec.mean(), 100 * rec.mean())
        blob = d[d.method == "blob"]
        s["cand"], s["gt"] = blob.n_candidates.mean(), blob.n_gt.mean()
        if "recall_reach" in d.columns:
            s["reach"] = 100 * d[d.method == "dtm1"].recall_reach.mean()
        s["pairs"] = d.pair_id.nunique()
        out[kind] = s
    return out


def variants(setup: str):
    """(label, how) of each row: how = (runner, features, blob config, budget, extra)."""
    features, blob = SETUPS[setup]
    cfg = BLOB_PRESETS[blob]
    yield "ref", ("engine", features, cfg, REF, {})
    for k in (1000, 3000, 8000):
        yield f"k{k}", ("engine", features, cfg, k, {})
    if setup == "baseline":
        yield "upright", ("engine", "sift-rootsift-upright", cfg, REF, {})
    yield "ref*", ("steps", features, cfg, REF, {"dedup": False})
    yield "dedup", ("steps", features, cfg, REF, {"dedup": True})
    if setup == "best":
        yield "f'=1", ("engine", features, replace(cfg, f_prime=1), REF, {})
    yield "half", ("half", features, cfg, REF, {})


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default="24", help="pairs evenly spread over planar + nonplanar, or 'all' "
                                                  "(default: %(default)s)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes of the engine (default: %(default)s)")
    ap.add_argument("--setups", default="baseline,best", help="comma-separated of baseline, best")
    args = ap.parse_args(argv)
    if args.pairs.strip().lower() == "all":
        select = None
    elif args.pairs.strip().isdigit() and int(args.pairs) > 0:
        select = int(args.pairs)
    else:
        ap.error(f"--pairs must be a positive integer or 'all', got {args.pairs!r}")
    setups = [s.strip() for s in args.setups.split(",") if s.strip()]
    bad = [s for s in setups if s not in SETUPS]
    if bad or not setups:
        ap.error(f"--setups must name some of {list(SETUPS)}, got {args.setups!r}")

    t0 = time.perf_counter()
    pairs = select_pairs(["planar", "nonplanar"], select=select)
    half = None
    results = []  # (setup, label, summary, note)
    for setup in setups:
        for label, (runner, features, cfg, budget, extra) in variants(setup):
            t1 = time.perf_counter()
            note = ""
            if runner == "engine":
                s = summary(engine_rows(pairs, features, cfg, budget, n_jobs=args.jobs))
            elif runner == "steps":
                df, dropped = steps_rows(pairs, features, cfg, budget, **extra)
                s = summary(df)
                if extra["dedup"]:
                    note = f"{100 * dropped:.1f}% kpts coincident"
            else:
                half = half or scaled_pairs(pairs, SCALE)
                s = summary(engine_rows(half, features, cfg, budget, n_jobs=args.jobs,
                                        gt_threshold=GT_THRESHOLD_PX * SCALE))
            results.append((setup, label, s, note))
            print(f"  [{setup} {label}: {time.perf_counter() - t1:.0f} s]", flush=True)

    n_kind = {k: sum(p.kind == k for p in pairs) for k in KINDS}
    print(f"\nDTM recall ablation, no model; {len(pairs)} pairs ({n_kind['planar']} planar, "
          f"{n_kind['nonplanar']} non-planar); ref = budget 'paper' ({REF} keypoints per image); "
          f"means per pair, P / R in %, dR = ours - paper (points)")
    head = (f"{'setup':8} {'kind':9} {'variant':8} {'cand':>6} {'gt':>5} {'blobP':>6} {'P1':>5} {'R1':>5} "
            f"{'P2':>5} {'R2':>5} {'dR1':>6} {'dR2':>6} {'dR1ref':>6} {'R1reach':>7}  note")
    print(head)
    print("-" * len(head))
    for setup in setups:
        paper = paper_table(setup)
        for kind in KINDS:
            pb = paper.loc[(kind, "none", "blob")]
            p1, p2 = paper.loc[(kind, "none", "dtm1")], paper.loc[(kind, "none", "dtm2")]
            pr1, pr2 = p1["recall (%)"], p2["recall (%)"]
            p_gt = PAPER_GT_COUNTS[setup]["n_gt"][KINDS.index(kind)]
            print(f"{setup:8} {kind:9} {'paper':8} {pb['output']:6.0f} {p_gt:5.0f} {pb['precision (%)']:6.1f} "
                  f"{p1['precision (%)']:5.1f} {pr1:5.1f} {p2['precision (%)']:5.1f} {pr2:5.1f}")
            ref_r1 = None
            for s_setup, label, s, note in results:
                if s_setup != setup or kind not in s:
                    continue
                r = s[kind]
                (bp, _), (q1, r1), (q2, r2) = r["blob"], r["dtm1"], r["dtm2"]
                if label == "ref":
                    ref_r1 = r1
                d_ref = f"{r1 - ref_r1:+6.1f}" if ref_r1 is not None and label != "ref" else f"{'':>6}"
                reach = f"{r['reach']:7.1f}" if "reach" in r else f"{'':>7}"
                print(f"{setup:8} {kind:9} {label:8} {r['cand']:6.0f} {r['gt']:5.0f} {bp:6.1f} {q1:5.1f} "
                      f"{r1:5.1f} {q2:5.1f} {r2:5.1f} {r1 - pr1:+6.1f} {r2 - pr2:+6.1f} {d_ref} {reach}  {note}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
