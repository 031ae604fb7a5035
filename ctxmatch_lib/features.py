"""Features: SIFT keypoints with their elliptical frames and RootSIFT descriptors, cached on disk.

The first stage of the evaluation pipeline of Sec. 5 (images → ``features`` → blob matching → filters).
Keypoints are ``(N, 2)`` float64 arrays of (x, y) pixels, x right, y down, with the origin at the centre of
the top-left pixel. Each keypoint also carries its elliptical patch as a 2×2 affine shape ``A``: the patch is
``{kpt + A @ u : |u| <= 1}``; for SIFT it is a disc of radius ``patch_radius * scale`` whose first axis
points along the keypoint orientation.

Extraction is cached per (OpenCV version, image content, extractor configuration) under
``ctxmatch_lib._paths.cache_dir("features")`` (``$CTXMATCH_CACHE/features``, else
``$XDG_CACHE_HOME/ctxmatch/features`` or ``~/.cache/ctxmatch/features``); every entry is written to a
temporary file and renamed into place, so an interrupted run never leaves a corrupt entry.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ._paths import atomic_path

__all__ = ["FeatureConfig", "Features", "extract_features", "load_image", "FEATURE_PRESETS"]

# Bump when the stored arrays or their meaning change: old cache entries are then ignored.
_CACHE_FORMAT = 1

_DETECTORS = ("sift",)
_DESCRIPTORS = ("rootsift", "sift")


@dataclass(frozen=True)
class FeatureConfig:
    """Settings of the keypoint extractor and descriptor.

    Parameters
    ----------
    detector : {"sift"}
        Keypoint detector: OpenCV's SIFT (difference of Gaussians).
    descriptor : {"rootsift", "sift"}
        ``"rootsift"``: L1-normalised, square-rooted SIFT (Arandjelović & Zisserman 2012), so that the
        Euclidean distance of the descriptors is the Hellinger distance of the histograms; ``"sift"``: plain
        L2-normalised SIFT.
    upright : bool
        Use no dominant orientation: every keypoint gets angle 0 and the descriptor is computed on the
        unrotated patch; keypoints that only differed by orientation are merged.
    max_keypoints : int
        Keep at most this many keypoints, strongest (largest absolute DoG response) first; 0 means no cap.
    n_octave_layers, contrast_threshold, edge_threshold, sigma : int, float, float, float
        OpenCV ``SIFT_create`` parameters (defaults are Lowe's and OpenCV's).
    precise_upscale : bool
        Use OpenCV's precise upscaling of the first octave (index x ↦ 2x), which removes the quarter-pixel
        localisation bias of the default linear upscaling, so keypoints follow the pixel-centre convention.
    patch_radius : float
        Radius of the elliptical patch in units of the keypoint scale (the Gaussian sigma of its octave
        layer); 3 sigma is the usual support of a SIFT blob.
    """

    detector: str = "sift"
    descriptor: str = "rootsift"
    upright: bool = False
    max_keypoints: int = 8000
    n_octave_layers: int = 3
    contrast_threshold: float = 0.04
    edge_threshold: float = 10.0
    sigma: float = 1.6
    precise_upscale: bool = True
    patch_radius: float = 3.0

    def __post_init__(self):
        if self.detector not in _DETECTORS:
            raise ValueError(f"detector must be one of {_DETECTORS}, got {self.detector!r}")
        if self.descriptor not in _DESCRIPTORS:
            raise ValueError(f"descriptor must be one of {_DESCRIPTORS}, got {self.descriptor!r}")
        if int(self.max_keypoints) != self.max_keypoints or self.max_keypoints < 0:
            raise ValueError(f"max_keypoints must be a non-negative integer, got {self.max_keypoints!r}")
        if int(self.n_octave_layers) != self.n_octave_layers or self.n_octave_layers < 1:
            raise ValueError(f"n_octave_layers must be a positive integer, got {self.n_octave_layers!r}")
        for name in ("contrast_threshold", "edge_threshold", "sigma", "patch_radius"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0 or (name in ("sigma", "patch_radius") and value == 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")

    def key(self) -> str:
        """A stable, file-name-safe string identifying this configuration (used for cache folders).

        Examples
        --------
        >>> FeatureConfig().key()
        'sift-rootsift-k8000-v1-441d0e9b'
        """
        items = sorted(asdict(self).items())
        digest = hashlib.sha1(repr(items).encode()).hexdigest()[:8]
        up = "-upright" if self.upright else ""
        return f"{self.detector}-{self.descriptor}{up}-k{self.max_keypoints}-v{_CACHE_FORMAT}-{digest}"


FEATURE_PRESETS = {
    "sift-rootsift": FeatureConfig(),
    "sift-rootsift-upright": FeatureConfig(upright=True),
    "sift": FeatureConfig(descriptor="sift"),
}


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints of one image with their frames and descriptors, strongest first.

    Attributes
    ----------
    kpts : ndarray of shape (N, 2), float64
        (x, y) pixels, x right, y down, origin at the centre of the top-left pixel.
    shapes : ndarray of shape (N, 2, 2), float64
        Affine shape ``A`` of each keypoint: its elliptical patch is ``{kpt + A @ u : |u| <= 1}``.
    desc : ndarray of shape (N, D), float32
        Descriptors (D = 128 for SIFT/RootSIFT), unit L2 norm.
    scales : ndarray of shape (N,), float64
        Keypoint scale: the Gaussian sigma of the detection in image pixels.
    angles : ndarray of shape (N,), float64
        Orientation in radians in the image frame (x right, y down, so positive angles turn clockwise on
        screen); 0 for upright features.
    responses : ndarray of shape (N,), float64
        Detector response (absolute DoG value), non-increasing along the rows.
    """

    kpts: np.ndarray
    shapes: np.ndarray
    desc: np.ndarray
    scales: np.ndarray
    angles: np.ndarray
    responses: np.ndarray

    def __len__(self) -> int:
        return len(self.kpts)

    @classmethod
    def empty(cls, dim: int = 128) -> "Features":
        """No keypoints, with the right shapes and dtypes."""
        return cls(
            np.empty((0, 2)), np.empty((0, 2, 2)), np.empty((0, dim), np.float32),
            np.empty(0), np.empty(0), np.empty(0),
        )


def load_image(path, *, gray: bool = True) -> np.ndarray:
    """Read an image file.

    Parameters
    ----------
    path : str or Path
        Image file (any format OpenCV reads: PNG, JPEG, PPM/PGM, TIFF, ...).
    gray : bool
        Return a single-channel ``(H, W)`` uint8 image; otherwise ``(H, W, 3)`` uint8 in RGB order.

    Returns
    -------
    ndarray
        The pixels; row ``r``, column ``c`` is the point x = c, y = r.

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    ValueError
        ``path`` exists but cannot be decoded as an image.
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


def _as_gray_uint8(image) -> np.ndarray:
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


def _shapes(scales: np.ndarray, angles: np.ndarray, radius: float) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2), columns = patch axes
    return rot * (radius * scales)[:, None, None]


def _extract(gray: np.ndarray, config: FeatureConfig) -> Features:
    import cv2

    if gray.size == 0 or min(gray.shape) < 8:
        return Features.empty()
    sift = cv2.SIFT_create(
        0, int(config.n_octave_layers), float(config.contrast_threshold), float(config.edge_threshold),
        float(config.sigma), bool(config.precise_upscale),
    )
    kps = sift.detect(gray, None)
    if not kps:
        return Features.empty()
    pts = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
    size = np.array([k.size for k in kps], np.float64)
    ang = np.array([k.angle for k in kps], np.float64)
    resp = np.abs(np.array([k.response for k in kps], np.float64))
    octave = np.array([k.octave for k in kps], np.int64)  # compute() reads the pyramid level from it
    if config.upright:
        ang = np.zeros_like(ang)
        # SIFT duplicates a blob for each secondary orientation peak; upright they are one keypoint.
        _, first = np.unique(np.c_[pts, size], axis=0, return_index=True)
        keep = np.sort(first)
        pts, size, ang, resp, octave = pts[keep], size[keep], ang[keep], resp[keep], octave[keep]
    # Strongest first; ties broken by position, size and angle so the order never depends on OpenCV's.
    order = np.lexsort((ang, size, pts[:, 1], pts[:, 0], -resp))
    if config.max_keypoints:
        order = order[: int(config.max_keypoints)]
    pts, size, ang, resp, octave = pts[order], size[order], ang[order], resp[order], octave[order]
    kps = [
        cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o))
        for (x, y), s, a, r, o in zip(pts, size, ang, resp, octave)
    ]
    kps_out, desc = sift.compute(gray, kps)
    if desc is None or len(kps_out) != len(kps):
        # compute() may drop keypoints; re-align on what it kept.
        if desc is None or not kps_out:
            return Features.empty()
        pts = np.array([k.pt for k in kps_out], np.float64)
        size = np.array([k.size for k in kps_out], np.float64)
        ang = np.array([k.angle for k in kps_out], np.float64)
        resp = np.abs(np.array([k.response for k in kps_out], np.float64))
    desc = desc.astype(np.float64)
    if config.descriptor == "rootsift":
        desc = np.sqrt(desc / np.maximum(desc.sum(1, keepdims=True), 1e-12))
    else:
        desc = desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
    scales = size / 2.0  # OpenCV's KeyPoint.size is twice the detection sigma
    # OpenCV angles are degrees measured in the image frame (clockwise on screen, y down).
    angles = np.deg2rad(ang)
    angles = np.where(angles > np.pi, angles - 2 * np.pi, angles)
    return Features(
        kpts=np.ascontiguousarray(pts),
        shapes=_shapes(scales, angles, float(config.patch_radius)),
        desc=np.ascontiguousarray(desc, dtype=np.float32),
        scales=scales,
        angles=angles,
        responses=resp,
    )


_FIELDS = ("kpts", "shapes", "desc", "scales", "angles", "responses")


def _load_entry(path: Path) -> Features | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            feats = Features(**{name: z[name] for name in _FIELDS})
    except Exception:  # a partial or foreign file: treat as a miss and overwrite it
        return None
    n = len(feats.kpts)
    if any(len(getattr(feats, f)) != n for f in _FIELDS):
        return None
    return feats


def _save_entry(path: Path, feats: Features) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **{name: getattr(feats, name) for name in _FIELDS})


def feature_cache_path(image, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> Path:
    """Where :func:`extract_features` stores the features of ``image`` under ``config``."""
    gray = _as_gray_uint8(image)
    return _entry_path(_image_hash(gray), config, cache_dir)


def _entry_path(digest: str, config: FeatureConfig, cache_dir) -> Path:
    if cache_dir is None:
        from ._paths import cache_dir as default_cache_dir

        base = default_cache_dir("features")
    else:
        base = Path(cache_dir)
    # SIFT's keypoints and descriptors change between OpenCV releases: the version is part of the key.
    return base / f"opencv-{_opencv_version()}" / config.key() / digest[:2] / f"{digest}.npz"


def _opencv_version() -> str:
    import cv2

    return cv2.__version__


def extract_features(image, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> Features:
    """Detect SIFT keypoints and describe them, reusing the on-disk cache.

    Parameters
    ----------
    image : str, Path or ndarray
        An image file, or pixels: ``(H, W)`` gray or ``(H, W, 3|4)`` RGB(A); uint8, wider integers, or
        floats in [0, 1].
    config : FeatureConfig
        Extractor settings; part of the cache key.
    cache_dir : str, Path, None or False
        Cache folder: ``None`` for ``ctxmatch_lib._paths.cache_dir("features")``, ``False`` to disable the
        cache. Entries are keyed by the OpenCV version, the hash of the gray pixels and ``config.key()``.

    Returns
    -------
    Features
        Keypoints sorted by decreasing response, at most ``config.max_keypoints``; empty (N = 0) when the
        image is blank or tiny.

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.data import camera
    >>> f = extract_features(camera(), FeatureConfig(max_keypoints=100), cache_dir=False)
    >>> f.kpts.shape, f.desc.shape, f.shapes.shape
    ((100, 2), (100, 128), (100, 2, 2))
    >>> bool(np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-5))
    True
    """
    if not isinstance(config, FeatureConfig):
        raise ValueError(f"config must be a FeatureConfig, got {type(config).__name__}")
    gray = _as_gray_uint8(image)
    if cache_dir is False:
        return _extract(gray, config)
    path = _entry_path(_image_hash(gray), config, cache_dir)
    if path.is_file():
        feats = _load_entry(path)
        if feats is not None:
            return feats
    feats = _extract(gray, config)
    _save_entry(path, feats)
    return feats
