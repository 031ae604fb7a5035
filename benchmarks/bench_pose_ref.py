"""The pose error and its AUC side by side with SuperGlue's reference code on the same inputs.

SuperGlue's ``estimate_pose``, ``compute_pose_error`` and ``pose_auc`` (``models/utils.py`` of
magicleap/SuperGluePretrainedNetwork) are imported at run time from a checkout outside this repository; their
code is never copied here. Get one with

    git clone https://github.com/magicleap/SuperGluePretrainedNetwork /tmp/superglue

(the file imports torch and matplotlib, both installed with the ``learned`` and ``plots`` extras). Then

    CTXMATCH_DATA=/path python benchmarks/bench_pose_ref.py /tmp/superglue [--pairs-per-scene 4]

Inputs, the same for both sides:

* real calibrated pairs: the Strecha scenes in ``$CTXMATCH_DATA/calibrated/strecha/<scene>`` (openMVG's
  layout, ``images/*.jpg`` and ``gt_dense_cameras/<image>.camera``: K, a distortion line, R camera-to-world, the
  centre C, width and height; parsed minimally here), pairs (i, i + d) for d = 1, 2, 3 in that order, the first
  ``--pairs-per-scene`` of each scene; ground truth ``R = R2^T R1``, ``t = R2^T (C1 - C2)`` (``X2 = R X1 + t``,
  SuperGlue's ``T_0to1``); matches: OpenCV SIFT (``--max-keypoints``) and Lowe's ratio test at 0.8
  (:func:`~ctxmatch_lib.opencv_matchers.opencv_ratio_matches`);
* synthetic pairs: random scenes in front of two cameras with different intrinsics, 0.5 px noise and 30 %
  outliers, and a few with fewer than five matches (every estimator fails there).

Printed, per pair: SuperGlue's ``estimate_pose`` (OpenCV's RANSAC five-point solver at 1 px, its evaluation's
threshold) gives one ``(R, t)``; both SuperGlue's ``compute_pose_error`` and ours
(:func:`~ctxmatch_lib.geometry.relative_pose_error`) measure that same estimate. Then the AUC at 5 / 10 / 20
degrees of the two pose-error lists, each by its own ``pose_auc`` (SuperGlue's failures at ``inf``, ours at 180
degrees). The two sides must agree to rounding. For information only (different estimators, so not expected to
agree): ours end to end, the ``essential`` model step (MAGSAC at 1 px) and the ``magsac`` step's F through
``E = K2^T F K1``, each then :func:`~ctxmatch_lib.geometry.pose_from_model`.

Two notes on running SuperGlue's code today: numpy 2 removed ``np.trapz``, which its ``pose_auc`` calls, so
``np.trapz`` is set to ``np.trapezoid`` (the same trapezoid rule) when missing; and on OpenCV 5 its
``cv2.recoverPose(E, p0, p1, I, 1e9, mask=mask)`` resolves to the overload without ``distanceThresh``, so points
beyond 50 baselines do not vote there (ours passes the keyword; the estimates measured here are SuperGlue's own
in either case).

On the shared data (4 pairs of each of the three Strecha scenes at 8000 keypoints, 20 synthetic pairs; about
1.5 min on 2 cores) the two sides print the same rotation and translation errors and the same AUC to the last
digit: 68.6200 / 79.3903 / 86.6357 % at 5 / 10 / 20 degrees.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np

from ctxmatch_lib.geometry import apply_model_step, pose_from_model, relative_pose_error
from ctxmatch_lib.geometry_metrics import pose_auc
from ctxmatch_lib.opencv_matchers import opencv_ratio_matches

THRESHOLDS_DEG = [5, 10, 20]


def load_superglue(checkout: Path):
    """``estimate_pose``, ``compute_pose_error``, ``pose_auc`` of ``checkout/models/utils.py``."""
    path = Path(checkout) / "models" / "utils.py"
    if not path.is_file():
        sys.exit(f"{path} not found: clone magicleap/SuperGluePretrainedNetwork there (see this script's docstring)")
    os.environ.setdefault("MPLBACKEND", "Agg")
    if not hasattr(np, "trapz"):
        np.trapz = np.trapezoid  # numpy 2 removed the alias; the same trapezoid rule
    spec = importlib.util.spec_from_file_location("superglue_utils", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.estimate_pose, mod.compute_pose_error, mod.pose_auc


def read_camera(path: Path):
    """K, R (camera to world) and the centre C of a Strecha ``.camera`` file (openMVG's layout)."""
    v = np.array(path.read_text().split(), dtype=np.float64)
    if len(v) != 26:
        raise ValueError(f"{path}: expected 26 numbers (K, distortion, R, C, width height), got {len(v)}")
    return v[:9].reshape(3, 3), v[12:21].reshape(3, 3), v[21:24]


def strecha_pairs(root: Path, per_scene: int):
    """(name, path1, path2, K1, K2, R, t) of the first ``per_scene`` pairs (i, i + d), d = 1, 2, 3, of each scene."""
    out = []
    for scene in sorted(p for p in root.iterdir() if (p / "images").is_dir()):
        images = sorted((scene / "images").glob("*.jpg"))
        cand = [(i, i + d) for d in (1, 2, 3) for i in range(len(images) - d)]
        for i, j in cand[:per_scene]:
            K1, R1, C1 = read_camera(scene / "gt_dense_cameras" / f"{images[i].name}.camera")
            K2, R2, C2 = read_camera(scene / "gt_dense_cameras" / f"{images[j].name}.camera")
            out.append((f"{scene.name} {images[i].stem}-{images[j].stem}", images[i], images[j], K1, K2,
                        R2.T @ R1, R2.T @ (C1 - C2)))
    return out


def sift_ratio_points(path1: Path, path2: Path, max_keypoints: int, cache: dict):
    """Matched (x, y) pixels of OpenCV SIFT + the ratio test (origin at the centre of the top-left pixel)."""
    import cv2

    feats = []
    for p in (path1, path2):
        if p not in cache:
            img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
            kp, desc = cv2.SIFT_create(nfeatures=max_keypoints).detectAndCompute(img, None)
            cache[p] = (np.array([k.pt for k in kp], np.float64).reshape(-1, 2), desc)
        feats.append(cache[p])
    m, _ = opencv_ratio_matches(feats[0][1], feats[1][1])
    return feats[0][0][m[:, 0]], feats[1][0][m[:, 1]]


def synthetic_pairs(n_pairs: int, seed: int = 0):
    """(name, pts1, pts2, K1, K2, R, t): random scenes, 0.5 px noise, 30 % outliers; the last two with 4 matches."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n_pairs):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        A = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        th = np.radians(rng.uniform(2, 30))
        R = np.eye(3) + np.sin(th) * A + (1 - np.cos(th)) * A @ A
        t = rng.normal(size=3)
        t *= rng.uniform(0.3, 2.0) / np.linalg.norm(t)
        K1 = np.array([[rng.uniform(500, 1200), 0, 320], [0, 0, 240], [0, 0, 1.0]])
        K1[1, 1] = K1[0, 0] * rng.uniform(0.98, 1.02)
        K2 = K1 * [[rng.uniform(0.8, 1.2)], [rng.uniform(0.8, 1.2)], [1.0]]
        n = 4 if k >= n_pairs - 2 else int(rng.integers(50, 400))
        X1 = rng.uniform([-3, -2, 5], [3, 2, 15], (n, 3))
        X2 = X1 @ R.T + t
        p1 = X1 @ K1.T
        p2 = X2 @ K2.T
        p1 = p1[:, :2] / p1[:, 2:] + rng.normal(0, 0.5, (n, 2))
        p2 = p2[:, :2] / p2[:, 2:] + rng.normal(0, 0.5, (n, 2))
        bad = rng.random(n) < 0.3
        p2[bad] = rng.uniform([0, 0], [640, 480], (int(bad.sum()), 2))
        out.append((f"synthetic {k:02d}", p1, p2, K1, K2, R, t))
    return out


def ours_end_to_end(p1, p2, K1, K2, R_gt, t_gt, seed):
    """Pose errors of ours end to end: the essential step, and the magsac step's F via E = K2^T F K1."""
    m = np.c_[np.arange(len(p1)), np.arange(len(p1))]
    out = []
    for step, extra in (("essential", {"K1": K1, "K2": K2}), ("magsac", {})):
        fit = apply_model_step(step, p1, p2, m, kind="F", rng=seed, **extra)
        inl = fit.sample
        pose = pose_from_model(fit.model, fit.kind, p1[inl], p2[inl], K1, K2) if fit.model is not None else None
        out.append(max(relative_pose_error(*(pose or (None, None)), R_gt, t_gt)))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("superglue", type=Path, help="checkout of magicleap/SuperGluePretrainedNetwork")
    parser.add_argument("--pairs-per-scene", type=int, default=4)
    parser.add_argument("--max-keypoints", type=int, default=8000)
    parser.add_argument("--synthetic", type=int, default=20, help="synthetic pairs (the last two have 4 matches)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    import cv2

    sg_estimate, sg_error, sg_auc = load_superglue(args.superglue)

    cases = []
    data = os.environ.get("CTXMATCH_DATA")
    root = Path(data) / "calibrated" / "strecha" if data else None
    if root is not None and root.is_dir():
        cache: dict = {}
        for name, i1, i2, K1, K2, R, t in strecha_pairs(root, args.pairs_per_scene):
            p1, p2 = sift_ratio_points(i1, i2, args.max_keypoints, cache)
            cases.append((name, p1, p2, K1, K2, R, t))
    else:
        print("CTXMATCH_DATA/calibrated/strecha not found: synthetic pairs only")
    cases += synthetic_pairs(args.synthetic, args.seed)

    rows = []
    print(f"{'pair':<28}{'matches':>8} | {'SuperGlue err_R':>15}{'ours err_R':>12} | {'SuperGlue err_t':>15}"
          f"{'ours err_t':>12} | ours end to end: E, F")
    for name, p1, p2, K1, K2, R, t in cases:
        cv2.setRNGSeed(args.seed)  # estimate_pose's cv2.RANSAC draws from OpenCV's global generator
        ret = sg_estimate(p1, p2, K1, K2, 1.0)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        if ret is None:
            sg_t, sg_R = np.inf, np.inf
            our_R, our_t = relative_pose_error(None, None, R, t)
        else:
            sg_t, sg_R = sg_error(T, ret[0], ret[1])
            our_R, our_t = relative_pose_error(ret[0], ret[1], R, t)
        e2e = ours_end_to_end(p1, p2, K1, K2, R, t, args.seed)
        rows.append((name, sg_R, our_R, sg_t, our_t, *e2e))
        print(f"{name:<28}{len(p1):>8} | {sg_R:>15.6f}{our_R:>12.6f} | {sg_t:>15.6f}{our_t:>12.6f} | "
              f"{e2e[0]:.2f}, {e2e[1]:.2f}")

    a = np.array([r[1:] for r in rows], dtype=np.float64)
    sg_R, our_R, sg_t, our_t, e2e_E, e2e_F = a.T
    ok = np.isfinite(sg_R)
    print(f"\n{len(rows)} pairs, {int((~ok).sum())} without a SuperGlue pose (SuperGlue: inf, ours: "
          f"{int((our_R[~ok] == 180).sum())} at 180 degrees)")
    dR, dt = np.abs(sg_R - our_R)[ok].max(initial=0), np.abs(sg_t - our_t)[ok].max(initial=0)
    print(f"largest |SuperGlue - ours| over the estimated poses: rotation {dR:.3g} deg, translation {dt:.3g} deg")
    sg_pose = np.maximum(sg_t, sg_R)
    our_pose = np.maximum(our_R, our_t)
    sg = 100 * np.asarray(sg_auc(sg_pose, THRESHOLDS_DEG))
    ours = 100 * pose_auc(our_pose, THRESHOLDS_DEG)
    print(f"\n{'AUC (%)':<44}" + "".join(f"{f'@{t} deg':>10}" for t in THRESHOLDS_DEG))
    print(f"{'SuperGlue pose_auc on its errors':<44}" + "".join(f"{v:>10.4f}" for v in sg))
    print(f"{'ours pose_auc on ours (same estimates)':<44}" + "".join(f"{v:>10.4f}" for v in ours))
    print(f"largest |difference|: {np.abs(sg - ours).max():.3g} points of AUC")
    for label, e in (("ours end to end, essential step", e2e_E), ("ours end to end, magsac F -> E", e2e_F)):
        print(f"{label + ' (info)':<44}" + "".join(f"{v:>10.4f}" for v in 100 * pose_auc(e, THRESHOLDS_DEG)))
    agree = np.allclose(sg_R[ok], our_R[ok], atol=1e-5) and np.allclose(sg_t[ok], our_t[ok], atol=1e-5) \
        and np.allclose(sg, ours, atol=1e-9)
    print("\nagree: " + ("yes" if agree else "NO"))
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
