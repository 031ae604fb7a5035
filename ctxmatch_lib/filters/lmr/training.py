"""Training LMR's classifiers on synthetic pairs (:func:`train_lmr`, :func:`synthetic_pair`); ``python -m
ctxmatch_lib.filters.lmr`` retrains the shipped model with :data:`LMR_TRAIN_DEFAULTS`."""

from __future__ import annotations

import numpy as np

from .features import lmr_features, mpc_features
from .._common import check_positive
from .model import LMRModel, _export

__all__ = ["LMR_TRAIN_DEFAULTS", "synthetic_pair", "train_lmr"]

#: Keyword arguments of :func:`train_lmr` that produced the shipped model.
LMR_TRAIN_DEFAULTS = dict(seed=0, n_pairs=60, max_samples_per_pair=400, n_estimators=60, max_depth=3,
                          learning_rate=0.15)


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
    from ...testing import apply_homography

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
    """One synthetic training pair ``(x, y, is_inlier)`` drawn from ``rng`` (distribution: ``docs/filters.md``)."""
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
    """Train the LMR classifiers on synthetic pairs drawn from ``seed``; same seed, same model.

    Stage 3 classifies :func:`mpc_features`, stages 1 and 2 the two passes of :func:`lmr_features`.

    Parameters
    ----------
    seed : int, default 0
        Seed of the pairs, of the per-pair sample draw and of the boosting.
    n_pairs, max_samples_per_pair : int, default 60 and 400
        Synthetic pairs (:func:`synthetic_pair`); matches of each used for training.
    n_estimators, max_depth, learning_rate : int, int, float
        Gradient boosting.
    path : path-like, optional
        Where to write the model (``.npz``); ``None`` writes nothing.
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
    # The default classifier (stage 3): the authors' match representation, one pass; same pairs and draws.
    X3 = np.vstack([mpc_features(x, y)[take] for (x, y, _), take in zip(pairs, picks)])
    clf3 = _fit(X3, L, seed, n_estimators, max_depth, learning_rate)
    model = LMRModel({**model1.arrays, **_export(clf2, 2), **_export(clf3, 3)})
    if path is not None:
        model.save(path)
    return model
