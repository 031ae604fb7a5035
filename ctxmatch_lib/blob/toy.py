"""The toy example of Fig. 1a: the 7×5 matrix D and the table of candidate sets per setup."""

from __future__ import annotations

import numpy as np

__all__ = ["FIG1A_D", "FIG1A_TABLE", "toy_table"]

FIG1A_D = np.array([
    [1.6, 2.5, 1.0, 4.0, 2.3],
    [4.2, 0.5, 1.7, 3.0, 1.1],
    [5.1, 3.5, 3.1, 1.2, 2.0],
    [2.8, 0.6, 2.1, 4.1, 5.0],
    [4.4, 3.4, 2.4, 4.3, 4.5],
    [3.2, 5.5, 5.8, 6.1, 3.6],
    [1.3, 6.0, 3.7, 2.7, 1.4],
])

_MNN = [(2, 2), (1, 3), (3, 4), (7, 1)]
_F2 = [(2, 2), (4, 2), (1, 3), (2, 5), (3, 4), (7, 1), (7, 5), (1, 1), (4, 3)]

# (label as printed in the paper, f, prefilter, f', the paper's set, counting from 1). The setups
# "f' > 0" and "f > 0∪" stand for every such value; they are run at the representative values given.
# Row 6 reads "f > 0∪, f' = 1" but must mean f >= 2∪: row 4 shows that f = 1∪, f' = 1 gives S_mNN.
FIG1A_TABLE = [
    ("f=1∩, f'>0", 1, "cap", 3, _MNN),
    ("f=1∪, f'=1", 1, "cup", 1, _MNN),
    ("f≥Ω, f'=1", "omega", "cup", 1, _MNN + [(6, 5)]),
    ("f>0∪ (f≥2∪), f'=1", 2, "cup", 1, _MNN + [(6, 5)]),
    ("f=3∩, f'=1", 3, "cap", 1, _MNN),
    ("f=1∪, f'=2", 1, "cup", 2, [(2, 2), (4, 2), (1, 3), (2, 5), (3, 4), (7, 1), (5, 3), (6, 1)]),
    ("f=3∩, f'=2", 3, "cap", 2, _F2),
    ("f≥Ω, f'=2", "omega", "cup", 2, _F2 + [(5, 4)]),
    ("f=3∪, f'=2", 3, "cup", 2, _F2 + [(5, 4)]),
]


def toy_table(D: np.ndarray | None = None):
    """Recompute the table of Fig. 1a with :func:`blob_matching` (indices counted from 1 as in the paper).

    Returns
    -------
    pandas.DataFrame
        One row per setup: ``setup``, ``f``, ``prefilter``, ``f_prime``, ``computed`` (the candidate set G
        in greedy order), ``paper`` (the set printed in the paper) and ``agrees``.
    """
    import pandas as pd

    from .context import BlobContext

    D = FIG1A_D if D is None else np.asarray(D, float)
    ctx = BlobContext(distances=D, depth=max(D.shape))
    rows = []
    for label, f, prefilter, f_prime, paper in FIG1A_TABLE:
        G, _ = ctx.candidates(f, prefilter, f_prime)  # in the order the greedy accepts them
        computed = [(int(i) + 1, int(j) + 1) for i, j in G]
        rows.append(dict(setup=label, f=f, prefilter=prefilter, f_prime=f_prime, computed=computed,
                         paper=paper, agrees=set(computed) == set(paper)))
    return pd.DataFrame(rows)
