"""Two-view models and the model step of the pipeline (Sec. 5.1): normalised DLT homography, normalised
8-point fundamental matrix, their errors, 1SAC (:mod:`~ctxmatch_lib.geometry.models`), the seeded USAC
estimators (:mod:`~ctxmatch_lib.geometry.usac`) and the relative pose of calibrated pairs with its error
(:mod:`~ctxmatch_lib.geometry.pose`).

Keypoints everywhere are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left
pixel. ``H`` maps image-1 points to image 2 (``x2 ~ H x1``); ``F`` satisfies ``x2^T F x1 = 0``.
"""

# The public names are listed once, in each module's ``__all__``; the star imports re-export them.
from . import models, pose, usac
from .models import *  # noqa: F403
from .models import ModelKind
from .pose import *  # noqa: F403
from .usac import *  # noqa: F403

__all__ = [*usac.__all__, *models.__all__, *pose.__all__, "ModelKind"]
