"""Delaunay Triangulation Matching (DTM), Sec. 4 of "SIFT Matching by Context Exposed" (TPAMI 2022):
:func:`dtm` (DTM1 and DTM2), :func:`dtm_filter` (``FILTERS["dtm"]``), :func:`dtm_boundary` (Fig. 2,
Appendix A), :func:`collapse_vertices` and :func:`triangulate`."""

from .boundary import (BOUNDARY_METHODS, AlphaShape, Boundary, alpha_shape, boundary_step, dtm_boundary,
                       matlab_boundary_alpha)
from .core import DTM1Iteration, DTM2Level, DTMResult, DTMTrace, dtm, dtm_filter
from .triangulation import Triangulation, collapse_vertices, triangulate

__all__ = [
    "dtm",
    "dtm_filter",
    "DTMResult",
    "DTMTrace",
    "DTM1Iteration",
    "DTM2Level",
    "dtm_boundary",
    "Boundary",
    "BOUNDARY_METHODS",
    "boundary_step",
    "alpha_shape",
    "AlphaShape",
    "matlab_boundary_alpha",
    "collapse_vertices",
    "triangulate",
    "Triangulation",
]
