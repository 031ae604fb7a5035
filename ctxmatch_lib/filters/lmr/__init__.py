"""LMR: a learned two-class classifier for mismatch removal (Ma, Jiang, Jiang, Zhao, Guo, IEEE TIP 2019).

:func:`lmr_filter` classifies each match from its neighbourhood's features (:func:`mpc_features`, the
authors' ``MPC.m``, or :func:`lmr_features`) by boosted trees trained on synthetic pairs (:func:`train_lmr`;
``python -m ctxmatch_lib.filters.lmr`` writes ``data/lmr_model.npz``) or by the authors' network
(:mod:`._network`). Details: ``docs/filters.md``.

One module per job: :mod:`.features` (the match representations), :mod:`.model` (the classifiers as arrays),
:mod:`.training` (synthetic pairs and training), :mod:`.filter` (the filter) and :mod:`._network` (the
authors' network, read from their ``Net.mat``).
"""

from .features import MPC_CONSENSUS, MPC_SCALES, SCALES, lmr_features, mpc_features
from .filter import lmr_filter
from .model import MODEL_PATH, LMRModel
from .training import LMR_TRAIN_DEFAULTS, synthetic_pair, train_lmr

__all__ = ["lmr_filter", "lmr_features", "mpc_features", "train_lmr", "synthetic_pair", "LMRModel",
           "LMR_TRAIN_DEFAULTS", "MODEL_PATH", "SCALES", "MPC_SCALES", "MPC_CONSENSUS"]
