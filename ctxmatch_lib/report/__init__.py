"""Tables and reports built from evaluation rows.

* :mod:`.tables`: the paper's tables (Tables 1-3 and the Appendix's), method labels and Markdown output; its
  names are re-exported here;
* :mod:`.blob`: the Fig. 5 heat-map tables of the blob-matching sweep;
* :mod:`.paper`: the paper's Tables 1-3 parsed from its LaTeX, side by side with ours, and the claims of
  Sec. 5.3;
* :mod:`.gt_compare`: the comparison of the ground-truth methods A-D of the Appendix.
"""

from .tables import *  # noqa: F401,F403
from .tables import __all__  # noqa: F401
