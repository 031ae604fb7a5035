"""Features: keypoints with their elliptical frames and descriptors, cached on disk.

Detectors: SIFT (OpenCV's DoG) and HarrisZ (:mod:`.harrisz`). Descriptors: RootSIFT / SIFT, RootsGLOH2
(:mod:`.sgloh`, non-oriented patches, rotation-min distance), HardNet2 and SOSNet (:mod:`.deep`, on patches
oriented by OriNet; **stand-in** TFeat-architecture weights shipped with the package, run in numpy). The paper's eight detector+descriptor
blocks of Fig. 5 are in :data:`FEATURE_PRESETS` (Sec. 5: "SIFT and HarrisZ ... RootSIFT, RootsGLOH2, HardNet2
and SOSNet").

The first stage of the evaluation pipeline of Sec. 5 (images → ``features`` → blob matching → filters).
Keypoints are ``(N, 2)`` float64 arrays of (x, y) pixels, x right, y down, with the origin at the centre of
the top-left pixel. Each keypoint also carries its elliptical patch as a 2×2 affine shape ``A``: the patch is
``{kpt + A @ u : |u| <= 1}``; for SIFT it is a disc of radius ``patch_radius * scale`` whose first axis
points along the keypoint orientation; for HarrisZ an ellipse (``A`` symmetric before orientation).
Patch descriptors sample ``2 A`` (the 6σ reach of the SIFT descriptor around a 3σ disc).

Extraction is cached per (OpenCV version, image content, extractor configuration) under
``ctxmatch_lib.cache.cache_dir("features")`` (``$CTXMATCH_CACHE/features``, else
``$XDG_CACHE_HOME/ctxmatch/features`` or ``~/.cache/ctxmatch/features``); every entry is written to a
temporary file and renamed into place, so an interrupted run never leaves a corrupt entry. Steps that
several blocks of an image share (the HarrisZ detections of the four HarrisZ blocks, the OriNet angles of
HardNet2 and SOSNet on one detector) are kept beside the entries (``shared/``, keyed by everything they
read), so a cold run computes each once per image; the features are the same either way.

The package's public face; the code lives in one module per job: :mod:`.config` (:class:`FeatureConfig`,
the presets), :mod:`.base` (:class:`Features`, :func:`descriptor_distance`), :mod:`.io` (images in),
:mod:`.sift` (SIFT), :mod:`.extract` (one extraction), :mod:`.cache` (:func:`extract_features`, the
on-disk cache); the other detectors and descriptors in :mod:`.harrisz`, :mod:`.sgloh`, :mod:`.patches`,
:mod:`.deep`.
"""

from __future__ import annotations

from .base import Features, descriptor_distance
from .cache import extract_features, feature_cache_path
from .config import (FEATURE_DESCRIPTIONS, FEATURE_PRESETS, KEYPOINT_BUDGETS, PAPER_FEATURE_BLOCKS, FeatureConfig,
                     keypoint_budget, paper_feature_blocks)
from .io import as_gray_uint8, load_image

__all__ = [
    "FeatureConfig", "Features", "extract_features", "load_image", "as_gray_uint8", "FEATURE_PRESETS", "FEATURE_DESCRIPTIONS",
    "KEYPOINT_BUDGETS", "keypoint_budget",
    "descriptor_distance", "feature_cache_path", "PAPER_FEATURE_BLOCKS", "paper_feature_blocks",
]
