"""``python -m ctxmatch_lib.filters.lmr``: retrain the shipped LMR model."""

import time

from .model import MODEL_PATH
from .training import LMR_TRAIN_DEFAULTS, train_lmr

t0 = time.perf_counter()
train_lmr(**LMR_TRAIN_DEFAULTS, path=MODEL_PATH)
print(f"wrote {MODEL_PATH} in {time.perf_counter() - t0:.1f} s")
