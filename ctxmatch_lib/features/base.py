"""The result of feature extraction, :class:`Features`, and how its descriptors compare."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import FeatureConfig

__all__ = ["Features", "descriptor_distance"]


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints of one image with their frames and descriptors, strongest first.

    Attributes
    ----------
    kpts : ndarray of shape (N, 2), float64
        (x, y) pixels, x right, y down, origin at the centre of the top-left pixel.
    shapes : ndarray of shape (N, 2, 2), float64
        Affine shape ``A``: the patch is ``{kpt + A @ u : |u| <= 1}``.
    desc : ndarray of shape (N, D), float32
        Unit L2 norm; D = 256 for RootsGLOH2, 128 otherwise.
    scales, angles, responses : ndarray of shape (N,), float64
        Detection sigma in pixels; orientation in radians, clockwise on screen (0 when upright); absolute DoG
        (SIFT, non-increasing) or z-scored Harris response (non-increasing within a scale).
    metric : {"l2", "sgloh2"}
        See :func:`descriptor_distance`.
    image_size : tuple of int (width, height), optional
        As :class:`ctxmatch_lib.datasets.Pair` stores it; ``None`` only for features built by hand.
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
    """The blob-matching distance hook of ``metric`` (``"l2"``, ``"sgloh2"``, a FeatureConfig or Features):
    ``None`` for the Euclidean distance, a :class:`.sgloh.SGLOH2Distance` for RootsGLOH2."""
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
