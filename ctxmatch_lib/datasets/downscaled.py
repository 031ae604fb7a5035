"""Calibrated pairs downscaled by an integer factor, intrinsics mapped to match (:func:`downscale_pairs`,
``strecha-half``): the paper's pixel thresholds refer to images about 1000 px wide (Sec. 5.1). See
``docs/evaluation.md`` (Calibrated pairs)."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from .base import Pair, PoseGT

__all__ = ["downscale_image", "downscale_intrinsics", "downscale_pairs"]

#: The image width the paper's pixel thresholds were set on (Sec. 5.1: images about 1000 px wide).
PAPER_IMAGE_SIDE = 1024


def downscale_image(img: np.ndarray, factor: int) -> np.ndarray:
    """Mean of each ``factor × factor`` block of a 2-D uint8 image, rounded half up, in integer arithmetic;
    rows and columns beyond the last whole block are dropped.

    Examples
    --------
    >>> downscale_image(np.array([[0, 1, 10, 10], [2, 3, 10, 11]], np.uint8), 2)
    array([[ 2, 10]], dtype=uint8)
    """
    img = np.asarray(img)
    if img.ndim != 2 or img.dtype != np.uint8:
        raise ValueError(f"img must be a 2-D uint8 image, got {img.dtype} {img.shape}")
    _check_factor(factor)
    h, w = img.shape[0] // factor, img.shape[1] // factor
    if h == 0 or w == 0:
        raise ValueError(f"img of {img.shape[1]} x {img.shape[0]} px is smaller than factor {factor}")
    blocks = img[: h * factor, : w * factor].astype(np.int64).reshape(h, factor, w, factor).sum(axis=(1, 3))
    n = factor * factor
    return ((blocks + n // 2) // n).astype(np.uint8)


def downscale_intrinsics(K, factor: int) -> np.ndarray:
    """``K`` of an image downscaled by ``factor``: pixel centres at integers, ``x`` becomes
    ``(x + 0.5) / factor - 0.5``.

    Examples
    --------
    >>> downscale_intrinsics(np.array([[100.0, 0, 49.5], [0, 100, 29.5], [0, 0, 1]]), 2)
    array([[50. ,  0. , 24.5],
           [ 0. , 50. , 14.5],
           [ 0. ,  0. ,  1. ]])
    """
    _check_factor(factor)
    s = 1.0 / factor
    A = np.array([[s, 0.0, (s - 1.0) / 2], [0.0, s, (s - 1.0) / 2], [0.0, 0.0, 1.0]])
    return A @ np.asarray(K, np.float64)


def _check_factor(factor) -> None:
    if isinstance(factor, bool) or not isinstance(factor, (int, np.integer)) or factor < 1:
        raise ValueError(f"factor must be a positive integer, got {factor!r}")


def _downscaled_file(image: Path, factor: int, folder: Path) -> Path:
    """The downscaled copy of ``image`` in ``folder``, written on first use (atomically)."""
    from ..features import load_image

    # Keyed by path and size: same-named files of two scenes never collide, an edited source gets a new copy.
    st = image.stat()
    key = hashlib.sha256(f"{image.resolve()}|{st.st_size}|{factor}".encode()).hexdigest()[:16]
    out = folder / f"{image.stem}-{key}.png"
    if out.is_file():
        return out
    import cv2

    small = downscale_image(load_image(image, gray=True), factor)
    ok, buf = cv2.imencode(".png", small)
    if not ok:
        raise ValueError(f"cannot encode the downscaled copy of {image}")
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".png")
    with os.fdopen(fd, "wb") as fh:
        fh.write(buf.tobytes())
    os.replace(tmp, out)
    return out


def downscale_pairs(pairs, factor: int = 2, *, folder=None, suffix: str = "half") -> list[Pair]:
    """Calibrated (``PoseGT``) pairs with their images downscaled by ``factor`` and ``K`` mapped to match.

    Images go to ``folder`` (default ``<cache>/datasets/downscaled-<factor>``); ``suffix`` is appended to the
    dataset name so the resolutions never mix. Pair ids are kept; ``threshold_scale`` becomes the longer side /
    :data:`PAPER_IMAGE_SIDE`.
    """
    from ..cache import cache_dir

    _check_factor(factor)
    folder = Path(folder) if folder is not None else cache_dir("datasets") / f"downscaled-{factor}"
    out = []
    for p in pairs:
        if not isinstance(p.gt, PoseGT):
            raise ValueError(f"pairs: {p.pair_id} has {type(p.gt).__name__}, only PoseGT pairs can be downscaled")
        im1, im2 = (_downscaled_file(Path(im), factor, folder) for im in (p.image1, p.image2))
        size1 = (p.image_size1[0] // factor, p.image_size1[1] // factor)
        size2 = (p.image_size2[0] // factor, p.image_size2[1] // factor)
        gt = dataclasses.replace(p.gt, K1=downscale_intrinsics(p.gt.K1, factor),
                                 K2=downscale_intrinsics(p.gt.K2, factor),
                                 threshold_scale=max(*size1, *size2) / PAPER_IMAGE_SIDE)
        out.append(dataclasses.replace(p, image1=im1, image2=im2, image_size1=size1, image_size2=size2, gt=gt,
                                       dataset=f"{p.dataset}-{suffix}" if p.dataset else suffix))
    return out
