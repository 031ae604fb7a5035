"""Calibrate the keypoint budget of the paper-scale runs on the counts of the paper's Table 2.

The paper's baseline (SIFT + RootSIFT, one-to-one NNR blob matching: f = Ω, f' = 1, t_o = ∞, D≥, W = a) has,
per pair, 1329 / 1370 candidate matches and 293 / 214 ground-truth (method D) matches among them on its planar
/ non-planar data (Table 2: the blob row's "output matches" and the caption). For each keypoint cap K of
``--budgets`` this script extracts SIFT + RootSIFT with at most K keypoints per image on every shared real pair
(planar: HPatches, Oxford graf, homogr; non-planar: kusvod2), runs the baseline blob matching, labels the
candidates with method D and prints the mean counts per pair next to the paper's, with the ratio. The budget
is chosen on these counts only, never on filter results; the choice is
:data:`ctxmatch_lib.features.KEYPOINT_BUDGETS` ``["paper"]``.

Run: ``CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/calibrate_budget.py [--budgets 1000,1500,8000]``
(about 20 s per budget on 2 cores once the images are cached by the OS; features are cached per budget).
"""

from __future__ import annotations

import argparse

from ctxmatch_lib.evaluation import evaluate_cached, select_pairs
from ctxmatch_lib.report import PAPER_GT_COUNTS, paper_table


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budgets", default="1000,1250,1500,1750,2000,8000",
                    help="comma-separated keypoint caps per image (default: %(default)s)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default: %(default)s)")
    args = ap.parse_args(argv)
    budgets = [int(b) for b in args.budgets.split(",") if b.strip()]
    if not budgets or min(budgets) < 1:
        ap.error(f"--budgets must be positive integers, got {args.budgets!r}")

    pairs = select_pairs(["planar", "nonplanar"])
    blob = paper_table("baseline").xs(("none", "blob"), level=("model", "method"))
    gt = dict(zip(("planar", "nonplanar"), PAPER_GT_COUNTS["baseline"]["n_gt"]))
    paper = {kind: (blob.loc[kind, "output"], gt[kind]) for kind in ("planar", "nonplanar")}
    print(f"{len(pairs)} pairs; baseline blob matching, ground truth D; means per pair "
          "(ours / paper = ratio); target: every ratio within 0.85-1.15")
    print(f"{'budget':>7} {'kind':10} {'candidates':>24} {'ground truth':>22} {'kpts/image':>10}")
    for k in budgets:
        df = evaluate_cached(pairs, features=["sift-rootsift"], blobs=["baseline"], filters=(), models=["none"],
                             max_keypoints=k, n_jobs=args.jobs)
        df = df[(df.method == "blob") & (df.error == "")]
        for kind, rows in df.groupby("kind", sort=False):
            cand, n_gt = rows.n_candidates.mean(), rows.n_gt.mean()
            p_cand, p_gt = paper[kind]
            kp = (rows.n_kpts1.mean() + rows.n_kpts2.mean()) / 2
            print(f"{k:>7} {kind:10} {cand:7.0f} / {p_cand:4.0f} = {cand / p_cand:4.2f}   "
                  f"{n_gt:5.0f} / {p_gt:3.0f} = {n_gt / p_gt:4.2f} {kp:10.0f}")


if __name__ == "__main__":
    main()
