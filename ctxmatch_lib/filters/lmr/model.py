"""LMR's boosted-tree classifiers as flat arrays (:class:`LMRModel`): prediction in numpy, saving and loading,
and the shipped model (``ctxmatch_lib/filters/data/lmr_model.npz``)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..._numerics.fixedmath import exp, log

__all__ = ["LMRModel", "MODEL_PATH"]

MODEL_PATH = Path(__file__).resolve().parents[1] / "data" / "lmr_model.npz"


@dataclass(frozen=True)
class LMRModel:
    """The boosted-tree classifiers (stages 1 to 3, see :func:`train_lmr`) as flat arrays.

    Per stage: ``offsets`` (T + 1,) into the node arrays ``left``, ``right`` (-1 at leaves), ``feature``,
    ``threshold``, ``value``; ``init`` (prior log-odds), ``learning_rate``, ``depth``.
    """

    arrays: dict

    def proba(self, stage: int, feats: np.ndarray) -> np.ndarray:
        """Inlier probability of every row of ``feats`` under the classifier of ``stage``."""
        a = {k[2:]: v for k, v in self.arrays.items() if k.startswith(f"{stage}_")}
        X = feats.astype(np.float32)  # scikit-learn's trees split float32 features
        off = a["offsets"]
        node = np.broadcast_to(off[:-1], (len(X), len(off) - 1)).copy()
        rows = np.arange(len(X))[:, None]
        for _ in range(int(a["depth"])):
            left = a["left"][node]
            leaf = left < 0
            go_left = X[rows, np.where(leaf, 0, a["feature"][node])] <= a["threshold"][node]
            child = np.where(go_left, left, a["right"][node])
            node = np.where(leaf, node, child + off[:-1][None, :])
        raw = float(a["init"]) + float(a["learning_rate"]) * a["value"][node].sum(1)
        return 1.0 / (1.0 + exp(-raw))  # _fixedmath's: the probability meets the threshold

    def save(self, path) -> None:
        """Write the arrays as a compressed ``.npz`` (file mode from the umask)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + f".tmp{os.getpid()}.npz")
        np.savez_compressed(tmp, **self.arrays)
        os.replace(tmp, path)

    @classmethod
    def load(cls, path=MODEL_PATH) -> LMRModel:
        with np.load(path) as z:
            return cls({k: z[k] for k in z.files})


@lru_cache(maxsize=1)
def _shipped_model() -> LMRModel:
    return LMRModel.load(MODEL_PATH)


def _export(clf, stage: int) -> dict:
    """Flat arrays of a fitted binary ``GradientBoostingClassifier``."""
    trees = [est.tree_ for est in clf.estimators_[:, 0]]
    counts = np.array([t.node_count for t in trees])
    offsets = np.r_[0, np.cumsum(counts)].astype(np.int64)
    prior = float(np.clip(clf.init_.class_prior_[1], 1e-12, 1 - 1e-12))
    out = {
        "offsets": offsets,
        "left": np.concatenate([t.children_left for t in trees]).astype(np.int64),
        "right": np.concatenate([t.children_right for t in trees]).astype(np.int64),
        "feature": np.concatenate([np.maximum(t.feature, 0) for t in trees]).astype(np.int64),
        "threshold": np.concatenate([t.threshold for t in trees]).astype(np.float64),
        "value": np.concatenate([t.value.reshape(-1) for t in trees]).astype(np.float64),
        "init": np.float64(log(prior / (1 - prior))),
        "learning_rate": np.float64(clf.learning_rate),
        "depth": np.int64(max(t.max_depth for t in trees) + 1),
    }
    return {f"{stage}_{k}": v for k, v in out.items()}
