"""Two-view models and the model step (Sec. 5.1): ``H``, ``F``, their errors and 1SAC (:mod:`.models`), the
seeded USAC steps (:mod:`.usac`), the relative pose of calibrated pairs and its error (:mod:`.pose`), and
PoseLib's steps (:mod:`.poselib_steps`)."""

# The public names are listed once, in each module's ``__all__``; the star imports re-export them.
from . import models, pose, poselib_steps, usac
from .models import *  # noqa: F403
from .models import ModelKind
from .pose import *  # noqa: F403
from .poselib_steps import *  # noqa: F403
from .usac import *  # noqa: F403

__all__ = [*usac.__all__, *models.__all__, *pose.__all__, *poselib_steps.__all__, "ModelKind"]
