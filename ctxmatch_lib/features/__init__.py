"""Features: keypoints with their elliptical frames and descriptors, cached on disk.

Detectors: SIFT (OpenCV's DoG) and HarrisZ (:mod:`.harrisz`). Descriptors: RootSIFT / SIFT, RootsGLOH2
(:mod:`.sgloh`, non-oriented patches, rotation-min distance) and, with the optional torch extra, HardNet2 and
SOSNet through kornia (:mod:`.deep`), on patches oriented by OriNet. The paper's eight detector+descriptor
blocks of Fig. 5 are in :data:`FEATURE_PRESETS` (Sec. 5: "SIFT and HarrisZ ... RootSIFT, RootsGLOH2, HardNet2
and SOSNet").

The first stage of the evaluation pipeline of Sec. 5 (images → ``features`` → blob matching → filters).
Keypoints are ``(N, 2)`` float64 arrays of (x, y) pixels, x right, y down, with the origin at the centre of
the top-left pixel. Each keypoint also carries its elliptical patch as a 2×2 affine shape ``A``: the patch is
``{kpt + A @ u : |u| <= 1}``; for SIFT it is a disc of radius ``patch_radius * scale`` whose first axis
points along the keypoint orientation; for HarrisZ an ellipse (``A`` symmetric before orientation).
Patch descriptors sample ``2 A`` (the 6σ reach of the SIFT descriptor around a 3σ disc).

Extraction is cached per (OpenCV version, image content, extractor configuration) under
``ctxmatch_lib._paths.cache_dir("features")`` (``$CTXMATCH_CACHE/features``, else
``$XDG_CACHE_HOME/ctxmatch/features`` or ``~/.cache/ctxmatch/features``); every entry is written to a
temporary file and renamed into place, so an interrupted run never leaves a corrupt entry.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from .._paths import atomic_path
from .._validation import Presets

__all__ = [
    "FeatureConfig", "Features", "extract_features", "load_image", "FEATURE_PRESETS", "FEATURE_DESCRIPTIONS",
    "descriptor_distance", "feature_cache_path", "PAPER_FEATURE_BLOCKS", "paper_feature_blocks",
]

# Bump when the extracted features change (keypoints, frames, descriptors): part of FeatureConfig.key(), so
# every cache keyed on it (features, sweep units) is then recomputed.
_CACHE_FORMAT = 1
# Bump when only the layout of a stored feature entry changes (the features are the same): part of the entry's
# file name, so old entries are ignored while the keys of the caches built on the features stay.
# 2: entries carry the image size.
_ENTRY_FORMAT = 2

_DETECTORS = ("sift", "harrisz")
_DESCRIPTORS = ("rootsift", "sift", "rootsgloh2", "hardnet2", "sosnet")
_DEEP = ("hardnet2", "sosnet")
_ORIENTATIONS = ("auto", "sift", "dominant", "orinet", "none")
_NETS = ("auto", "hardnet", "sosnet", "tfeat", "hardtfeat")
# Fields added after cache format 1: left out of the key digest at their defaults, so the keys (and cache
# entries) of the SIFT configurations stay what they were.
_NEW_FIELDS = {"orientation": "auto", "weights": None, "net": "auto", "orinet_weights": None,
               "support": 2.0}


@dataclass(frozen=True)
class FeatureConfig:
    """Settings of the keypoint extractor and descriptor.

    Parameters
    ----------
    detector : {"sift", "harrisz"}
        Keypoint detector: OpenCV's SIFT (difference of Gaussians), or HarrisZ (:func:`.harrisz.harrisz`,
        affine multi-scale Harris corners).
    descriptor : {"rootsift", "sift", "rootsgloh2", "hardnet2", "sosnet"}
        ``"rootsift"``: L1-normalised, square-rooted SIFT (Arandjelović & Zisserman 2012), so that the
        Euclidean distance of the descriptors is the Hellinger distance of the histograms; ``"sift"``: plain
        L2-normalised SIFT; ``"rootsgloh2"``: RootsGLOH2 (256-D, non-oriented patches, matched with the
        rotation-min distance of :func:`descriptor_distance`); ``"hardnet2"``, ``"sosnet"``: deep patch
        descriptors through kornia (needs torch and kornia, see ``weights``).
    upright : bool
        Use no dominant orientation: every keypoint gets angle 0 and the descriptor is computed on the
        unrotated patch; keypoints that only differed by orientation are merged.
    max_keypoints : int
        Keep at most this many keypoints, strongest (largest absolute DoG response) first for SIFT, finest
        scale then strongest first for HarrisZ; 0 means no cap.
    n_octave_layers, contrast_threshold, edge_threshold, sigma : int, float, float, float
        OpenCV ``SIFT_create`` parameters (defaults are Lowe's and OpenCV's).
    precise_upscale : bool
        Use OpenCV's precise upscaling of the first octave (index x ↦ 2x), which removes the quarter-pixel
        localisation bias of the default linear upscaling, so keypoints follow the pixel-centre convention.
    patch_radius : float
        Radius of the elliptical patch in units of the keypoint scale (the Gaussian sigma of its octave
        layer); 3 sigma is the usual support of a SIFT blob. For HarrisZ, the major semi-axis of the
        ellipse in units of the integration scale.
    orientation : {"auto", "sift", "dominant", "orinet", "none"}
        Patch orientation: SIFT's own (SIFT detector only), the dominant gradient orientation of the
        affine-normalised patch (a handcrafted stand-in for the learned orientation of Yi et al. 2016 that the
        paper uses), OriNet through kornia (the learned stand-in, weights ``orinet_weights``), or none.
        ``"auto"``: none for RootsGLOH2 and upright, SIFT's for SIFT+(Root)SIFT, dominant for
        HarrisZ+(Root)SIFT, OriNet for the deep descriptors.
    weights : str, optional
        Deep descriptor weights: a path, or a file name in the weights folder (``$CTXMATCH_WEIGHTS``, else
        ``$CTXMATCH_DATA/../weights``). ``None`` loads the published weights the way kornia does (download on a
        connected machine). The file's hash is part of :meth:`key`.
    net : {"auto", "hardnet", "sosnet", "tfeat", "hardtfeat"}
        Network architecture for ``weights``: ``"auto"`` is the descriptor's own (kornia's HardNet for
        hardnet2, SOSNet for sosnet); stand-in weights of another architecture name it here.
    orinet_weights : str, optional
        OriNet weights (path or file name in the weights folder); ``None``: kornia's published ones.
    support : float
        Patch descriptors sample ``support × A`` around each keypoint.
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
    orientation: str = "auto"
    weights: str | None = None
    net: str = "auto"
    orinet_weights: str | None = None
    support: float = 2.0

    def __post_init__(self):
        if self.detector not in _DETECTORS:
            raise ValueError(f"detector must be one of {_DETECTORS}, got {self.detector!r}")
        if self.descriptor not in _DESCRIPTORS:
            raise ValueError(f"descriptor must be one of {_DESCRIPTORS}, got {self.descriptor!r}")
        if self.orientation not in _ORIENTATIONS:
            raise ValueError(f"orientation must be one of {_ORIENTATIONS}, got {self.orientation!r}")
        if self.net not in _NETS:
            raise ValueError(f"net must be one of {_NETS}, got {self.net!r}")
        if self.orientation == "sift" and self.detector != "sift":
            raise ValueError("orientation='sift' needs detector='sift'")
        if self.descriptor == "rootsgloh2" and self.orientation not in ("auto", "none"):
            raise ValueError("RootsGLOH2 works on non-oriented patches: orientation must be 'auto' or 'none', "
                             f"got {self.orientation!r}")
        if self.descriptor not in _DEEP and (self.weights is not None or self.net != "auto"):
            raise ValueError(f"weights and net apply to the deep descriptors {_DEEP}, not {self.descriptor!r}")
        if not np.isfinite(self.support) or self.support <= 0:
            raise ValueError(f"support must be a positive number, got {self.support!r}")
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
        items = sorted((k, v) for k, v in asdict(self).items() if not (k in _NEW_FIELDS and v == _NEW_FIELDS[k]))
        # The weights enter by content: another file under the same name is another configuration.
        for field in ("weights", "orinet_weights"):
            if getattr(self, field) is not None or (field == "orinet_weights"
                                                    and self.resolved_orientation() == "orinet"):
                from .deep import weights_digest

                items.append((field + "_sha1", weights_digest(getattr(self, field), field)))
        digest = hashlib.sha1(repr(items).encode()).hexdigest()[:8]
        up = "-upright" if self.upright else ""
        return f"{self.detector}-{self.descriptor}{up}-k{self.max_keypoints}-v{_CACHE_FORMAT}-{digest}"

    def resolved_orientation(self) -> str:
        """The orientation ``"auto"`` stands for (see the class docstring)."""
        if self.orientation != "auto":
            return self.orientation
        if self.descriptor == "rootsgloh2" or self.upright:
            return "none"
        if self.descriptor in _DEEP:
            return "orinet"
        return "sift" if self.detector == "sift" else "dominant"


_HARDNET2_STANDIN = dict(weights="HardTFeat.pth", net="hardtfeat", orinet_weights="OriNet.pth")
_SOSNET_STANDIN = dict(weights="tfeat-liberty.params", net="tfeat", orinet_weights="OriNet.pth")

FEATURE_PRESETS = Presets("feature preset", {
    "sift-rootsift": FeatureConfig(),
    "sift-rootsift-upright": FeatureConfig(upright=True),
    "sift": FeatureConfig(descriptor="sift"),
    "sift-rootsgloh2": FeatureConfig(descriptor="rootsgloh2"),
    "harrisz-rootsift": FeatureConfig(detector="harrisz"),
    "harrisz-rootsgloh2": FeatureConfig(detector="harrisz", descriptor="rootsgloh2"),
    "sift-hardnet2": FeatureConfig(descriptor="hardnet2", **_HARDNET2_STANDIN),
    "sift-sosnet": FeatureConfig(descriptor="sosnet", **_SOSNET_STANDIN),
    "harrisz-hardnet2": FeatureConfig(detector="harrisz", descriptor="hardnet2", **_HARDNET2_STANDIN),
    "harrisz-sosnet": FeatureConfig(detector="harrisz", descriptor="sosnet", **_SOSNET_STANDIN),
})

#: One line per preset for tables and figure captions; every stand-in says so and names its weights.
FEATURE_DESCRIPTIONS = {
    "sift-rootsift": "SIFT + RootSIFT (SIFT orientation)",
    "sift-rootsift-upright": "upright SIFT + RootSIFT",
    "sift": "SIFT + SIFT (plain L2)",
    "sift-rootsgloh2": "SIFT + RootsGLOH2 (non-oriented patches, rotation-min distance)",
    "harrisz-rootsift": "HarrisZ + RootSIFT (dominant-gradient orientation: stand-in for the learned orientation)",
    "harrisz-rootsgloh2": "HarrisZ + RootsGLOH2 (non-oriented patches, rotation-min distance)",
    "sift-hardnet2": "SIFT + HardNet2 stand-in (TFeat architecture, weights HardTFeat.pth; "
                     "orientation: OriNet stand-in, OriNet.pth)",
    "sift-sosnet": "SIFT + SOSNet stand-in (TFeat architecture, weights tfeat-liberty.params; "
                   "orientation: OriNet stand-in, OriNet.pth)",
    "harrisz-hardnet2": "HarrisZ + HardNet2 stand-in (TFeat architecture, weights HardTFeat.pth; "
                        "orientation: OriNet stand-in, OriNet.pth)",
    "harrisz-sosnet": "HarrisZ + SOSNet stand-in (TFeat architecture, weights tfeat-liberty.params; "
                      "orientation: OriNet stand-in, OriNet.pth)",
}


#: The eight detector + descriptor blocks of the paper's heat map (Fig. 5), handcrafted ones first.
PAPER_FEATURE_BLOCKS = ("sift-rootsift", "sift-rootsgloh2", "harrisz-rootsift", "harrisz-rootsgloh2",
                        "sift-hardnet2", "sift-sosnet", "harrisz-hardnet2", "harrisz-sosnet")


def paper_feature_blocks(deep: bool | None = None) -> list[str]:
    """The paper's detector + descriptor blocks that can run here.

    Parameters
    ----------
    deep : bool, optional
        Include the HardNet2 / SOSNet blocks (stand-in weights, run in numpy). ``None``: when their weights
        are found (they ship with the package); ``True``: always (an error later if they cannot run);
        ``False``: never.

    Returns
    -------
    list of str
        Keys of :data:`FEATURE_PRESETS`, in the order of :data:`PAPER_FEATURE_BLOCKS`.

    Examples
    --------
    >>> paper_feature_blocks(deep=False)
    ['sift-rootsift', 'sift-rootsgloh2', 'harrisz-rootsift', 'harrisz-rootsgloh2']
    """
    handcrafted = [k for k in PAPER_FEATURE_BLOCKS if FEATURE_PRESETS[k].descriptor not in _DEEP]
    if deep is False:
        return handcrafted
    if deep is None:
        try:
            for k in PAPER_FEATURE_BLOCKS:
                FEATURE_PRESETS[k].key()  # resolves (and hashes) the weights: FileNotFoundError when missing
        except (FileNotFoundError, ValueError):
            return handcrafted
    return list(PAPER_FEATURE_BLOCKS)


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
        Descriptors (D = 128 for SIFT/RootSIFT and the deep ones, 256 for RootsGLOH2), unit L2 norm.
    scales : ndarray of shape (N,), float64
        Keypoint scale: the Gaussian sigma of the detection in image pixels.
    angles : ndarray of shape (N,), float64
        Orientation in radians in the image frame (x right, y down, so positive angles turn clockwise on
        screen); 0 for upright features.
    responses : ndarray of shape (N,), float64
        Detector response: absolute DoG value for SIFT, non-increasing along the rows; z-scored Harris
        response for HarrisZ, non-increasing within each scale (rows go from the finest scale up).
    metric : {"l2", "sgloh2"}
        How descriptors compare: Euclidean, or the sGLOH2 rotation-min distance (see
        :func:`descriptor_distance`).
    image_size : tuple of int (width, height), optional
        Size of the image the features come from, as :class:`ctxmatch_lib.datasets.Pair` stores it, ready
        for the filters' ``image_size1`` / ``image_size2``. :func:`extract_features` always fills it;
        ``None`` only for features built by hand without it.
    """

    kpts: np.ndarray
    shapes: np.ndarray
    desc: np.ndarray
    scales: np.ndarray
    angles: np.ndarray
    responses: np.ndarray
    metric: str = "l2"
    image_size: tuple[int, int] | None = None

    def __post_init__(self):
        if self.image_size is not None:
            size = tuple(self.image_size)
            if (len(size) != 2 or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                                          for v in size) or min(size) < 0):
                raise ValueError(f"image_size must be (width, height) non-negative integers, got {self.image_size!r}")
            object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))

    def __len__(self) -> int:
        return len(self.kpts)

    def distance(self):
        """The distance hook for :func:`ctxmatch_lib.blob.blob_matching` (``None`` for plain L2)."""
        return descriptor_distance(self.metric)

    @classmethod
    def empty(cls, dim: int = 128, metric: str = "l2", image_size: tuple[int, int] | None = None) -> "Features":
        """No keypoints, with the right shapes and dtypes (and the image size, when given)."""
        return cls(
            np.empty((0, 2)), np.empty((0, 2, 2)), np.empty((0, dim), np.float32),
            np.empty(0), np.empty(0), np.empty(0), metric, image_size,
        )


def descriptor_distance(metric):
    """The blob-matching distance hook of a descriptor metric.

    Parameters
    ----------
    metric : {"l2", "sgloh2"} or FeatureConfig or Features

    Returns
    -------
    callable or None
        ``None`` for the Euclidean distance (blob matching's own GEMM path); for RootsGLOH2 a
        :class:`.sgloh.SGLOH2Distance`, the minimum over the 16 discrete rotations (sGLOH2, TPAMI 2018).
    """
    if isinstance(metric, FeatureConfig):
        metric = "sgloh2" if metric.descriptor == "rootsgloh2" else "l2"
    elif isinstance(metric, Features):
        metric = metric.metric
    if metric == "l2":
        return None
    if metric == "sgloh2":
        from .sgloh import SGLOH2Distance

        return SGLOH2Distance()
    raise ValueError(f"metric must be 'l2' or 'sgloh2', got {metric!r}")


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


def _sift_detect(gray: np.ndarray, config: FeatureConfig, *, merge: bool):
    """OpenCV SIFT keypoints sorted strongest first and capped; ``merge`` folds orientation duplicates."""
    import cv2

    sift = cv2.SIFT_create(
        0, int(config.n_octave_layers), float(config.contrast_threshold), float(config.edge_threshold),
        float(config.sigma), bool(config.precise_upscale),
    )
    kps = sift.detect(gray, None)
    if not kps:
        return sift, None
    pts = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
    size = np.array([k.size for k in kps], np.float64)
    ang = np.array([k.angle for k in kps], np.float64)
    resp = np.abs(np.array([k.response for k in kps], np.float64))
    octave = np.array([k.octave for k in kps], np.int64)  # compute() reads the pyramid level from it
    if merge:
        ang = np.zeros_like(ang)
        # SIFT duplicates a blob for each secondary orientation peak; without its orientation they are one.
        _, first = np.unique(np.c_[pts, size], axis=0, return_index=True)
        keep = np.sort(first)
        pts, size, ang, resp, octave = pts[keep], size[keep], ang[keep], resp[keep], octave[keep]
    # Strongest first; ties broken by position, size and angle so the order never depends on OpenCV's.
    order = np.lexsort((ang, size, pts[:, 1], pts[:, 0], -resp))
    if config.max_keypoints:
        order = order[: int(config.max_keypoints)]
    return sift, (pts[order], size[order], ang[order], resp[order], octave[order])


def _normalise(desc: np.ndarray, root: bool) -> np.ndarray:
    desc = desc.astype(np.float64)
    if root:
        return np.sqrt(desc / np.maximum(desc.sum(1, keepdims=True), 1e-12))
    return desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)


def _image_size(gray: np.ndarray) -> tuple[int, int]:
    return int(gray.shape[1]), int(gray.shape[0])  # (width, height), as Pair.image_size1


def _extract(gray: np.ndarray, config: FeatureConfig) -> Features:
    ori = config.resolved_orientation()
    metric = "sgloh2" if config.descriptor == "rootsgloh2" else "l2"
    dim = 256 if metric == "sgloh2" else 128
    if gray.size == 0 or min(gray.shape) < 8:
        feats = Features.empty(dim, metric)
    elif config.detector == "sift" and config.descriptor in ("rootsift", "sift") and ori in ("sift", "none"):
        feats = _extract_sift(gray, config, upright=ori == "none")
    else:
        feats = _extract_patches(gray, config, ori, metric, dim)
    # Every detector path ends here: the size is set once, for empty results too.
    return replace(feats, image_size=_image_size(gray))


def _extract_sift(gray: np.ndarray, config: FeatureConfig, *, upright: bool) -> Features:
    """SIFT keypoints described by OpenCV's SIFT at their own orientation (or upright)."""
    import cv2

    sift, det = _sift_detect(gray, config, merge=upright)
    if det is None:
        return Features.empty()
    pts, size, ang, resp, octave = det
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
    desc = _normalise(desc, config.descriptor == "rootsift")
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


def _extract_patches(gray: np.ndarray, config: FeatureConfig, ori: str, metric: str, dim: int) -> Features:
    """Any detector, orientation and descriptor through affine-normalised patches."""
    from .patches import dominant_orientation, rotation_shapes, sift_from_patches

    if config.detector == "sift":
        _, det = _sift_detect(gray, config, merge=ori != "sift")
        if det is None:
            return Features.empty(dim, metric)
        pts, size, ang, resp, _ = det
        scales = size / 2.0
        angles = np.deg2rad(ang) if ori == "sift" else np.zeros(len(pts))
        angles = np.where(angles > np.pi, angles - 2 * np.pi, angles)
        base = _shapes(scales, np.zeros(len(pts)), float(config.patch_radius))
    else:
        from .harrisz import harrisz

        hz = harrisz(gray, patch_radius=float(config.patch_radius), max_keypoints=int(config.max_keypoints))
        if len(hz) == 0:
            return Features.empty(dim, metric)
        pts, scales, resp, base = hz.kpts, hz.scales, hz.responses, hz.shapes
        angles = np.zeros(len(pts))
    if ori == "dominant":
        angles = dominant_orientation(gray, pts, base, support=config.support)
    elif ori == "orinet":
        from .deep import orinet_angles

        angles = orinet_angles(gray, pts, base, weights=config.orinet_weights, support=config.support)
    shapes = rotation_shapes(base, angles)
    if config.descriptor == "rootsgloh2":
        from .sgloh import sgloh_descriptors

        desc = sgloh_descriptors(gray, pts, base, support=config.support)
    elif config.descriptor in _DEEP:
        from .deep import deep_descriptors

        desc = deep_descriptors(gray, pts, shapes, descriptor=config.descriptor, net=config.net,
                                weights=config.weights, support=config.support)
    else:
        desc = _normalise(sift_from_patches(gray, pts, shapes, support=config.support),
                          config.descriptor == "rootsift")
    return Features(
        kpts=np.ascontiguousarray(pts, dtype=np.float64),
        shapes=np.ascontiguousarray(shapes, dtype=np.float64),
        desc=np.ascontiguousarray(desc, dtype=np.float32),
        scales=np.asarray(scales, np.float64),
        angles=np.asarray(angles, np.float64),
        responses=np.asarray(resp, np.float64),
        metric=metric,
    )


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
    gray = _as_gray_uint8(image)
    return _entry_path(_image_hash(gray), config, cache_dir)


def _entry_path(digest: str, config: FeatureConfig, cache_dir) -> Path:
    if cache_dir is None:
        from .._paths import cache_dir as default_cache_dir

        base = default_cache_dir("features")
    else:
        base = Path(cache_dir)
    # SIFT's keypoints and descriptors change between OpenCV releases: the version is part of the key.
    return base / f"opencv-{_opencv_version()}" / config.key() / digest[:2] / f"{digest}.e{_ENTRY_FORMAT}.npz"


def _opencv_version() -> str:
    import cv2

    return cv2.__version__


def extract_features(image, config: FeatureConfig = FeatureConfig(), *, cache_dir=None) -> Features:
    """Detect keypoints and describe them (see :class:`FeatureConfig`), reusing the on-disk cache.

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
        image is blank or tiny. ``image_size`` is the image's (width, height).

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
    gray = _as_gray_uint8(image)
    if cache_dir is False:
        return _extract(gray, config)
    path = _entry_path(_image_hash(gray), config, cache_dir)
    if path.is_file():
        feats = _load_entry(path, _image_size(gray))
        if feats is not None:
            return feats
    feats = _extract(gray, config)
    _save_entry(path, feats)
    return feats
