"""Peer filters side by side with their authors' reference implementations on real candidates (issue 22).

For every ``--ref NAME=SPEC`` the filter ``NAME`` of :data:`ctxmatch_lib.filters.FILTERS` and its reference run
on the SAME blob candidates of the shared real pairs (``CTXMATCH_DATA``; datasets ``planar`` and ``nonplanar``,
``--pairs N`` pairs evenly spread over each by :func:`ctxmatch_lib.evaluation.select_pairs`). Configurations
(``--configs``): ``baseline`` = SIFT + RootSIFT features with the ``baseline`` blob preset, ``best`` = HarrisZ +
SOSNet (stand-in) with ``paper-best-overlap``, both at ``--max-keypoints paper`` (1500). Labels are the library's
ground truth (method D, :func:`~ctxmatch_lib.evaluation.steps.label_candidates`).

References (each runs in its own process, with its own interpreter, through a small driver written to a temp
dir; inputs and outputs travel as ``.npz``; the reference is never imported here and never a dependency):

- ``gms=PYTHON``: ``cv2.xfeatures2d.matchGMS`` of opencv-contrib-python(-headless), which conflicts with the
  project's opencv-python-headless, so ``PYTHON`` is the interpreter of a scratch environment, e.g.
  ``python3.11 -m venv /tmp/refenv && /tmp/refenv/bin/pip install opencv-contrib-python-headless numpy``.
  Every candidate row is one ``DMatch`` (its ``distance`` carries the row index so that repeated rows stay
  apart); ``withRotation`` / ``withScale`` are off and ``thresholdFactor`` is 6, the defaults of matchGMS and
  the call of the authors' Python ``GmsMatcher.compute_matches``.
- ``adalam=kornia`` (or ``adalam=PYTHON``, an interpreter with torch and kornia; ``kornia`` is this one):
  ``kornia.feature.adalam.AdalamFilter.filter_matches`` with its default configuration. Its input is one
  putative match per image-1 keypoint, so every candidate row becomes its own image-1 point (the keypoint of
  the row), matched to its image-2 keypoint; the scores are passed squared (kornia's ratio scores are ratios of
  squared distances: its seed threshold is ``0.8 ** 2``); no mutual-nearest-neighbour mask (blob candidates are
  not plain nearest neighbours); orientations (degrees) and scales from the keypoint shapes ``A``: the angle of
  the closest rotation to ``A`` and ``sqrt(|det A|)``.

Printed per filter, configuration and dataset: the number of pairs and mean candidates, the mean precision /
recall (percent; recall is the library's normalised recall, :func:`ctxmatch_lib.metrics.recall`, against the
pair's correct candidates) of ours and of the reference, the mean Jaccard index of the two keep masks, and the
summed CPU times (process time, one thread, each measured around the filter call only, the fastest of
``--repeat`` calls, after one untimed call on the first pair on both sides) with the ratio ours / reference (< 1: ours faster). The reference's time
excludes building its inputs (OpenCV ``KeyPoint`` / ``DMatch`` lists, torch tensors) from the arrays.

Run::

    OMP_NUM_THREADS=1 CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_filters_ref.py \\
        --ref gms=/tmp/refenv/bin/python --ref adalam=kornia --pairs 6
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

CONFIGS = {"baseline": ("sift-rootsift", "baseline"), "best": ("harrisz-sosnet", "paper-best-overlap")}
DATASETS = ("planar", "nonplanar")

# One driver for every reference: argv = kind, input folder, output folder. Each input ``case-*.npz`` holds
# kpts1, kpts2 (N, 2) (x, y) pixels (pixel-centre origin, OpenCV's and kornia's convention too), matches (K, 2),
# scores (K,), size1, size2 (width, height), shapes1, shapes2 (N, 2, 2); each output holds keep (K,) bool and
# cpu, the process time of the reference call alone.
_DRIVER = r'''
import sys, time
from pathlib import Path
import numpy as np

kind, src, dst, repeat = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])


def gms(d):
    import cv2
    k1 = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in d["kpts1"]]
    k2 = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in d["kpts2"]]
    # The row index rides in ``distance`` so that repeated rows remain distinct in the output.
    dm = [cv2.DMatch(int(i), int(j), float(r)) for r, (i, j) in enumerate(d["matches"])]
    size1, size2 = tuple(int(v) for v in d["size1"]), tuple(int(v) for v in d["size2"])
    c0 = time.process_time()
    out = cv2.xfeatures2d.matchGMS(size1, size2, k1, k2, dm, withRotation=bool(d.get("withRotation", False)),
                                   withScale=bool(d.get("withScale", False)),
                                   thresholdFactor=float(d.get("thresholdFactor", 6.0)))
    cpu = time.process_time() - c0
    keep = np.zeros(len(dm), bool)
    keep[[int(m.distance) for m in out]] = True
    return keep, cpu


def adalam(d):
    import torch
    from kornia.feature.adalam import AdalamFilter, get_adalam_default_config
    torch.set_num_threads(1)
    m = d["matches"]
    if len(m) == 0:
        return np.zeros(0, bool), 0.0

    def orient_scale(A):
        # Closest rotation to A (polar decomposition) and the scale of its area.
        ang = np.degrees(np.arctan2(A[:, 1, 0] - A[:, 0, 1], A[:, 0, 0] + A[:, 1, 1]))
        sc = np.sqrt(np.abs(A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]))
        return torch.from_numpy(ang.astype(np.float32)), torch.from_numpy(sc.astype(np.float32))

    o1, s1 = orient_scale(d["shapes1"][m[:, 0]])
    o2, s2 = orient_scale(d["shapes2"])
    k1 = torch.from_numpy(d["kpts1"][m[:, 0]].astype(np.float32))
    k2 = torch.from_numpy(d["kpts2"].astype(np.float32))
    fnn = torch.from_numpy(m[:, 1].astype(np.int64))
    sc = torch.from_numpy((d["scores"] ** 2).astype(np.float32))
    size1, size2 = [int(v) for v in d["size1"]], [int(v) for v in d["size2"]]
    config = get_adalam_default_config()
    for key in [k for k in d if k.startswith("config_")]:
        value = d[key][()]
        config[key[len("config_"):]] = None if isinstance(value, float) and np.isnan(value) else value.item()
    filt = AdalamFilter(config)
    c0 = time.process_time()
    out = filt.filter_matches(k1, k2, fnn, sc, mnn=None, im1shape=size1, im2shape=size2, o1=o1, o2=o2,
                              s1=s1, s2=s2)
    cpu = time.process_time() - c0
    keep = np.zeros(len(m), bool)
    keep[out[:, 0].numpy()] = True
    return keep, cpu


run = {"gms": gms, "adalam": adalam}[kind]
files = sorted(src.glob("case-*.npz"))
if files:  # one untimed call first: imports and first-call set-up are not the filter's time
    run(dict(np.load(files[0])))
for f in files:
    d = dict(np.load(f))
    keep, cpu = run(d)
    for _ in range(repeat - 1):  # the fastest of ``repeat`` calls
        cpu = min(cpu, run(d)[1])
    np.savez(dst / f.name, keep=keep, cpu=cpu)
'''

REFERENCES = ("gms", "adalam")

#: Our keyword -> the reference's option, for the ``--param`` settings that exist on both sides (given to both).
SHARED_OPTIONS = {
    "gms": {"with_scale": "withScale", "with_rotation": "withRotation", "alpha": "thresholdFactor"},
    "adalam": {k: "config_" + v for k, v in {
        "area_ratio": "area_ratio", "search_expansion": "search_expansion", "ransac_iters": "ransac_iters",
        "min_inliers": "min_inliers", "min_confidence": "min_confidence",
        "orientation_threshold": "orientation_difference_threshold", "scale_rate_threshold": "scale_rate_threshold",
        "detected_scale_rate_threshold": "detected_scale_rate_threshold", "refit": "refit"}.items()},
}


def reference_options(name: str, params: dict) -> dict:
    """The driver's option arrays for our ``params`` that the reference of ``name`` shares (None -> NaN)."""
    table = SHARED_OPTIONS.get(name, {})
    return {table[k]: np.asarray(np.nan if v is None else v) for k, v in params.items() if k in table}


def parse_ref(text: str) -> tuple[str, str]:
    """``NAME=SPEC`` -> ``(name, python)``: SPEC is an interpreter path, or ``kornia`` (this interpreter) for
    ``adalam``."""
    name, sep, spec = text.partition("=")
    if not sep or not spec:
        raise ValueError(f"--ref must be NAME=SPEC, got {text!r}")
    if name not in REFERENCES:
        raise ValueError(f"--ref: no reference runner for filter {name!r}; known: {', '.join(REFERENCES)}")
    if spec == "kornia":
        if name != "adalam":
            raise ValueError(f"--ref {text!r}: 'kornia' is the reference of adalam only")
        return name, sys.executable
    if not Path(spec).is_file():
        raise ValueError(f"--ref {text!r}: {spec} is not an interpreter")
    return name, spec


def run_reference(kind: str, python: str, cases: list[dict], repeat: int = 1) -> list[tuple[np.ndarray, float]]:
    """Run reference ``kind`` in ``python`` on every case (dicts of the driver's input arrays); one process.

    Returns one ``(keep, cpu_seconds)`` per case, in order; the time is the fastest of ``repeat`` calls.
    """
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in", Path(tmp) / "out"
        src.mkdir()
        dst.mkdir()
        for i, case in enumerate(cases):
            np.savez(src / f"case-{i:05d}.npz", **case)
        driver = Path(tmp) / "driver.py"
        driver.write_text(_DRIVER)
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        subprocess.run([python, str(driver), kind, str(src), str(dst), str(int(repeat))], check=True, env=env)
        out = []
        for i in range(len(cases)):
            d = np.load(dst / f"case-{i:05d}.npz")
            out.append((d["keep"].astype(bool), float(d["cpu"])))
    return out


def make_case(f1, f2, matches, scores, size1, size2) -> dict:
    """The driver's input arrays for one candidate set."""
    return dict(kpts1=np.asarray(f1.kpts[:, :2], np.float64), kpts2=np.asarray(f2.kpts[:, :2], np.float64),
                matches=np.asarray(matches, np.int64), scores=np.asarray(scores, np.float64),
                size1=np.asarray(size1, np.int64), size2=np.asarray(size2, np.int64),
                shapes1=np.asarray(f1.shapes, np.float64), shapes2=np.asarray(f2.shapes, np.float64))


def jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """|a & b| / |a | b| of two masks; 1 when both are empty."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def precision_recall(matches: np.ndarray, labels: np.ndarray, keep: np.ndarray) -> tuple[float, float]:
    """Precision and the library's normalised recall (against the correct candidates), in percent."""
    from ctxmatch_lib.metrics import precision, recall

    p = precision(labels[keep])
    r = recall(matches[keep], labels[keep], matches[labels])
    return 100 * p, 100 * r


def _inputs(dataset: str, config: str, n_pairs: int, max_keypoints):
    from ctxmatch_lib.blob import BLOB_PRESETS
    from ctxmatch_lib.evaluation import select_pairs
    from ctxmatch_lib.evaluation.steps import blob_candidates, label_candidates, pair_features
    from ctxmatch_lib.features import FEATURE_PRESETS, keypoint_budget

    feat, blob = CONFIGS[config]
    fcfg = FEATURE_PRESETS[feat]
    budget = keypoint_budget(max_keypoints)
    if budget is not None:
        fcfg = replace(fcfg, max_keypoints=budget)
    for pair in select_pairs(dataset, select=n_pairs):
        f1, f2 = pair_features(pair, fcfg)
        matches, scores, _ = blob_candidates(f1, f2, BLOB_PRESETS[blob])
        labels = label_candidates(pair, f1, f2, matches)
        yield pair, f1, f2, matches, scores, labels


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ref", action="append", required=True, metavar="NAME=SPEC",
                        help="filter and its reference: gms=PYTHON (opencv-contrib env), adalam=kornia|PYTHON")
    parser.add_argument("--configs", nargs="+", default=["baseline"], choices=list(CONFIGS))
    parser.add_argument("--datasets", nargs="+", default=list(DATASETS))
    parser.add_argument("--pairs", type=int, default=6, help="pairs per dataset, evenly spread (default 6)")
    parser.add_argument("--max-keypoints", default="paper", help="keypoint budget (default 'paper': 1500)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME:KEY=JSON",
                        help="extra keyword of our filter, e.g. gms:with_scale=true (repeatable); the reference "
                             "gets it too where it has the same option (SHARED_OPTIONS)")
    parser.add_argument("--repeat", type=int, default=3, help="time the fastest of this many calls (default 3)")
    parser.add_argument("--json", type=Path, help="also write the per-pair numbers here")
    args = parser.parse_args(argv)
    try:
        refs = dict(parse_ref(r) for r in args.ref)
    except ValueError as exc:
        parser.error(str(exc))
    if args.pairs < 1:
        parser.error(f"--pairs must be a positive integer, got {args.pairs}")
    if args.repeat < 1:
        parser.error(f"--repeat must be a positive integer, got {args.repeat}")
    params: dict[str, dict] = {name: {} for name in refs}
    for p in args.param:
        name, _, kv = p.partition(":")
        key, sep, val = kv.partition("=")
        if name not in refs or not sep:
            parser.error(f"--param must be NAME:KEY=JSON with NAME among the --ref filters, got {p!r}")
        params[name][key] = json.loads(val)
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to compare", file=sys.stderr)
        return 2
    from ctxmatch_lib.evaluation.steps import run_filter

    print("command: " + " ".join([Path(sys.argv[0]).name] + (sys.argv[1:] if argv is None else list(argv))))
    print(f"{'filter':<7} {'config':<9} {'dataset':<10} {'pairs':>5} {'cands':>6} {'ours P / R':>13} "
          f"{'ref P / R':>13} {'Jaccard':>7} {'ours ms':>8} {'ref ms':>8} {'ours/ref':>8}")
    rows = []
    for config in args.configs:
        for dataset in args.datasets:
            data = list(_inputs(dataset, config, args.pairs, args.max_keypoints))
            for name, python in refs.items():
                opts = reference_options(name, params[name])
                cases = [dict(make_case(f1, f2, m, s, p.image_size1, p.image_size2), **opts)
                         for p, f1, f2, m, s, _ in data]
                ref_out = run_reference(name, python, cases, args.repeat)
                per = []
                if data:  # one untimed call first (numba kernels load or compile on the first call)
                    pair, f1, f2, m, s, _ = data[0]
                    run_filter(name, f1, f2, m, s, image_size1=pair.image_size1, image_size2=pair.image_size2,
                               **params[name])
                for (pair, f1, f2, m, s, lab), (rkeep, rcpu) in zip(data, ref_out):
                    cpu = np.inf
                    for _ in range(args.repeat):  # the fastest of ``repeat`` calls, as for the reference
                        c0 = time.process_time()
                        keep, _ = run_filter(name, f1, f2, m, s, image_size1=pair.image_size1,
                                             image_size2=pair.image_size2, **params[name])
                        cpu = min(cpu, time.process_time() - c0)
                    per.append(dict(pair=pair.pair_id, K=int(len(m)), ours=precision_recall(m, lab, keep),
                                    ref=precision_recall(m, lab, rkeep), jaccard=jaccard(keep, rkeep),
                                    kept_ours=int(keep.sum()), kept_ref=int(rkeep.sum()), t_ours=cpu, t_ref=rcpu))
                po, ro = np.nanmean([x["ours"] for x in per], axis=0)
                pr, rr = np.nanmean([x["ref"] for x in per], axis=0)
                jac = np.mean([x["jaccard"] for x in per])
                to, tr = sum(x["t_ours"] for x in per), sum(x["t_ref"] for x in per)
                ratio = to / tr if tr > 0 else float("inf")
                print(f"{name:<7} {config:<9} {dataset:<10} {len(per):>5} {np.mean([x['K'] for x in per]):>6.0f} "
                      f"{po:>6.1f} / {ro:<5.1f} {pr:>6.1f} / {rr:<5.1f} {jac:>7.3f} {1e3 * to:>8.1f} {1e3 * tr:>8.1f} "
                      f"{ratio:>7.2f}x", flush=True)
                rows.extend(dict(filter=name, config=config, dataset=dataset, **x) for x in per)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
