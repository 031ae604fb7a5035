"""MOP and MOP+MiHo side by side with the authors' PyTorch code (fb82/MiHo) on real candidates.

Our numpy ports (:func:`ctxmatch_lib.filters.mop.mop_clusters`, :func:`~ctxmatch_lib.filters.mop.mop_miho_clusters`)
and the authors' ``miho_unduplex`` (``src/miho_other.py``, MOP) and ``miho_duplex`` (``src/miho.py``, MOP+MiHo)
run on the SAME blob candidates of the shared real pairs (``CTXMATCH_DATA``): the kinds ``planar`` (HPatches,
Oxford graf, homogr), ``kusvod2`` (dataset ``nonplanar``) and ``strecha`` (dataset ``calibrated``), ``--pairs N``
pairs of each, evenly spread by :func:`ctxmatch_lib.evaluation.select_pairs`. Candidates are the library's own
steps (:func:`~ctxmatch_lib.evaluation.steps.pair_features`, :func:`~ctxmatch_lib.evaluation.steps.blob_candidates`):
SIFT + RootSIFT features (``sift-rootsift``) at ``--max-keypoints`` (default 8000) and the ``paper-best`` blob
preset; both sides get the rows in the canonical order (score, keypoint coordinates, keypoint indices) that our
filters decide in. Labels are the library's ground truth (method D,
:func:`~ctxmatch_lib.evaluation.steps.label_candidates`).

The reference is the authors' code run as published, in its own interpreter (``--ref-python``, a scratch
environment with CPU torch; their code is never imported here, never copied, never a dependency) through
``benchmarks/ref_miho.py`` (``--ref-runner``), given the folder of their ``src/`` (``--ref-miho``). The
runner takes ``IN.npz OUT.npz`` pairs: ``pt1``, ``pt2`` (K, 2) float32, the candidates' keypoints in image 1
and 2 (x, y pixels), and ``seeds``; it returns per seed the authors' ``Hidx``
(-1 = rejected; kept = ``Hidx > -1``, their ``refinement_miho`` mask) and the process time of
``planar_clustering``. One runner process per filter handles every pair (importing torch takes seconds), after
one untimed call. Both sides run with ``check_reflection`` on (``miho_ncc_demo.py``'s setting, MOP* in the
paper; ours: ``reject_reflections=True``). A seed s is ``seed=s`` on our side and the authors'
``random_seed_init = s`` (their ``torch.manual_seed`` inside ``get_avg_hom``) on theirs: the two random streams
differ, so masks of the two sides are compared over all seed pairs, beside the spread of each side across its
own seeds.

Printed per pair and filter: the candidates K; the kept count (mean over seeds) of each side; the keep-mask
Jaccard index ours vs theirs over all ``S x S`` seed pairs (mean and range), ours vs ours and theirs vs theirs over
the ``S (S - 1) / 2`` pairs of seeds of one side (the spread of each side's randomness); precision / recall of each
side (percent, mean over seeds; recall is the library's normalised recall, :func:`ctxmatch_lib.metrics.recall`,
against the pair's correct candidates); the mean CPU (process) time per call of each side, measured around the
filter call of the same runs, one thread on both sides (``torch.set_num_threads(1)`` and OMP / MKL / OpenBLAS
threads 1 in the runner; run this script with ``OMP_NUM_THREADS=1``). Then a summary table per kind: means over
the pairs, CPU times summed over the pairs, and their ratio ours / theirs (< 1: ours faster).

Reference environment (outside this repository)::

    python3.11 -m venv /tmp/miho-ref/.venv
    /tmp/miho-ref/.venv/bin/pip install torch numpy scipy opencv-python-headless matplotlib pillow
    git -C <clone of fb82/MiHo> archive HEAD src | tar -x -C /tmp/miho-ref   # their src/, read at run time
    # ref_miho.py stands in for torchvision, which the authors' modules import at the top but
    # planar_clustering never uses

Run::

    OMP_NUM_THREADS=1 CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_mop_ref.py \\
        --ref-python /tmp/miho-ref/.venv/bin/python --ref-miho /tmp/miho-ref --pairs 2 --seeds 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from itertools import combinations, product
from pathlib import Path

import numpy as np
from _common import canonical_candidates

#: Kind shown -> dataset name of :func:`ctxmatch_lib.evaluation.select_pairs`.
KINDS = {"planar": "planar", "kusvod2": "nonplanar", "strecha": "calibrated"}

#: Our filter -> (the function's name in ``ctxmatch_lib.filters.mop``, the authors' method in the runner).
FILTERS = {"mop": ("mop_clusters", "miho_unduplex"), "mop_miho": ("mop_miho_clusters", "miho_duplex")}
LABELS = {"mop": "MOP", "mop_miho": "MOP+MiHo"}

FEATURES, BLOB = "sift-rootsift", "paper-best"

#: Given to our filters explicitly: the runner's ``check_reflection = True``.
OURS_PARAMS = {"reject_reflections": True}


def jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """|a & b| / |a | b| of two masks; 1 when both are empty."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def cross_jaccard(masks_a: list, masks_b: list) -> list[float]:
    """Jaccard of every mask of ``masks_a`` with every mask of ``masks_b``."""
    return [jaccard(a, b) for a, b in product(masks_a, masks_b)]


def within_jaccard(masks: list) -> list[float]:
    """Jaccard of every pair of distinct masks of ``masks`` (empty for fewer than two)."""
    return [jaccard(a, b) for a, b in combinations(masks, 2)]


def precision_recall(matches: np.ndarray, labels: np.ndarray, keep: np.ndarray) -> tuple[float, float]:
    """Precision and the library's normalised recall (against the correct candidates), in percent."""
    from ctxmatch_lib.metrics import precision, recall

    return 100 * precision(labels[keep]), 100 * recall(matches[keep], labels[keep], matches[labels])


def run_reference(python: str, runner: str, miho: str, method: str, cases: list[dict]) -> list[dict]:
    """The authors' ``method`` on every case (``pt1``, ``pt2``, ``seeds``) in one runner process: per case
    ``labels`` (S, K) and ``cpu`` (S,)."""
    with tempfile.TemporaryDirectory() as tmp:
        files = []
        for i, case in enumerate(cases):
            src, dst = Path(tmp) / f"in-{i:04d}.npz", Path(tmp) / f"out-{i:04d}.npz"
            np.savez(src, **case)
            files += [str(src), str(dst)]
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
                   CUDA_VISIBLE_DEVICES="")
        res = subprocess.run([python, runner, "--miho", miho, "--methods", method, "--", *files],
                             capture_output=True, text=True, env=env)
        if res.returncode != 0:
            raise RuntimeError(f"the reference runner failed ({method}):\n{res.stderr[-3000:]}")
        out = []
        for i in range(len(cases)):
            d = np.load(Path(tmp) / f"out-{i:04d}.npz")
            out.append(dict(labels=d[f"{method}_labels"], cpu=d[f"{method}_cpu"]))
    return out


def run_ours(func, pair, f1, f2, matches, scores, seeds) -> dict:
    """Our filter on one candidate set for every seed: ``labels`` (S, K) and ``cpu`` (S,) process times."""
    labels, cpu = [], []
    for seed in seeds:
        c0 = time.process_time()
        out = func(f1.kpts[:, :2], f2.kpts[:, :2], matches, scores, image_size1=tuple(pair.image_size1),
                   image_size2=tuple(pair.image_size2), shapes1=f1.shapes, shapes2=f2.shapes, seed=int(seed),
                   **OURS_PARAMS)
        cpu.append(time.process_time() - c0)
        keep = np.asarray(out.keep, bool)
        if keep.shape != (len(matches),):
            raise ValueError(f"our filter returned a keep mask of shape {keep.shape}, expected ({len(matches)},)")
        labels.append(np.where(keep, np.asarray(out.labels, np.int64), -1))
    return dict(labels=np.array(labels, np.int64).reshape(len(seeds), len(matches)), cpu=np.array(cpu))


def fmt_range(values: list[float]) -> str:
    """``mean [min, max]`` of Jaccard values, or ``-`` for none."""
    if not values:
        return f"{'-':>19}"
    return f"{np.mean(values):.3f} [{min(values):.2f},{max(values):.2f}]"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ref-python", required=True, help="interpreter of the reference environment (CPU torch)")
    parser.add_argument("--ref-miho", required=True, help="the folder holding the authors' src/ (fb82/MiHo)")
    parser.add_argument("--ref-runner", default=str(Path(__file__).with_name("ref_miho.py")),
                        help="the runner of the authors' code (default: ref_miho.py beside this script)")
    parser.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    parser.add_argument("--filters", nargs="+", default=list(FILTERS), choices=list(FILTERS))
    parser.add_argument("--pairs", type=int, default=2, help="pairs per kind, evenly spread (default 2)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0 ... S-1 on each side (default 3)")
    parser.add_argument("--max-keypoints", default="8000", help="keypoint budget (default 8000)")
    parser.add_argument("--json", type=Path, help="also write the per-pair numbers here")
    args = parser.parse_args(argv)
    if args.pairs < 1:
        parser.error(f"--pairs must be a positive integer, got {args.pairs}")
    if args.seeds < 1:
        parser.error(f"--seeds must be a positive integer, got {args.seeds}")
    for opt, path in (("--ref-python", args.ref_python), ("--ref-runner", args.ref_runner)):
        if not Path(path).is_file():
            parser.error(f"{opt}: {path} is not a file")
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to compare", file=sys.stderr)
        return 2
    from ctxmatch_lib.filters import mop

    seeds = np.arange(args.seeds)
    print("command: " + " ".join([Path(sys.argv[0]).name] + (sys.argv[1:] if argv is None else list(argv))))
    print(f"features {FEATURES} (max {args.max_keypoints} keypoints), blob {BLOB}; check_reflection on; seeds "
          f"0..{args.seeds - 1}; Jaccard: mean [min,max]; CPU: process time per call, one thread")
    data = {kind: list(canonical_candidates(KINDS[kind], FEATURES, BLOB, args.pairs, args.max_keypoints))
            for kind in args.kinds}
    flat = [(kind, d) for kind in args.kinds for d in data[kind]]
    cases = [dict(pt1=f1.kpts[m[:, 0], :2].astype(np.float32), pt2=f2.kpts[m[:, 1], :2].astype(np.float32),
                  seeds=seeds) for _, (_, f1, f2, m, _, _) in flat]
    ref = {name: run_reference(args.ref_python, args.ref_runner, args.ref_miho, FILTERS[name][1], cases)
           for name in args.filters}
    ours_fn = {name: getattr(mop, FILTERS[name][0]) for name in args.filters}
    if flat:  # one untimed call of each of ours first, as the runner does
        _, (pair, f1, f2, m, s, _) = flat[0]
        for func in ours_fn.values():
            run_ours(func, pair, f1, f2, m, s, seeds[:1])

    head = (f"{'pair':<30} {'filter':<8} {'K':>5} {'kept o/t':>11} {'J ours-theirs':>19} {'J ours-ours':>19} "
            f"{'J theirs-theirs':>19} {'ours P / R':>13} {'theirs P / R':>13} {'ours s':>7} {'theirs s':>8}")
    print(head)
    rows = []
    for i, (kind, (pair, f1, f2, m, s, lab)) in enumerate(flat):
        for name in args.filters:
            o = run_ours(ours_fn[name], pair, f1, f2, m, s, seeds)
            t = ref[name][i]
            ko, kt = list(o["labels"] > -1), list(t["labels"] > -1)
            po, ro = np.mean([precision_recall(m, lab, k) for k in ko], axis=0)
            pt, rt = np.mean([precision_recall(m, lab, k) for k in kt], axis=0)
            row = dict(kind=kind, pair=pair.pair_id, filter=name, K=int(len(m)), correct=int(lab.sum()),
                       kept_ours=float(np.mean([k.sum() for k in ko])),
                       kept_theirs=float(np.mean([k.sum() for k in kt])),
                       j_cross=cross_jaccard(ko, kt), j_ours=within_jaccard(ko), j_theirs=within_jaccard(kt),
                       p_ours=float(po), r_ours=float(ro), p_theirs=float(pt), r_theirs=float(rt),
                       cpu_ours=float(np.mean(o["cpu"])), cpu_theirs=float(np.mean(t["cpu"])))
            rows.append(row)
            print(f"{pair.pair_id:<30.30} {LABELS[name]:<8} {len(m):>5} "
                  f"{row['kept_ours']:>5.0f}/{row['kept_theirs']:<5.0f} {fmt_range(row['j_cross'])} "
                  f"{fmt_range(row['j_ours'])} {fmt_range(row['j_theirs'])} {po:>6.1f} / {ro:<5.1f} "
                  f"{pt:>6.1f} / {rt:<5.1f} {row['cpu_ours']:>7.2f} {row['cpu_theirs']:>8.2f}", flush=True)

    print()
    print(f"{'kind':<8} {'filter':<8} {'pairs':>5} {'K':>6} {'ours P / R':>13} {'theirs P / R':>13} {'J o-t':>6} "
          f"{'J o-o':>6} {'J t-t':>6} {'ours s':>7} {'theirs s':>8} {'ours/theirs':>11}")
    for kind in args.kinds:
        for name in args.filters:
            per = [r for r in rows if r["kind"] == kind and r["filter"] == name]
            if not per:
                continue

            def mean(key):
                return float(np.nanmean([r[key] for r in per]))

            def jmean(key):
                vals = [np.mean(r[key]) for r in per if r[key]]
                return f"{np.mean(vals):>6.3f}" if vals else f"{'-':>6}"

            to, tt = sum(r["cpu_ours"] for r in per), sum(r["cpu_theirs"] for r in per)
            ratio = to / tt if tt > 0 else float("inf")
            print(f"{kind:<8} {LABELS[name]:<8} {len(per):>5} {mean('K'):>6.0f} {mean('p_ours'):>6.1f} / "
                  f"{mean('r_ours'):<5.1f} {mean('p_theirs'):>6.1f} / {mean('r_theirs'):<5.1f} {jmean('j_cross')} "
                  f"{jmean('j_ours')} {jmean('j_theirs')} {to:>7.2f} {tt:>8.2f} {ratio:>10.2f}x", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
