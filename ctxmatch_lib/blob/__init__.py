"""Blob matching (Sec. 3): :func:`blob_matching` with :data:`BLOB_PRESETS`, :class:`BlobContext`, and the
FGINN-by-overlap patches (:func:`shapes_from_scale_angle`, :func:`ellipse_overlap_error`)."""

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
