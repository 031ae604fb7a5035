"""The custom folder format (:func:`read_custom_dataset`, :func:`write_custom_dataset`): a ``pairs.csv``
with ``pair_id,image1,image2,kind,gt[,F]``, described in ``docs/evaluation.md`` (Datasets). Example::

    pair_id,image1,image2,kind,gt,F
    graf-1-2,graf/img1.png,graf/img2.png,planar,graf/H1to2.txt,
    castle,castle/A.png,castle/B.png,nonplanar,castle/points.txt,castle/F.txt
"""

from __future__ import annotations

import csv
import dataclasses
import os
from pathlib import Path

import numpy as np

from ..cache import atomic_path

from ._io import epipolar_gt, fitted_epipolar_gt, flow_gt, homography_gt, image_size, named_errors, read_matrix
from .base import PAIR_KINDS, Dataset, EpipolarGT, FlowGT, HomographyGT, Pair, PoseGT

__all__ = ["read_custom_dataset", "write_custom_dataset", "read_flow", "write_flow", "REQUIRED_COLUMNS"]

REQUIRED_COLUMNS = ("pair_id", "image1", "image2", "kind", "gt")


def read_flow(path) -> FlowGT:
    """Read a dense ``.npz`` ground truth (arrays ``flow12`` and optionally ``flow21``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground-truth file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            flow12 = np.asarray(z["flow12"], np.float64)
            flow21 = np.asarray(z["flow21"], np.float64) if "flow21" in z.files else None
    except Exception as exc:
        raise ValueError(f"cannot read dense ground truth (flow12[, flow21]) from {path}: {exc}") from None
    return flow_gt(flow12, flow21, path)


def write_flow(path, gt: FlowGT) -> None:
    """Write a :class:`FlowGT` as a compressed ``.npz`` (float32), atomically."""
    arrays = {"flow12": np.asarray(gt.flow12, np.float32)}
    if gt.flow21 is not None:
        arrays["flow21"] = np.asarray(gt.flow21, np.float32)
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)


def _read_points(path) -> np.ndarray:
    pts = read_matrix(path, shape=None, what="ground-truth correspondences")
    if pts.size == 0:
        raise ValueError(f"correspondences file {path} is empty; it needs N >= 7 rows 'x1 y1 x2 y2'")
    if pts.shape[1] != 4:
        raise ValueError(f"correspondences file {path} must have 4 columns 'x1 y1 x2 y2', got {pts.shape[1]}")
    return pts


def _read_gt(folder: Path, row: dict):
    kind = row["kind"].strip().lower()
    if kind not in PAIR_KINDS:
        raise ValueError(f"kind must be one of {PAIR_KINDS}, got {row['kind']!r}")
    gt_name = (row.get("gt") or "").strip()
    if not gt_name:
        raise ValueError("the gt column is empty")
    gt_path = folder / gt_name
    if gt_path.suffix.lower() == ".npz":
        return kind, read_flow(gt_path)
    if kind == "planar":
        return kind, homography_gt(read_matrix(gt_path, what="homography"), gt_path)
    if kind == "nonplanar":
        pts = _read_points(gt_path)
        f_name = (row.get("F") or "").strip()
        if f_name:
            F = read_matrix(folder / f_name, what="fundamental matrix")
            return kind, epipolar_gt(F, folder / f_name, pts[:, :2], pts[:, 2:])
        if len(pts) < 7:
            raise ValueError(f"{gt_path}: fitting F needs at least 7 correspondences, got {len(pts)}")
        return kind, fitted_epipolar_gt(pts[:, :2], pts[:, 2:], gt_path)
    if kind == "calibrated":
        return kind, _read_pose(gt_path)
    raise ValueError(f"kind 'depth' needs a dense .npz ground truth, got {gt_name!r}")


def _read_pose(path: Path) -> PoseGT:
    from .posefile import parse_pose_tokens

    if not path.is_file():
        raise FileNotFoundError(f"ground-truth file not found: {path}")
    lines = [(k, ln) for k, ln in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if ln.strip() and not ln.lstrip().startswith("#")]
    tokens = [t for _, ln in lines for t in ln.split()]
    with named_errors(f"{path}{f', line {lines[0][0]}' if len(lines) == 1 else ''}"):
        return parse_pose_tokens(tokens)


def read_custom_dataset(folder, *, name: str | None = None) -> Dataset:
    """Load the folder holding ``pairs.csv``, named ``name`` (default: the folder's). A missing file raises
    FileNotFoundError, a bad ``pairs.csv``, image or gt file ValueError; both name the file."""
    folder = Path(folder).expanduser()
    if not (folder / "pairs.csv").is_file():
        raise FileNotFoundError(f"pairs.csv not found in {folder}")
    folder = folder.resolve()  # pairs keep absolute paths, valid whatever the working directory
    csv_path = folder / "pairs.csv"
    with open(csv_path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f, skipinitialspace=True)
        header = [c.strip() for c in (reader.fieldnames or [])]
        reader.fieldnames = header
        rows = [(i + 2, r) for i, r in enumerate(reader) if any((v or "").strip() for v in r.values())]
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if not header:
        raise ValueError(f"{csv_path} is empty: expected the header {','.join(REQUIRED_COLUMNS)} and one row per pair")
    if missing:
        raise ValueError(f"{csv_path} misses the column(s) {', '.join(missing)}; header is {','.join(header)}")
    if not rows:
        raise ValueError(f"{csv_path} lists no pairs: add one row per pair under the header")
    name = name or folder.name
    pairs, seen = [], set()
    for line, row in rows:
        pair_id = (row["pair_id"] or "").strip()
        if not pair_id:
            raise ValueError(f"{csv_path}, line {line}: pair_id is empty")
        if pair_id in seen:
            raise ValueError(f"{csv_path}, line {line}: duplicate pair_id {pair_id!r}")
        seen.add(pair_id)
        images = []
        for col in ("image1", "image2"):
            value = (row[col] or "").strip()
            if not value:
                raise ValueError(f"{csv_path}, line {line}: the {col} column is empty")
            images.append(folder / value)
        sizes = [image_size(p) for p in images]  # raises naming a missing or corrupt image
        with named_errors(f"{csv_path}, line {line}, pair {pair_id!r}"):
            kind, gt = _read_gt(folder, row)
        if isinstance(gt, FlowGT):
            w, h = sizes[0]
            if gt.flow12.shape[:2] != (h, w):
                raise ValueError(f"{folder / row['gt'].strip()}: flow12 has shape {gt.flow12.shape[:2]} but image1 "
                                 f"is {h}x{w}")
        if isinstance(gt, PoseGT):  # the pixel thresholds scale with the images (see posefile)
            from .strecha import threshold_scale_for

            gt = dataclasses.replace(gt, threshold_scale=threshold_scale_for((*sizes[0], *sizes[1])))
        pairs.append(Pair(pair_id, images[0], images[1], sizes[0], sizes[1], kind, gt, dataset=name))
    return Dataset(name, pairs, folder)


def _rel(path: Path, folder: Path) -> str:
    try:
        return Path(os.path.relpath(Path(path).resolve(), folder.resolve())).as_posix()
    except ValueError:  # another drive on Windows
        return Path(path).resolve().as_posix()


def write_custom_dataset(dataset, folder) -> Path:
    """Write ``dataset`` (a :class:`Dataset` or a list of pairs) as a custom-format folder and return the
    path of its ``pairs.csv``; images are referenced, ground truth is written under ``gt/``."""
    folder = Path(folder)
    gt_dir = folder / "gt"
    gt_dir.mkdir(parents=True, exist_ok=True)
    pairs = list(dataset)
    lines = []
    for i, p in enumerate(pairs):
        stem = f"{i:04d}"
        f_rel = ""
        if isinstance(p.gt, FlowGT):
            gt_rel = f"gt/{stem}_flow.npz"
            write_flow(folder / gt_rel, p.gt)
        elif isinstance(p.gt, HomographyGT):
            gt_rel = f"gt/{stem}_H.txt"
            np.savetxt(folder / gt_rel, p.gt.H, fmt="%.17g")
        elif isinstance(p.gt, EpipolarGT):
            gt_rel = f"gt/{stem}_points.txt"
            np.savetxt(folder / gt_rel, np.c_[p.gt.pts1, p.gt.pts2], fmt="%.17g")
            f_rel = f"gt/{stem}_F.txt"
            np.savetxt(folder / f_rel, p.gt.F, fmt="%.17g")
        elif isinstance(p.gt, PoseGT):
            from .posefile import format_pose_tokens

            gt_rel = f"gt/{stem}_pose.txt"
            (folder / gt_rel).write_text(" ".join(format_pose_tokens(p.gt)) + "\n", encoding="utf-8")
        else:
            raise ValueError(f"pair {p.pair_id!r}: unsupported ground truth {type(p.gt).__name__}")
        lines.append([p.pair_id, _rel(p.image1, folder), _rel(p.image2, folder), p.kind, gt_rel, f_rel])
    csv_path = folder / "pairs.csv"
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow([*REQUIRED_COLUMNS, "F"])
        w.writerows(lines)
    return csv_path
