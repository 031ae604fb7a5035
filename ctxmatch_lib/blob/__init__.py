"""Blob matching (paper Sec. 3): descriptor-space context for candidate matches.

>>> from ctxmatch_lib.blob import blob_matching, BLOB_PRESETS
>>> # out = blob_matching(desc1, desc2, kpts1=k1, kpts2=k2, **BLOB_PRESETS["paper-best"].kwargs())
"""

from .config import BLOB_PRESETS, BlobConfig, blob_grid
from .context import BlobContext
from .core import BlobMatches, blob_matching, combine_ratios, match_context, nnr_ratio, rank_candidates
from ._workspace import free_workspace
from .overlap import ellipse_overlap_error, shapes_from_scale_angle

__all__ = [
    "BLOB_PRESETS",
    "BlobConfig",
    "BlobContext",
    "BlobMatches",
    "blob_grid",
    "blob_matching",
    "combine_ratios",
    "ellipse_overlap_error",
    "free_workspace",
    "match_context",
    "nnr_ratio",
    "rank_candidates",
    "shapes_from_scale_angle",
]
