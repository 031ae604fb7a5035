"""The geometry metrics side by side with the functions they follow, on the same inputs.

* AUC over pairs: :func:`ctxmatch_lib.geometry_metrics.pose_auc` against SuperGlue's ``pose_auc``
  (magicleap/SuperGluePretrainedNetwork, ``models/utils.py``) and glue-factory's ``cal_error_auc``
  (cvg/glue-factory, ``gluefactory/utils/tools.py``, which rounds to 4 decimals), on error lists with
  failures (``inf``), ties, errors equal to a threshold and an empty list;
* the mean corner error: :func:`~ctxmatch_lib.geometry_metrics.homography_corner_error` against glue-factory's
  ``homography_corner_error`` (``gluefactory/geometry/homography.py``, torch) on random homographies written in
  its corner-origin convention;
* the symmetric epipolar distance: :func:`~ctxmatch_lib.geometry_metrics.symmetric_epipolar_distance` against
  kornia's ``symmetrical_epipolar_distance(squared=False)``, which the WxBS benchmark thresholds.

The peers' functions are read from the checkouts at run time (their source, by name, with ``ast``) and run
here; nothing of them is copied into the project. Without the checkouts the script says what it skips.

    python benchmarks/bench_geometry_metrics.py --superglue PATH --gluefactory PATH

or ``CTXMATCH_SUPERGLUE_REF`` / ``CTXMATCH_GLUEFACTORY_REF``; each is the root of a checkout (a folder with
``models/utils.py``, resp. ``gluefactory/``). Prints the largest absolute difference per comparison.
"""

from __future__ import annotations

import argparse
import ast
import os
from pathlib import Path

import numpy as np

from ctxmatch_lib.geometry_metrics import homography_corner_error, pose_auc, symmetric_epipolar_distance

THRESHOLDS = [1.0, 3.0, 5.0, 10.0, 20.0]


def peer_functions(path: Path, names: list[str], namespace: dict) -> dict:
    """The functions ``names`` of the Python file ``path``, compiled from their source in ``namespace``."""
    source = path.read_text()
    tree = ast.parse(source)
    found = {node.name: node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name in names}
    missing = sorted(set(names) - set(found))
    if missing:
        raise SystemExit(f"{path}: no function {', '.join(missing)}")
    for name in names:
        exec(compile(ast.Module([found[name]], []), str(path), "exec"), namespace)
    return {name: namespace[name] for name in names}


def error_lists() -> dict:
    rng = np.random.default_rng(0)
    return {
        "random 200": rng.exponential(4.0, 200),
        "random 200 + 60 failures": np.r_[rng.exponential(4.0, 200), np.full(60, np.inf)],
        "ties and errors at thresholds": np.array([0.0, 0.0, 1.0, 1.0, 3.0, 2.5, 5.0, 10.0, 10.0, np.inf]),
        "all failures": np.full(7, np.inf),
        "one pair": np.array([2.0]),
        "31 pairs, 4 failures": np.r_[rng.gamma(1.5, 3.0, 27), np.full(4, np.inf)],
    }


def compare_auc(superglue: Path | None, gluefactory: Path | None) -> None:
    peers = {}
    if superglue is not None:
        peers["SuperGlue pose_auc"] = peer_functions(superglue / "models" / "utils.py", ["pose_auc"],
                                                     {"np": np})["pose_auc"]
    if gluefactory is not None:
        peers["glue-factory cal_error_auc"] = peer_functions(
            gluefactory / "gluefactory" / "utils" / "tools.py", ["cal_error_auc"], {"np": np})["cal_error_auc"]
    if not peers:
        print("AUC: no checkout given (--superglue, --gluefactory): skipped")
        return
    trapz = getattr(np, "trapz", None) or np.trapezoid
    np.trapz = trapz  # both peers call np.trapz, which NumPy 2 renamed
    print(f"AUC at {THRESHOLDS} px, in %")
    for label, errors in error_lists().items():
        ours = pose_auc(errors, THRESHOLDS)
        print(f"  {label}:")
        print(f"    ctxmatch pose_auc          {np.array2string(100 * ours, precision=4)}")
        for name, func in peers.items():
            theirs = np.asarray(func(errors.copy(), THRESHOLDS), np.float64)
            tol = 5e-5 if "glue" in name else 0.0  # glue-factory rounds to 4 decimals
            diff = np.abs(theirs - ours).max()
            print(f"    {name:26s} {np.array2string(100 * theirs, precision=4)}  max |diff| {diff:.3g}"
                  f"{'' if diff <= tol + 1e-15 else '  <-- DIFFERS'}")
    empty = {name: func(np.empty(0), THRESHOLDS) for name, func in peers.items()}
    print(f"  no pair at all: ctxmatch {pose_auc([], THRESHOLDS)[:2]} ... (undefined); "
          + "; ".join(f"{name} {np.asarray(v, np.float64)[:2]} ..." for name, v in empty.items()))


def compare_corner_error(gluefactory: Path | None) -> None:
    if gluefactory is None:
        print("corner error: no glue-factory checkout given: skipped")
        return
    import torch

    ns = {"np": np, "torch": torch}
    peer_functions(gluefactory / "gluefactory" / "geometry" / "utils.py", ["to_homogeneous", "from_homogeneous"], ns)
    peer = peer_functions(gluefactory / "gluefactory" / "geometry" / "homography.py", ["homography_corner_error"],
                          ns)["homography_corner_error"]
    rng = np.random.default_rng(1)
    T = np.array([[1.0, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])  # our origin (pixel centre) -> theirs (pixel corner)
    worst, n = 0.0, 200
    for _ in range(n):
        size = (int(rng.integers(300, 1200)), int(rng.integers(300, 1000)))
        H, H_gt = (np.eye(3) + rng.normal(0, [[3e-2, 3e-2, 10], [3e-2, 3e-2, 10], [3e-5, 3e-5, 0]]) for _ in range(2))
        ours = homography_corner_error(H, H_gt, size)
        theirs = peer(torch.from_numpy(T @ H @ np.linalg.inv(T)), torch.from_numpy(T @ H_gt @ np.linalg.inv(T)),
                      torch.tensor(size, dtype=torch.float64)).item()
        worst = max(worst, abs(ours - theirs) / max(ours, 1e-12))
    print(f"corner error: {n} random homography pairs, largest relative difference to glue-factory's "
          f"homography_corner_error {worst:.3g}")


def compare_epipolar() -> None:
    try:
        import torch
        from kornia.geometry.epipolar import symmetrical_epipolar_distance
    except ImportError:
        print("symmetric epipolar distance: kornia not installed: skipped")
        return
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(50):
        F = rng.normal(size=(3, 3))
        u, s, vt = np.linalg.svd(F)
        F = u @ np.diag([s[0], s[1], 0.0]) @ vt
        p1, p2 = rng.uniform(0, 800, (500, 2)), rng.uniform(0, 800, (500, 2))
        ours = symmetric_epipolar_distance(F, p1, p2)
        theirs = symmetrical_epipolar_distance(torch.from_numpy(p1)[None], torch.from_numpy(p2)[None],
                                               torch.from_numpy(F)[None], squared=False)[0].numpy()
        worst = max(worst, float(np.max(np.abs(ours - theirs) / np.maximum(ours, 1e-9))))
    print(f"symmetric epipolar distance: 50 random F x 500 points, largest relative difference to kornia's "
          f"symmetrical_epipolar_distance(squared=False) {worst:.3g}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--superglue", default=os.environ.get("CTXMATCH_SUPERGLUE_REF"),
                   help="root of a SuperGluePretrainedNetwork checkout (default: $CTXMATCH_SUPERGLUE_REF)")
    p.add_argument("--gluefactory", default=os.environ.get("CTXMATCH_GLUEFACTORY_REF"),
                   help="root of a glue-factory checkout (default: $CTXMATCH_GLUEFACTORY_REF)")
    args = p.parse_args(argv)
    superglue = Path(args.superglue) if args.superglue else None
    gluefactory = Path(args.gluefactory) if args.gluefactory else None
    compare_auc(superglue, gluefactory)
    compare_corner_error(gluefactory)
    compare_epipolar()


if __name__ == "__main__":
    main()
