"""Tables and reports built from evaluation rows: :mod:`.tables` (Tables 1-3, re-exported here),
:mod:`.blob` (Fig. 5), :mod:`.paper` (the paper's tables and Sec. 5.3's claims), :mod:`.gt_compare`
(ground-truth methods A-D)."""

from .tables import *  # noqa: F401,F403
from .tables import __all__  # noqa: F401
