"""ctxmatch: SIFT Matching by Context Exposed (F. Bellavia, IEEE TPAMI 2022).

Blob matching (Sec. 3), Delaunay Triangulation Matching (Sec. 4, ``ctxmatch_lib.dtm.dtm``) and the evaluation
of Sec. 5; two images to filtered matches in :func:`ctxmatch_lib.match.match_images`, OpenCV / kornia glue in
:mod:`ctxmatch_lib.io.interop`, hloc / COLMAP exports in :mod:`ctxmatch_lib.io.export`. Keypoints everywhere
are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left pixel.
"""

# The one source of the version (pyproject.toml and ``ctxmatch --version`` read it).
__version__ = "0.1.0"

from .blob import BLOB_PRESETS, BlobConfig, BlobContext, BlobMatches, blob_grid, blob_matching
from .datasets import Dataset, Pair, list_datasets, load_dataset
# Only names from the subpackage: binding the function ``dtm`` here would shadow the subpackage itself
# (``import ctxmatch_lib.dtm.boundary`` would then fail).
from . import dtm
from .dtm import DTMResult, DTMTrace, dtm_boundary
from .features import FeatureConfig, Features, extract_features, load_image
from .filters import FILTERS, register_filter
from .geometry import fit_fundamental, fit_homography, one_sac, ransac
from .geometry_metrics import epipolar_consistency, geometry_table, homography_corner_error, pose_auc
from .groundtruth import label_matches
from .metrics import average_precision, evaluate_matches, mean_average_precision
from .match import MatchResult, match_images
from .pipeline import evaluate_dataset, evaluate_pair, summary_table

__all__ = [
    "BLOB_PRESETS",
    "BlobConfig",
    "BlobContext",
    "BlobMatches",
    "DTMResult",
    "DTMTrace",
    "Dataset",
    "FILTERS",
    "FeatureConfig",
    "Features",
    "Pair",
    "blob_grid",
    "blob_matching",
    "dtm",
    "dtm_boundary",
    "extract_features",
    "list_datasets",
    "load_dataset",
    "load_image",
    "register_filter",
    "average_precision",
    "evaluate_dataset",
    "evaluate_matches",
    "evaluate_pair",
    "fit_fundamental",
    "fit_homography",
    "label_matches",
    "MatchResult",
    "match_images",
    "mean_average_precision",
    "one_sac",
    "ransac",
    "homography_corner_error",
    "epipolar_consistency",
    "pose_auc",
    "geometry_table",
    "summary_table",
    "__version__",
]
