"""DTM side by side with its author's public Python port on the real pairs.

For every pair of the real datasets under ``CTXMATCH_DATA`` (planar: HPatches, Oxford, homogr; non-planar:
kusvod2) and each blob preset (``baseline``, ``paper-best``), the blob candidates are computed once (SIFT +
RootSIFT, ground-truth labels by method D) and filtered by :func:`ctxmatch_lib.dtm.dtm` with the paper's
alpha-shape boundary and with ``boundary="keypoints"`` (the port's construction). With ``--port PATH`` the
same candidates also go through the port (github fb82/DTM, ``src/dtm.py``, GPL-3), run in its own process
with its own interpreter (``--port-python``, an environment with numpy, scipy, pillow, matplotlib,
opencv-python-headless, torch and kornia, which the port imports); the port is never imported here, never a dependency, and never run in CI.

Printed per dataset group and preset: mean precision / recall of the DTM2 outputs (over pairs, in percent,
against the correct candidates of the pair) and of our DTM1 outputs, the matches our DTM2 re-added (and how
many of them are wrong), the mean Jaccard index of our keep mask with the port's, the
summed CPU times (process time, one thread, so that a loaded machine does not skew the ratio) with
their ratio, the matches only the port keeps that lie farther than ``s`` from our DTM1 survivors
(beyond the reach of an alpha boundary; how many of them are wrong), and both precision / recall
without every match that far. Port outputs are cached in ``--work`` (keyed by the candidates), so a
second run only times ours.

Run::

    CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_dtm_real.py \
        --port /path/to/DTM --port-python /path/to/env/bin/python
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ctxmatch_lib import BLOB_PRESETS
from ctxmatch_lib.datasets import load_dataset
from ctxmatch_lib.dtm import dtm
from ctxmatch_lib.dtm.boundary import boundary_step
from ctxmatch_lib.evaluation.steps import blob_candidates, label_candidates, pair_features

GROUPS = {"planar": ("hpatches", "oxford", "homogr"), "kusvod2": ("kusvod2",)}
PRESETS = ("paper-best", "baseline")

# Runs the port on one dumped input (argv: port folder, input npz, output npz). The port's entry point is
# dtm.dtm(pipe_data, prepare_data=...) with pipe_data holding the image paths (for the sizes), all keypoints
# of both images, the candidate indices, their scores and a candidate mask; its output labels each candidate
# with <= 0 for kept (0: survived DTM1, -i: re-added by DTM2 at level i) and i > 0 for removed at iteration i.
_PORT_DRIVER = r"""
import sys, time
import numpy as np
import torch
sys.path.insert(0, sys.argv[1] + "/src")
import dtm as port
d = np.load(sys.argv[2])
pipe = {"img": [str(d["image1"]), str(d["image2"])],
        "kp": [torch.from_numpy(d["kpts1"]), torch.from_numpy(d["kpts2"])],
        "m_idx": torch.from_numpy(d["matches"]), "m_val": torch.from_numpy(d["scores"]),
        "m_mask": torch.ones(len(d["matches"]), dtype=torch.bool)}
t0, c0 = time.perf_counter(), time.process_time()
label = port.dtm(pipe, prepare_data=port.prepare_data_shaped)
t, c = time.perf_counter() - t0, time.process_time() - c0
keep = np.zeros(len(d["matches"]), bool) if label is None else np.asarray(label) <= 0
np.savez(sys.argv[3], keep=keep, wall=t, cpu=c)
"""


def _inputs(group: str, preset: str, limit: int | None):
    """Yield ``(pair, f1, f2, matches, scores, labels)`` for every pair of ``group``."""
    config = BLOB_PRESETS[preset]
    for name in GROUPS[group]:
        for pair in load_dataset(name).pairs[:limit]:
            f1, f2 = pair_features(pair)
            matches, scores, _ = blob_candidates(f1, f2, config)
            labels = label_candidates(pair, f1, f2, matches)
            yield pair, f1, f2, matches, scores, labels


def _run_port(port: Path, python: str, work: Path, pair, f1, f2, matches, scores) -> tuple[np.ndarray, float]:
    digest = hashlib.sha1()
    for a in (f1.kpts, f2.kpts, matches, scores):
        digest.update(np.ascontiguousarray(a).tobytes())
    out = work / f"port-{digest.hexdigest()[:20]}.npz"
    if not out.exists() or "cpu" not in np.load(out).files:
        with tempfile.TemporaryDirectory() as tmp:
            inp = Path(tmp) / "in.npz"
            np.savez(inp, image1=str(pair.image1), image2=str(pair.image2),
                     kpts1=np.asarray(f1.kpts[:, :2], np.float32), kpts2=np.asarray(f2.kpts[:, :2], np.float32),
                     matches=matches.astype(np.int64), scores=scores.astype(np.float32))
            driver = Path(tmp) / "driver.py"
            driver.write_text(_PORT_DRIVER)
            env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
                       MKL_NUM_THREADS="1")
            subprocess.run([python, str(driver), str(port), str(inp), str(out)], check=True, env=env)
    d = np.load(out)
    return d["keep"], float(d["cpu"])


def _pr(keep: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    precision = labels[keep].mean() if keep.any() else 0.0
    recall = keep[labels].mean() if labels.any() else 0.0
    return 100 * precision, 100 * recall


def _far_from(xy: np.ndarray, survivors: np.ndarray, s: float) -> np.ndarray:
    """Whether each candidate's image-1 keypoint lies farther than ``s`` from every DTM1 survivor's: beyond
    the alpha boundary drawn at distance ``s`` around them, where DTM2 cannot re-add it."""
    if not survivors.any():
        return np.ones(len(xy), bool)
    return cKDTree(xy[survivors]).query(xy)[0] > s


def _jaccard(a: np.ndarray, b: np.ndarray) -> float:
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=Path, help="checkout of github fb82/DTM (holds src/dtm.py)")
    parser.add_argument("--port-python", default=sys.executable, help="interpreter of the port's environment")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "ctxmatch-dtm-port",
                        help="cache of the port's outputs")
    parser.add_argument("--groups", nargs="+", default=list(GROUPS), choices=list(GROUPS))
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), choices=list(BLOB_PRESETS))
    parser.add_argument("--limit", type=int, default=None, help="at most this many pairs per dataset")
    parser.add_argument("--boundaries", nargs="+", default=["alpha", "keypoints"],
                        help="boundary methods of ours, optionally with the DTM2 boundary: alpha/stored")
    parser.add_argument("--json", type=Path, help="also write the per-pair numbers here")
    args = parser.parse_args(argv)
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to compare", file=sys.stderr)
        return 2
    if args.port is not None and not (args.port / "src" / "dtm.py").is_file():
        parser.error(f"--port {args.port} holds no src/dtm.py")
    args.work.mkdir(parents=True, exist_ok=True)

    rows = []
    header = (f"{'preset':<11} {'data':<8} {'pairs':>5} {'boundary':<10} {'ours P / R':>13} {'DTM1 P / R':>13} "
              f"{'re-added (wrong)':>16} ")
    if args.port:
        header += (f"{'port P / R':>13} {'Jaccard':>7} {'ours s':>7} {'port s':>7} {'speed-up':>8} "
                   f"{'port-only >s (wrong)':>20} {'<=s: ours P / R':>15} {'port P / R':>13}")
    print(header)
    for preset in args.presets:
        for group in args.groups:
            per = []
            for pair, f1, f2, matches, scores, labels in _inputs(group, preset, args.limit):
                rec = {"pair": pair.pair_id, "K": int(len(matches))}
                sizes = dict(image_size1=pair.image_size1, image_size2=pair.image_size2)
                for b in args.boundaries:
                    method, _, dtm2 = b.partition("/")
                    t0 = time.process_time()
                    extra = {"dtm2_boundary": dtm2} if dtm2 else {}
                    res = dtm(f1.kpts, f2.kpts, matches, scores, boundary=method, **extra, **sizes)
                    elapsed = time.process_time() - t0
                    added = res.readded_at > 0
                    rec[b] = dict(keep=res.keep, time=elapsed, pr=_pr(res.keep, labels),
                                  pr1=_pr(res.removed_at == 0, labels), added=int(added.sum()),
                                  added_wrong=int((added & ~labels).sum()), survivors=res.removed_at == 0)
                if args.port:
                    keep, t = _run_port(args.port, args.port_python, args.work, pair, f1, f2, matches, scores)
                    rec["port"] = dict(keep=keep, time=t, pr=_pr(keep, labels))
                    for b in args.boundaries:
                        rec[b]["far"] = _far_from(f1.kpts[matches[:, 0], :2], rec[b]["survivors"],
                                                  boundary_step(pair.image_size1))
                        only = keep & ~rec[b]["keep"] & rec[b]["far"]
                        rec[b]["port_far"] = (int(only.sum()), int((only & ~labels).sum()))
                        rec[b]["port_near_pr"] = _pr(keep & ~rec[b]["far"], labels)
                        rec[b]["near_pr"] = _pr(rec[b]["keep"] & ~rec[b]["far"], labels)
                per.append(rec)
            for b in args.boundaries:
                p, r = np.mean([x[b]["pr"] for x in per], axis=0)
                p1, r1 = np.mean([x[b]["pr1"] for x in per], axis=0)
                added = f"{sum(x[b]['added'] for x in per)} ({sum(x[b]['added_wrong'] for x in per)})"
                line = (f"{preset:<11} {group:<8} {len(per):>5} {b:<10} {p:>6.1f} / {r:<5.1f} {p1:>6.1f} / {r1:<5.1f} "
                        f"{added:>16}")
                if args.port:
                    pp, pr_ = np.mean([x["port"]["pr"] for x in per], axis=0)
                    jac = np.mean([_jaccard(x[b]["keep"], x["port"]["keep"]) for x in per])
                    t_ours = sum(x[b]["time"] for x in per)
                    t_port = sum(x["port"]["time"] for x in per)
                    far = f"{sum(x[b]['port_far'][0] for x in per)} ({sum(x[b]['port_far'][1] for x in per)})"
                    pn, rn = np.mean([x[b]["port_near_pr"] for x in per], axis=0)
                    on, orn = np.mean([x[b]["near_pr"] for x in per], axis=0)
                    line += (f" {pp:>6.1f} / {pr_:<5.1f} {jac:>7.3f} {t_ours:>7.1f} {t_port:>7.1f} "
                             f"{t_port / t_ours:>7.1f}x {far:>20} {on:>8.1f} / {orn:<5.1f} {pn:>6.1f} / {rn:<5.1f}")
                print(line, flush=True)
            rows.extend(dict(preset=preset, group=group, **{
                k: (v if not isinstance(v, dict) else {"P": v["pr"][0], "R": v["pr"][1], "time": v["time"],
                                                       **({"port_far": v["port_far"]} if "port_far" in v else {}),
                                                       **({"P1": v["pr1"][0], "R1": v["pr1"][1], "added": v["added"],
                                                           "added_wrong": v["added_wrong"]} if "pr1" in v else {})})
                for k, v in rec.items()}) for rec in per)
    if args.port and rows:
        t_port = sum(x["port"]["time"] for x in rows)
        for b in args.boundaries:
            t_ours = sum(x[b]["time"] for x in rows)
            print(f"summed over all {len(rows)} pair-runs, {b}: ours {t_ours:.1f} s, port {t_port:.1f} s, "
                  f"speed-up {t_port / t_ours:.1f}x (target >= 20x)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print("P / R: mean over pairs of the DTM2 output's precision and recall (percent) against the pair's correct "
          "candidates; DTM1 P / R: the same for the DTM1 output; re-added (wrong): matches DTM2 re-added, summed "
          "over pairs (of them wrong); Jaccard: mean over pairs of |ours ∩ port| / |ours ∪ port|; CPU seconds "
          "summed over pairs; port-only >s (wrong): matches the port keeps and ours does not whose image-1 keypoint "
          "lies farther than s = min(w, h) / 10 from every DTM1 survivor of ours (where an alpha boundary stops "
          "DTM2), summed over pairs (of them wrong); <=s: ours P / R, port P / R: both outputs without the matches that far")
    return 0


if __name__ == "__main__":
    sys.exit(main())
