"""LMR: a learned two-class classifier for mismatch removal (Ma, Jiang, Jiang, Zhao, Guo, IEEE TIP 2019).

LMR turns mismatch removal into the classification of each putative match from a *general* description of
its neighbourhood, so that one classifier trained on a few image pairs serves any other pair.

**Features** (built on the neighbourhoods of LPM, Ma et al. IJCV 2019). For every match ``i`` and every
scale ``k`` in ``SCALES = (4, 8, 12, 16, 20)``, with ``N_x`` and ``N_y`` the ``k`` nearest matches of
``x_i`` in image 1 and of ``y_i`` in image 2:

- ``n_i / k``, the fraction of shared neighbours ``n_i = |N_x ∩ N_y|`` (neighbourhood consistency);
- ``sum_j s(v_i, v_j) / k`` over the shared neighbours, with the motion similarity of LPM's Eq. (13)-(14),
  ``s = min(|v_i|, |v_j|) / max(|v_i|, |v_j|) * cos(v_i, v_j)`` (motion consistency), ``v = y - x``.

The ten numbers use only +, -, *, / and square roots (correctly rounded), so they are the same on every
machine. **Two passes**: the first classifier sees neighbours among all matches; the second, as LPM's
second iteration (IJCV 2019, Sec. 4.3), sees neighbours among the first pass's inliers, and has its own
classifier trained on such features. A match is kept when the second pass's inlier probability exceeds
``threshold`` (0.5).

**Classifier** (a choice made here: the paper treats the classifier as a replaceable component): gradient
boosted decision trees (scikit-learn's ``GradientBoostingClassifier``, 60 trees of depth 3 per pass), trained
without threads, so training is bit-for-bit repeatable, and stored as plain arrays in
``ctxmatch_lib/filters/data/lmr_model.npz`` (a few tens of kB); prediction is pure NumPy.

**Training data** (:func:`train_lmr`): synthetic pairs generated here from a seed, never evaluation data.
Each pair draws a motion (a random homography, two independently moving planar layers, or a homography
plus a smooth non-rigid warp), 300-3000 matches, an inlier ratio of 5-90 %, Gaussian keypoint noise of
0.3-2 px, keypoints uniform or clustered as on texture, and three kinds of outliers: uniform in both
images, "near misses" 15-120 px from the true position, and second matches of inlier keypoints (the
many-to-many case). The shipped model is exactly::

    python -m ctxmatch_lib.filters.lmr          # = train_lmr(seed=0), writes the shipped npz

(10-30 s on one core). The embedded image dataset is not used by default: its features come
from the OpenCV build, which would tie the model's bits to it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ._common import check_positive, knn_without_self, merge_coincident, prepare

__all__ = ["lmr_filter", "lmr_features", "train_lmr", "LMRModel", "LMR_TRAIN_DEFAULTS", "MODEL_PATH", "SCALES"]

SCALES = (4, 8, 12, 16, 20)
MODEL_PATH = Path(__file__).with_name("data") / "lmr_model.npz"

#: Keyword arguments of :func:`train_lmr` that produced the shipped model.
LMR_TRAIN_DEFAULTS = dict(seed=0, n_pairs=60, max_samples_per_pair=400, n_estimators=60, max_depth=3,
                          learning_rate=0.15)


# ----------------------------------------------------------------------------------------------- features


def lmr_features(x: np.ndarray, y: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
    """The LMR feature vectors of every match, ``(K, 2 * len(SCALES))`` float64.

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoints of each match, (x, y) pixels, origin at the centre of the top-left
        pixel.
    candidates : ndarray of int, optional
        Matches among which the neighbours are searched (default: all).

    Returns
    -------
    ndarray of shape (K, 10)
        Per scale ``k`` in :data:`SCALES`: the shared-neighbour fraction, then the summed motion
        similarity over ``k``.
    """
    n = len(x)
    cand = np.arange(n) if candidates is None else np.asarray(candidates, np.int64)
    feats = np.zeros((n, 2 * len(SCALES)))
    kmax = max(SCALES)
    nx_all = knn_without_self(x, cand, kmax)
    ny_all = knn_without_self(y, cand, kmax)
    if nx_all.shape[1] == 0:
        return feats
    v = y - x
    norm = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1])
    for s, k in enumerate(SCALES):
        kk = min(k, nx_all.shape[1])
        nx, ny = nx_all[:, :kk], ny_all[:, :kk]
        shared = (nx[:, :, None] == ny[:, None, :]).any(-1)  # (n, kk): x-neighbour also a y-neighbour
        ni, nj = norm[:, None], norm[nx]
        lo, hi = np.minimum(ni, nj), np.maximum(ni, nj)
        dot = v[:, None, 0] * v[nx, 0] + v[:, None, 1] * v[nx, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            sim = dot / (ni * nj) * (lo / hi)
        sim = np.where(hi == 0, 1.0, np.where(lo == 0, 0.0, sim))  # two null motions agree
        feats[:, 2 * s] = shared.sum(1) / k
        feats[:, 2 * s + 1] = np.where(shared, sim, 0.0).sum(1) / k
    return feats


# ----------------------------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class LMRModel:
    """Two boosted-tree classifiers (first and second pass) as flat arrays; see :meth:`proba`.

    Each pass holds ``offsets`` (T + 1,) into the node arrays ``left``, ``right`` (-1 at leaves),
    ``feature``, ``threshold`` (float64, compared with float32 features as scikit-learn does) and
    ``value`` (leaf values), plus ``init`` (prior log-odds) and ``learning_rate``.
    """

    arrays: dict

    def proba(self, stage: int, feats: np.ndarray) -> np.ndarray:
        """Inlier probability of every row of ``feats`` under the classifier of pass ``stage`` (1 or 2)."""
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
        return 1.0 / (1.0 + np.exp(-raw))

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
        "init": np.float64(np.log(prior / (1 - prior))),
        "learning_rate": np.float64(clf.learning_rate),
        "depth": np.int64(max(t.max_depth for t in trees) + 1),
    }
    return {f"{stage}_{k}": v for k, v in out.items()}


# ----------------------------------------------------------------------------------------------- training


def _random_homography(rng, w: int, h: int) -> np.ndarray:
    angle = rng.uniform(-0.6, 0.6)
    scale = np.exp(rng.uniform(-0.5, 0.5))
    shear = rng.uniform(-0.2, 0.2)
    c, s = np.cos(angle), np.sin(angle)
    A = np.array([[scale * c, -scale * s + shear, 0.0], [scale * s, scale * c, 0.0], [0.0, 0.0, 1.0]])
    P = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [rng.uniform(-4e-4, 4e-4), rng.uniform(-4e-4, 4e-4), 1.0]])
    T1 = np.array([[1.0, 0.0, -w / 2], [0.0, 1.0, -h / 2], [0.0, 0.0, 1.0]])
    t = rng.uniform(-0.15, 0.15, 2) * (w, h)
    T2 = np.array([[1.0, 0.0, w / 2 + t[0]], [0.0, 1.0, h / 2 + t[1]], [0.0, 0.0, 1.0]])
    return T2 @ P @ A @ T1


def _keypoints(rng, n: int, w: int, h: int) -> np.ndarray:
    """Uniform, or clustered as on textured regions, inside the image."""
    if rng.uniform() < 0.5:
        return rng.uniform([0, 0], [w - 1, h - 1], size=(n, 2))
    m = int(rng.integers(3, 15))
    centres = rng.uniform([0, 0], [w - 1, h - 1], size=(m, 2))
    spread = rng.uniform(15, 80, size=m)
    which = rng.integers(0, m, size=n)
    p = centres[which] + rng.normal(size=(n, 2)) * spread[which, None]
    return np.clip(p, [0, 0], [w - 1, h - 1])


def _motion(rng, w: int, h: int):
    """A random motion image 1 -> image 2: homography, two layers, or homography plus a smooth warp."""
    from ..synthetic import apply_homography

    kind = rng.integers(0, 3)
    H = _random_homography(rng, w, h)
    if kind == 0:
        return lambda p: apply_homography(H, p)
    if kind == 1:
        H2 = _random_homography(rng, w, h)
        normal = rng.normal(size=2)
        cut = rng.uniform(0.3, 0.7) * np.array([w, h])
        return lambda p: np.where(((p - cut) @ normal > 0)[:, None], apply_homography(H, p), apply_homography(H2, p))
    amp = rng.uniform(5, 30, size=2)
    freq = rng.uniform(0.5, 2.0, size=2) * 2 * np.pi / np.array([w, h])
    phase = rng.uniform(0, 2 * np.pi, size=2)

    def warp(p):
        q = apply_homography(H, p)
        return q + np.c_[amp[0] * np.sin(freq[1] * p[:, 1] + phase[0]), amp[1] * np.sin(freq[0] * p[:, 0] + phase[1])]

    return warp


def synthetic_pair(rng, size=(640, 480)):
    """One synthetic training pair: ``(x, y, is_inlier)`` with ``x, y`` of shape (K, 2).

    See the module notes for the distribution; every draw comes from ``rng``.
    """
    w, h = size
    move = _motion(rng, w, h)
    n = int(rng.integers(300, 3001))
    ratio = rng.uniform(0.05, 0.9)
    noise = rng.uniform(0.3, 2.0)
    n_in = max(int(round(n * ratio)), 3)
    # Inliers: keypoints whose image stays inside image 2.
    x_in = np.empty((0, 2))
    for _ in range(20):
        cand = _keypoints(rng, 4 * n_in, w, h)
        q = move(cand)
        ok = (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
        x_in = np.vstack([x_in, cand[ok]])
        if len(x_in) >= n_in:
            break
    x_in = x_in[:n_in]
    n_in = len(x_in)
    y_in = move(x_in) + rng.normal(scale=noise, size=x_in.shape)
    n_out = n - n_in
    kind = rng.choice(3, size=n_out, p=[0.6, 0.2, 0.2])
    x_out = _keypoints(rng, n_out, w, h)
    y_out = rng.uniform([0, 0], [w - 1, h - 1], size=(n_out, 2))
    near = kind == 1  # a near miss of the true position
    r = rng.uniform(15, 120, size=int(near.sum()))
    a = rng.uniform(0, 2 * np.pi, size=int(near.sum()))
    y_out[near] = move(x_out[near]) + np.c_[r * np.cos(a), r * np.sin(a)]
    second = (kind == 2) & (n_in > 0)  # a wrong second match of an inlier keypoint
    x_out[second] = x_in[rng.integers(0, n_in, size=int(second.sum()))]
    y_out = np.clip(y_out, [0, 0], [w - 1, h - 1])
    x = np.vstack([x_in, x_out])
    y = np.vstack([y_in, y_out])
    inl = np.r_[np.ones(n_in, bool), np.zeros(n_out, bool)]
    perm = rng.permutation(len(x))
    return x[perm], y[perm], inl[perm]


def _fit(X: np.ndarray, labels: np.ndarray, seed: int, n_estimators: int, max_depth: int, learning_rate: float):
    from sklearn.ensemble import GradientBoostingClassifier

    clf = GradientBoostingClassifier(n_estimators=n_estimators, max_depth=max_depth, learning_rate=learning_rate,
                                     subsample=1.0, random_state=seed)
    return clf.fit(X, labels)


def train_lmr(
    seed: int = 0,
    *,
    n_pairs: int = 60,
    max_samples_per_pair: int = 400,
    n_estimators: int = 60,
    max_depth: int = 3,
    learning_rate: float = 0.15,
    path=None,
) -> LMRModel:
    """Train the two LMR classifiers on synthetic pairs drawn from ``seed``; same seed, same model.

    Parameters
    ----------
    seed : int, default 0
        Seed of the synthetic pairs, of the per-pair sample draw and of the boosting.
    n_pairs : int, default 60
        Synthetic pairs (:func:`synthetic_pair`).
    max_samples_per_pair : int, default 400
        Matches drawn from each pair for training (all of a pair's matches give the features).
    n_estimators, max_depth, learning_rate : int, int, float
        Gradient boosting: 60 trees of depth 3, rate 0.15.
    path : path-like, optional
        Where to write the model (``.npz``); ``None`` writes nothing.

    Returns
    -------
    LMRModel
        The shipped model is ``train_lmr(**LMR_TRAIN_DEFAULTS)`` (see the module notes).
    """
    n_pairs = check_positive(n_pairs, "n_pairs", integer=True)
    max_samples_per_pair = check_positive(max_samples_per_pair, "max_samples_per_pair", integer=True)
    rng = np.random.default_rng(seed)
    X1, X2, L = [], [], []
    pairs = [synthetic_pair(rng) for _ in range(n_pairs)]
    picks = []
    for x, y, inl in pairs:
        take = rng.permutation(len(x))[:max_samples_per_pair]
        picks.append(take)
        X1.append(lmr_features(x, y)[take])
        L.append(inl[take])
    X1, L = np.vstack(X1), np.concatenate(L)
    clf1 = _fit(X1, L, seed, n_estimators, max_depth, learning_rate)
    model1 = LMRModel(_export(clf1, 1))
    # Second pass: neighbours among the first classifier's inliers on each pair.
    for (x, y, _), take in zip(pairs, picks):
        first = model1.proba(1, lmr_features(x, y)) > 0.5
        X2.append(lmr_features(x, y, np.flatnonzero(first))[take])
    clf2 = _fit(np.vstack(X2), L, seed, n_estimators, max_depth, learning_rate)
    model = LMRModel({**model1.arrays, **_export(clf2, 2)})
    if path is not None:
        model.save(path)
    return model


# ----------------------------------------------------------------------------------------------- the filter


def lmr_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    threshold: float = 0.5,
    model: LMRModel | None = None,
) -> np.ndarray:
    """LMR: classify every match from its multi-scale neighbourhood features, in two passes.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        Unused by LMR (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), validated only.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    threshold : float, default 0.5
        Inlier probability above which a match is kept (both passes).
    model : LMRModel, optional
        The classifiers; default: the shipped model (trained by ``train_lmr(seed=0)`` on synthetic
        pairs, see the module notes).

    Returns
    -------
    keep : ndarray of shape (K,), bool

    Notes
    -----
    Coincident candidates: rows whose keypoints coincide in both images (SIFT's orientation copies of one
    correspondence, on distinct keypoint indices, or a row the matcher repeated) are one match here. The filter
    decides the distinct matches (each with the best score of its copies) and gives every copy the decision of
    its match, so a wrong correspondence cannot support itself through its own copies and a location counts once
    in the neighbourhoods of the features. The authors' code was not found in the code index read here; this is
    our choice. The shipped model needs no retraining: its synthetic training pairs hold no coincident rows. The
    result on inputs without coincident rows is unchanged.

    References
    ----------
    J. Ma, X. Jiang, J. Jiang, J. Zhao, X. Guo, "LMR: learning a two-class classifier for mismatch
    removal", IEEE TIP 28(8), 2019.
    J. Ma, J. Zhao, J. Jiang, H. Zhou, X. Guo, "Locality preserving matching", IJCV 127(5), 2019.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = lmr_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                   image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    threshold = check_positive(threshold, "threshold", allow_zero=True)
    model = _shipped_model() if model is None else model
    merged = merge_coincident(ms)
    if merged is not None:  # coincident copies of a match are one match (see Notes)
        rows, group = merged
        keep = lmr_filter(kpts1, kpts2, ms.matches[rows], ms.scores[rows], image_size1=image_size1,
                          image_size2=image_size2, shapes1=shapes1, shapes2=shapes2,
                          threshold=threshold, model=model)
        return keep[group]
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    first = model.proba(1, lmr_features(ms.x, ms.y)) > threshold
    if first.sum() < 2:
        return first
    return model.proba(2, lmr_features(ms.x, ms.y, np.flatnonzero(first))) > threshold


if __name__ == "__main__":  # python -m ctxmatch_lib.filters.lmr: retrain the shipped model
    import time

    t0 = time.perf_counter()
    train_lmr(**LMR_TRAIN_DEFAULTS, path=MODEL_PATH)
    print(f"wrote {MODEL_PATH} in {time.perf_counter() - t0:.1f} s")
