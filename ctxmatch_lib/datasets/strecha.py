"""Calibrated pairs from the Strecha et al. (CVPR 2008) scenes in openMVG's layout, standing in for the
paper's SUN3D (Sec. 5.1): :func:`load_strecha_folder`, the pair rule :func:`select_pairs`, the bands
:data:`DIFFICULTY_BANDS`. Layout, ``.camera`` format and pair rule: ``docs/evaluation.md`` (Calibrated pairs).

The 60° cap on the relative rotation: SIFT's repeatability vanishes beyond (Mikolajczyk et al., IJCV 2005).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._numerics.fixedmath import acos
from .._numerics.validation import as_intrinsics, as_rotation
from ._io import IMAGE_SUFFIXES, image_size, named_errors
from .base import ROTATION_TEXT_TOL, Pair, PoseGT, nearest_rotation

__all__ = ["STRECHA_SCENES", "DIFFICULTY_BANDS", "MAX_PAIRS_PER_BAND", "MAX_ROTATION_DEG", "MIN_BASELINE_RATIO",
           "REFERENCE_SIDE", "Camera", "read_strecha_camera", "relative_pose", "pair_geometry", "rotation_band",
           "pose_difficulty", "select_pairs", "threshold_scale_for", "is_strecha_scene", "strecha_scenes",
           "load_strecha_folder"]

#: The six scenes openMVG/SfM_quality_evaluation distributes (``ctxmatch data download strecha``).
STRECHA_SCENES = ("fountain-P11", "Herz-Jesus-P8", "castle-P19", "entry-P10", "Herz-Jesus-P25", "castle-P30")

#: Difficulty bands on the relative rotation angle in degrees: ``(name, low, high)``, low inclusive.
DIFFICULTY_BANDS = (("easy", 0.0, 15.0), ("medium", 15.0, 30.0), ("hard", 30.0, 60.0))

#: Largest relative rotation of a pair (degrees), the top of the ``hard`` band.
MAX_ROTATION_DEG = DIFFICULTY_BANDS[-1][2]

#: Smallest baseline as a fraction of the depth of the fixation point (a defined translation direction).
MIN_BASELINE_RATIO = 0.05

#: Pairs kept per scene and band (keeps the paper-scale gallery within its time budget).
MAX_PAIRS_PER_BAND = 6

#: Image side (px) the paper's pixel thresholds refer to.
REFERENCE_SIDE = 1024


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated view: ``x ~ K R^T (X - C)``, ``R`` camera-to-world, ``size`` (width, height)."""

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    size: tuple[int, int]
    path: Path | None = None


def _numbers(lines: list[str], start: int, stop: int, count: int, path: Path) -> np.ndarray:
    rows = []
    for k in range(start, stop):
        tokens = lines[k].split()
        if len(tokens) != count:
            raise ValueError(f"{path}, line {k + 1}: expected {count} numbers, got {len(tokens)}: {lines[k]!r}")
        try:
            row = [float(v) for v in tokens]
        except ValueError:
            raise ValueError(f"{path}, line {k + 1}: not a number in {lines[k]!r}") from None
        if not np.isfinite(row).all():
            raise ValueError(f"{path}, line {k + 1}: NaN or infinite value in {lines[k]!r}")
        rows.append(row)
    return np.array(rows, np.float64)


def read_strecha_camera(path) -> Camera:
    """Read one ``.camera`` file (9 lines: K, distortion, R, C, size) as a :class:`Camera`; a malformed file
    raises ValueError naming the file and line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if len(lines) != 9:
        raise ValueError(f"{path}: a .camera file has 9 lines (K 3, distortion 1, R 3, C 1, 'width height' 1), "
                         f"got {len(lines)}")
    K = _numbers(lines, 0, 3, 3, path)
    dist = _numbers(lines, 3, 4, 3, path)
    R = _numbers(lines, 4, 7, 3, path)
    C = _numbers(lines, 7, 8, 3, path)[0]
    size = _numbers(lines, 8, 9, 2, path)[0]
    with named_errors(f"{path}, lines 1-3"):
        K = as_intrinsics(K, "K")
    if np.any(dist):
        raise ValueError(f"{path}, line 4: non-zero distortion {dist[0].tolist()}; the images must be undistorted")
    with named_errors(f"{path}, lines 5-7"):
        R = nearest_rotation(as_rotation(R, "R", ROTATION_TEXT_TOL))
    if np.any(size <= 0) or np.any(size != np.round(size)):
        raise ValueError(f"{path}, line 9: 'width height' must be positive integers, got {lines[8]!r}")
    return Camera(K, R, C, (int(size[0]), int(size[1])), path)


def relative_pose(cam1: Camera, cam2: Camera) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` with ``X_cam2 = R @ X_cam1 + t``: ``R = R2^T R1``, ``t = R2^T (C1 - C2)``."""
    return cam2.R.T @ cam1.R, cam2.R.T @ (cam1.C - cam2.C)


def pair_geometry(cam1: Camera, cam2: Camera) -> tuple[float, float, float, float]:
    """Quantities of the pair rule: rotation angle (degrees), depths ``d1``, ``d2`` of the closest points of
    the optical axes along each axis (``nan`` for parallel axes), and the baseline ``|C2 - C1|``."""
    R, _ = relative_pose(cam1, cam2)
    angle = float(np.degrees(acos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    a1, a2 = cam1.R[:, 2], cam2.R[:, 2]  # optical axes in world coordinates
    b = cam2.C - cam1.C
    c = float(a1 @ a2)
    den = 1.0 - c * c
    if den < 1e-12:
        d1 = d2 = float("nan")
    else:
        d1 = float((b @ a1 - c * (b @ a2)) / den)
        d2 = float((c * (b @ a1) - b @ a2) / den)
    return angle, d1, d2, float(np.linalg.norm(b))


def rotation_band(angle_deg: float) -> str:
    """The difficulty band of a relative rotation angle (:data:`DIFFICULTY_BANDS`), ``""`` outside them."""
    for name, lo, hi in DIFFICULTY_BANDS:
        if lo <= angle_deg < hi or (name == DIFFICULTY_BANDS[-1][0] and angle_deg == hi):
            return name
    return ""


def pose_difficulty(pair) -> str:
    """The difficulty band of a calibrated pair: ``pair.gt.difficulty``, else that of the rotation of
    ``pair.gt.R``; ``""`` for a pair of another kind."""
    gt = pair.gt
    if not isinstance(gt, PoseGT):
        return ""
    if gt.difficulty:
        return gt.difficulty
    angle = float(np.degrees(acos(np.clip((np.trace(gt.R) - 1) / 2, -1.0, 1.0))))
    return rotation_band(angle)


def select_pairs(cameras, *, max_per_band: int | None = MAX_PAIRS_PER_BAND) -> list[tuple[int, int, str]]:
    """The pairs ``(i, j, band)`` of one scene's cameras, sorted: axes converging in front of both cameras,
    baseline ≥ :data:`MIN_BASELINE_RATIO` × fixation depth, rotation in a band; at most ``max_per_band``
    (``None``: all) per band, evenly over the angles."""
    by_band: dict[str, list[tuple[float, int, int]]] = {name: [] for name, _, _ in DIFFICULTY_BANDS}
    for i in range(len(cameras)):
        for j in range(i + 1, len(cameras)):
            angle, d1, d2, baseline = pair_geometry(cameras[i], cameras[j])
            if not (d1 > 0 and d2 > 0) or baseline < MIN_BASELINE_RATIO * min(d1, d2):
                continue
            band = rotation_band(angle)
            if band:
                by_band[band].append((angle, i, j))
    out = []
    for band, cands in by_band.items():
        cands.sort()
        n = len(cands) if max_per_band is None else min(len(cands), max_per_band)
        keep = sorted({int(k) for k in np.round(np.linspace(0, len(cands) - 1, n))}) if n else []
        out += [(cands[k][1], cands[k][2], band) for k in keep]
    return sorted(out)


def threshold_scale_for(size) -> float:
    """``max(width, height) / REFERENCE_SIDE``: the factor on the paper's pixel thresholds (Sec. 5.1)."""
    return max(size) / REFERENCE_SIDE


def is_strecha_scene(folder) -> bool:
    """Whether ``folder`` holds ``images/`` and ``gt_dense_cameras/``."""
    folder = Path(folder)
    return (folder / "images").is_dir() and (folder / "gt_dense_cameras").is_dir()


def strecha_scenes(folder) -> list[Path]:
    """The scene folders: ``folder`` itself if it is one, else its sub-folders that are, sorted by name."""
    folder = Path(folder)
    if is_strecha_scene(folder):
        return [folder]
    return sorted(p for p in folder.iterdir() if p.is_dir() and is_strecha_scene(p)) if folder.is_dir() else []


def _scene_views(scene: Path) -> tuple[list[Path], list[Camera]]:
    images = sorted(p for p in (scene / "images").iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not images:
        raise FileNotFoundError(f"no image in {scene / 'images'}")
    cams = []
    for img in images:
        cam = read_strecha_camera(scene / "gt_dense_cameras" / f"{img.name}.camera")
        actual = image_size(img)
        if actual != cam.size:
            raise ValueError(f"{cam.path}, line 9: size {cam.size[0]} {cam.size[1]} but {img} is "
                             f"{actual[0]}x{actual[1]}")
        cams.append(cam)
    return images, cams


def load_strecha_folder(folder, *, dataset: str = "strecha",
                        max_per_band: int | None = MAX_PAIRS_PER_BAND) -> list[Pair]:
    """Calibrated pairs of a scene (``images/``, ``gt_dense_cameras/``) or a folder of scenes, ids
    ``<dataset>/<scene>/<i>-<j>``; ``max_per_band``: see :func:`select_pairs`.

    Raises FileNotFoundError (no scene, a missing ``.camera``) or ValueError (a malformed ``.camera``, a
    size that disagrees with its image).
    """
    scenes = strecha_scenes(folder)
    if not scenes:
        raise FileNotFoundError(f"no scene in the Strecha layout (images/, gt_dense_cameras/) in {folder}")
    pairs = []
    for scene in scenes:
        images, cams = _scene_views(scene.resolve())
        for i, j, band in select_pairs(cams, max_per_band=max_per_band):
            R, t = relative_pose(cams[i], cams[j])
            scale = threshold_scale_for((*cams[i].size, *cams[j].size))
            gt = PoseGT(cams[i].K, cams[j].K, R, t, threshold_scale=scale, difficulty=band)
            pairs.append(Pair(
                pair_id=f"{dataset}/{scene.name}/{i}-{j}", image1=images[i], image2=images[j],
                image_size1=cams[i].size, image_size2=cams[j].size, kind="calibrated", gt=gt, dataset=dataset,
            ))
    return pairs
