"""Loaders of the public real datasets in their authors' formats (:data:`REAL_LOADERS`: HPatches, Oxford,
Lebeda's homogr and kusvod2), each taking the data root (default ``$CTXMATCH_DATA``) or the dataset folder.
Lebeda's files relate B to A; image 1 is A, so homogr gets ``inv(model)`` and kusvod2 ``F^T``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..cache import data_root
from ._io import epipolar_gt, fitted_epipolar_gt, homography_gt, image_size, named_errors, read_matrix, read_vpts
from .base import Pair, _check_matrix

__all__ = ["load_hpatches", "load_oxford", "load_homogr", "load_kusvod2", "REAL_LOADERS"]


def _resolve(root, subpath: str, marker) -> Path:
    """The dataset folder: ``root/subpath``, ``root/<last part>`` or ``root`` itself, first that ``marker`` accepts."""
    if root is None:
        root = data_root(required=True)
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"data root not found: {root}")
    root = root.resolve()  # pairs keep absolute paths, valid whatever the working directory
    last = Path(subpath).name
    for cand in (root / subpath, root / last, root):
        if cand.is_dir() and marker(cand):
            return cand
    raise FileNotFoundError(
        f"{last} data not found under {root} (looked in {root / subpath}, {root / last} and {root}); "
        f"run `ctxmatch data download {last}` or set CTXMATCH_DATA"
    )


def _images_in(folder: Path, pattern: str) -> dict[str, Path]:
    rx = re.compile(pattern)
    out = {}
    for p in sorted(folder.iterdir()):
        m = rx.fullmatch(p.name)
        if m and p.is_file():
            out.setdefault(m.group(1), p)
    return out


def _sequence_pairs(seq: Path, images: dict[str, Path], gt_name, dataset: str) -> list[Pair]:
    if "1" not in images:
        raise FileNotFoundError(f"reference image 1 not found in sequence folder {seq}")
    ref = images["1"]
    size1 = image_size(ref)
    pairs = []
    for k in sorted((k for k in images if k != "1"), key=int):
        H = read_matrix(seq / gt_name(k), what="homography")
        pairs.append(Pair(
            pair_id=f"{dataset}/{seq.name}/1-{k}", image1=ref, image2=images[k], image_size1=size1,
            image_size2=image_size(images[k]), kind="planar", gt=homography_gt(H, seq / gt_name(k)),
            dataset=dataset,
        ))
    return pairs


def _sequences(folder: Path, dataset: str, image_prefix: str, gt_name) -> list[Pair]:
    """The pairs 1→k of every sequence folder in ``folder`` (one holding ``gt_name(2)``)."""
    pairs = []
    for seq in sorted(s for s in folder.iterdir() if s.is_dir() and (s / gt_name(2)).is_file()):
        images = _images_in(seq, image_prefix + r"(\d+)\.(?:ppm|png|jpg|pgm)")
        pairs += _sequence_pairs(seq, images, gt_name, dataset)
    return pairs


def load_hpatches(root=None) -> list[Pair]:
    """HPatches sequences (Balntas et al., CVPR 2017), pairs 1→k; ``root`` may also be the extracted
    ``hpatches-sequences-release`` folder."""
    folder = _resolve(root, "planar/hpatches", lambda d: any((s / "H_1_2").is_file() for s in d.iterdir()))
    if not (folder / "planar").exists() and (folder / "hpatches-sequences-release").is_dir():
        folder = folder / "hpatches-sequences-release"
    return _sequences(folder, "hpatches", "", lambda k: f"H_1_{k}")


def load_oxford(root=None) -> list[Pair]:
    """Oxford affine sequences (Mikolajczyk et al., IJCV 2005): ``img1 … img6`` with ``H1tokp``, pairs 1→k."""
    folder = _resolve(root, "planar/oxford", lambda d: any((s / "H1to2p").is_file() for s in d.iterdir()))
    return _sequences(folder, "oxford", "img", lambda k: f"H1to{k}p")


def _ab_pairs(folder: Path):
    """(name, imageA, imageB, vpts) for each ``<name>_vpts.mat`` in ``folder``."""
    out = []
    for vpts in sorted(folder.glob("*_vpts.mat")):
        name = vpts.name[: -len("_vpts.mat")]
        imgs = {}
        for side in "AB":
            found = [p for p in sorted(folder.glob(f"{name}{side}.*")) if p.suffix.lower() != ".mat"]
            if not found:
                raise FileNotFoundError(f"image file not found: {folder / name}{side}.* (for {vpts.name})")
            imgs[side] = found[0]
        out.append((name, imgs["A"], imgs["B"], vpts))
    return out


def _model_file(folder: Path, name: str, mat_model):
    """The 3x3 model from ``<name>_model.txt`` or the .mat, ``None`` when absent or all zeros, and its file."""
    txt = folder / f"{name}_model.txt"
    if txt.is_file():
        M = read_matrix(txt, what="model")
        return (M if np.any(M) else None), txt
    return mat_model, folder / f"{name}_vpts.mat"


def load_homogr(root=None) -> list[Pair]:
    """Lebeda, Matas & Chum (BMVC 2012) planar "homogr" pairs, image 1 = A: ``H`` is the inverse of the
    shipped model (B to A), else fitted to the hand points, which are kept in ``pts1``/``pts2``."""
    import cv2

    folder = _resolve(root, "planar/homogr", lambda d: any(d.glob("*_vpts.mat")))
    pairs = []
    for name, a, b, vpts in _ab_pairs(folder):
        ptsA, ptsB, mat_model = read_vpts(vpts)
        model, source = _model_file(folder, name, mat_model)
        if model is not None:
            with named_errors(source):  # inverted below: a singular model must fail here, naming its file
                _check_matrix(model, "model", "homography", min_rank=3)
            H = np.linalg.inv(model)
        else:
            if len(ptsA) < 4:
                raise ValueError(f"{vpts}: no model and fewer than 4 hand points to fit a homography")
            H, _ = cv2.findHomography(ptsA, ptsB, 0)
            source = f"{vpts} (H fitted to its hand points)"
            if H is None:
                raise ValueError(f"{source}: the hand points are degenerate (collinear or coincident)")
        pairs.append(Pair(
            pair_id=f"homogr/{name}", image1=a, image2=b, image_size1=image_size(a), image_size2=image_size(b),
            kind="planar", gt=homography_gt(H, source, ptsA, ptsB), dataset="homogr",
        ))
    return pairs


def load_kusvod2(root=None) -> list[Pair]:
    """Lebeda, Matas & Chum (BMVC 2012) non-planar "kusvod2" pairs, image 1 = A: F is the transpose of the
    shipped one (``xA^T F xB = 0``), else fitted (:func:`._io.fundamental_from_hand_points`)."""
    folder = _resolve(root, "nonplanar/kusvod2", lambda d: any(d.glob("*_vpts.mat")))
    pairs = []
    for name, a, b, vpts in _ab_pairs(folder):
        ptsA, ptsB, mat_model = read_vpts(vpts)
        model, source = _model_file(folder, name, mat_model)
        gt = epipolar_gt(model.T, source, ptsA, ptsB) if model is not None else fitted_epipolar_gt(ptsA, ptsB, vpts)
        pairs.append(Pair(
            pair_id=f"kusvod2/{name}", image1=a, image2=b, image_size1=image_size(a), image_size2=image_size(b),
            kind="nonplanar", gt=gt, dataset="kusvod2",
        ))
    return pairs


REAL_LOADERS = {
    "hpatches": load_hpatches,
    "oxford": load_oxford,
    "homogr": load_homogr,
    "kusvod2": load_kusvod2,
}
