"""Two-view models and the model step of the pipeline (Sec. 5.1): normalised DLT homography, normalised
8-point fundamental matrix, their errors, 1SAC (:mod:`~ctxmatch_lib.geometry.models`) and the seeded USAC
estimators (:mod:`~ctxmatch_lib.geometry.usac`).

Keypoints everywhere are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left
pixel. ``H`` maps image-1 points to image 2 (``x2 ~ H x1``); ``F`` satisfies ``x2^T F x1 = 0``.
"""

from .models import (
    CONSISTENCY_THRESHOLD_PX,
    MIN_SAMPLE,
    ModelFit,
    ModelKind,
    _dlt_design,  # noqa: F401  (the DTM and the ground truth share these kernels)
    _dlt_normal_matrix,  # noqa: F401
    _epipolar,  # noqa: F401
    _normalise,  # noqa: F401
    _transfer_errors,  # noqa: F401
    apply_homography,
    epipolar_distances,
    fit_fundamental,
    fit_homography,
    homography_transfer_errors,
    model_errors,
    normalise_points,
    one_sac,
    top_ranked_sample,
)
from .usac import (
    MODEL_STEPS,
    ROBUST_STEPS,
    USAC_PRESETS,
    UsacSettings,
    apply_model_step,
    model_kind_for,
    ransac,
    usac_settings,
)

from . import models, usac

# The package's names are its two modules' public names (and the model-kind type).
__all__ = [*usac.__all__, *models.__all__, "ModelKind"]
