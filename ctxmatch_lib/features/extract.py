"""One extraction, uncached: the detector (SIFT or HarrisZ), the orientation and the descriptor of a
:class:`~ctxmatch_lib.features.config.FeatureConfig` on gray pixels. Keypoints are ``(N, 2)`` float64 arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .base import Features
from .config import _DEEP, FeatureConfig
from .io import _image_size
from .sift import _extract_sift, _normalise, _shapes, _sift_detect

__all__: list[str] = []


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
