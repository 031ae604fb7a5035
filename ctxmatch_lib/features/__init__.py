"""Features, the first stage of the pipeline of Sec. 5: keypoints, elliptical frames and descriptors.

Detectors SIFT and HarrisZ (:mod:`.harrisz`); descriptors RootSIFT / SIFT, RootsGLOH2 (:mod:`.sgloh`),
HardNet2 and SOSNet (:mod:`.deep`, stand-in weights). :data:`FEATURE_PRESETS` holds the eight blocks of
Fig. 5. A keypoint's patch is ``{kpt + A @ u : |u| <= 1}`` for its 2×2 shape ``A``; patch descriptors
sample ``2 A``. :func:`extract_features` caches per OpenCV version, image and :class:`FeatureConfig`.
"""

from __future__ import annotations

from .base import Features, descriptor_distance
from .cache import extract_features, feature_cache_path
from .config import (FEATURE_DESCRIPTIONS, FEATURE_PRESETS, KEYPOINT_BUDGETS, PAPER_FEATURE_BLOCKS, FeatureConfig,
                     keypoint_budget, paper_feature_blocks)
from .io import as_gray_uint8, load_image

__all__ = [
    "FeatureConfig", "Features", "extract_features", "load_image", "as_gray_uint8", "FEATURE_PRESETS",
    "FEATURE_DESCRIPTIONS", "KEYPOINT_BUDGETS", "keypoint_budget", "descriptor_distance", "feature_cache_path",
    "PAPER_FEATURE_BLOCKS", "paper_feature_blocks",
]
