"""The feature cache: :func:`extract_features` reads an entry per (OpenCV version, gray pixels, settings) or
extracts and writes it (temporary file, then rename: an interrupted run never leaves a corrupt entry).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cache import atomic_path
from ..cache import cache_dir as default_cache_dir
from .base import Features
from .config import FeatureConfig
from .extract import _extract
from .io import as_gray_uint8, _image_hash, _image_size

__all__ = ["extract_features", "feature_cache_path"]


# Part of the entry's file name: bump it when only the entry layout changes (the caches built on it stay).
_ENTRY_FORMAT = 2

_FIELDS = ("kpts", "shapes", "desc", "scales", "angles", "responses")


def _load_entry(path: Path, image_size: tuple[int, int]) -> Features | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            metric = str(z["metric"]) if "metric" in z.files else "l2"
            size = tuple(int(v) for v in z["image_size"])
            feats = Features(**{name: z[name] for name in _FIELDS}, metric=metric, image_size=size)
    except Exception:  # a partial, foreign or older-format file: treat as a miss and overwrite it
        return None
    n = len(feats.kpts)
    if any(len(getattr(feats, f)) != n for f in _FIELDS) or feats.image_size != image_size:
        return None
    return feats


def _save_entry(path: Path, feats: Features) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **{name: getattr(feats, name) for name in _FIELDS}, metric=np.array(feats.metric),
                 image_size=np.array(feats.image_size, np.int64))


def feature_cache_path(image, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> Path:
    """Where :func:`extract_features` stores the features of ``image`` under ``config``."""
    gray = as_gray_uint8(image)
    return _entry_path(_image_hash(gray), config, cache_dir)


def _entry_path(digest: str, config: FeatureConfig, cache_dir) -> Path:
    base = default_cache_dir("features") if cache_dir is None else Path(cache_dir)
    # SIFT's keypoints and descriptors change between OpenCV releases: the version is part of the key.
    return base / f"opencv-{_opencv_version()}" / config.key() / digest[:2] / f"{digest}.e{_ENTRY_FORMAT}.npz"


def _opencv_version() -> str:
    import cv2

    return cv2.__version__


def extract_features(image, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> Features:
    """The :class:`Features` of ``image`` under ``config``, empty for a blank or tiny image, cached.

    Parameters
    ----------
    image : str, Path or ndarray
        A file or pixels (:func:`.io.as_gray_uint8`).
    config : FeatureConfig
    cache_dir : str, Path, None or False
        ``None``: ``ctxmatch_lib.cache.cache_dir("features")``; ``False``: no cache. Entries are keyed by the
        OpenCV version, the gray pixels' hash and ``config.key()``.

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.data import camera
    >>> f = extract_features(camera(), FeatureConfig(max_keypoints=100), cache_dir=False)
    >>> f.kpts.shape, f.desc.shape, f.shapes.shape, f.image_size
    ((100, 2), (100, 128), (100, 2, 2), (512, 512))
    >>> bool(np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-5))
    True
    """
    if not isinstance(config, FeatureConfig):
        raise ValueError(f"config must be a FeatureConfig, got {type(config).__name__}")
    gray = as_gray_uint8(image)
    if cache_dir is False:
        return _extract(gray, config)
    path = _entry_path(_image_hash(gray), config, cache_dir)
    if path.is_file():
        feats = _load_entry(path, _image_size(gray))
        if feats is not None:
            return feats
    # The steps shared by several blocks of an image (HarrisZ, OriNet) are kept beside the entries.
    feats = _extract(gray, config, memo=path.parents[2] / "shared")
    _save_entry(path, feats)
    return feats
