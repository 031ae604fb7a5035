"""Delaunay Triangulation Matching (DTM), Sec. 4 of "SIFT Matching by Context Exposed" (TPAMI 2022).

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels with the origin at the centre of the top-left
pixel; image sizes are ``(width, height)``.

- :func:`dtm` runs DTM1 (contraction/expansion) and DTM2 (re-addition) and returns a :class:`DTMResult`;
  :func:`dtm_filter` is the same behind the common filter signature (``FILTERS["dtm"]``).
- :func:`dtm_boundary` builds the boundary point set of Fig. 2 / Appendix A.
- :func:`collapse_vertices` and :func:`triangulate` are the geometric kernel (rounding, Delaunay, ``A_v``).
"""

from .boundary import BOUNDARY_METHODS, AlphaShape, Boundary, alpha_shape, boundary_step, dtm_boundary, matlab_boundary_alpha
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
