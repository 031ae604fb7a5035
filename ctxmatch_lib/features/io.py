"""Images in: reading files (:func:`load_image`), gray uint8 pixels from any array, their hash and size."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

__all__ = ["load_image"]


def load_image(path, *, gray: bool = True) -> np.ndarray:
    """An image file as uint8 pixels; row ``r``, column ``c`` is the point x = c, y = r.

    Parameters
    ----------
    path : str or Path
        Any format OpenCV reads; ``FileNotFoundError`` when missing, ``ValueError`` when it does not decode.
    gray : bool
        ``(H, W)`` gray, else ``(H, W, 3)`` RGB.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    data = np.fromfile(path, dtype=np.uint8)  # also handles non-ASCII paths, unlike cv2.imread
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise ValueError(f"cannot decode image file {path} (corrupt or unsupported format)")
    if not gray:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return img


def as_gray_uint8(image) -> np.ndarray:
    """A path or an array (gray, RGB or RGBA; uint8, other integers or floats in [0, 1]) as gray uint8."""
    if isinstance(image, (str, os.PathLike)):
        return load_image(image, gray=True)
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        rgb = img[..., :3].astype(np.float64)
        img = rgb @ np.array([0.299, 0.587, 0.114])  # ITU-R 601 luma, as OpenCV's RGB2GRAY
        if np.asarray(image).dtype == np.uint8:
            img = np.round(img)
        elif np.issubdtype(np.asarray(image).dtype, np.integer):
            img = img.astype(np.asarray(image).dtype)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim != 2:
        raise ValueError(f"image must be a path, an (H, W) or an (H, W, 3|4) array, got shape {img.shape}")
    if img.dtype == np.bool_:
        return img.astype(np.uint8) * 255
    if np.issubdtype(img.dtype, np.floating):
        if img.size and not np.isfinite(img).all():
            raise ValueError("image contains NaN or infinite values")
        scale = 255.0 if (img.size == 0 or img.max() <= 1.0) else 1.0
        return np.clip(np.round(img * scale), 0, 255).astype(np.uint8)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if np.issubdtype(img.dtype, np.integer):
        info = np.iinfo(img.dtype)
        if img.size and img.max() > 255 and info.max > 255:
            return np.round(img.astype(np.float64) * 255.0 / info.max).astype(np.uint8)
        return np.clip(img, 0, 255).astype(np.uint8)
    raise ValueError(f"image must hold numbers, got dtype {img.dtype}")


def _image_hash(gray: np.ndarray) -> str:
    h = hashlib.sha1()
    h.update(repr(gray.shape).encode())
    h.update(np.ascontiguousarray(gray).tobytes())
    return h.hexdigest()


def _image_size(gray: np.ndarray) -> tuple[int, int]:
    return int(gray.shape[1]), int(gray.shape[0])  # (width, height), as Pair.image_size1
