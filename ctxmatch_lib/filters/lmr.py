"""LMR: a learned two-class classifier for mismatch removal (Ma, Jiang, Jiang, Zhao, Guo, IEEE TIP 2019).

:func:`lmr_filter` classifies each match from its neighbourhood's features (:func:`mpc_features`, the
authors' ``MPC.m``, or :func:`lmr_features`) by boosted trees trained on synthetic pairs (:func:`train_lmr`;
``python -m ctxmatch_lib.filters.lmr`` writes ``data/lmr_model.npz``) or by the authors' network
(:mod:`._lmr_network`). Details: ``docs/filters.md``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .._numerics.fixedmath import atan2, exp
from ._common import MatchSet, check_positive, knn_without_self, match_filter
from ._lmr_network import ANGLE_GAUSSMF, LENGTH_GAUSSMF, gaussmf, load_network, mpc_motion

__all__ = ["lmr_filter", "lmr_features", "mpc_features", "train_lmr", "LMRModel", "LMR_TRAIN_DEFAULTS",
           "MODEL_PATH", "SCALES", "MPC_SCALES"]

SCALES = (4, 8, 12, 16, 20)
#: Neighbourhood sizes of the authors' match representation (``Klist`` of their ``LMR_Test.m``).
MPC_SCALES = (2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 15, 18, 20, 25)
#: The consensus stages of the authors' ``MPC.m``: (neighbours, shared fraction a match must exceed).
MPC_CONSENSUS = ((10, 0.1), (10, 0.3), (10, 0.5))
MODEL_PATH = Path(__file__).with_name("data") / "lmr_model.npz"

#: Keyword arguments of :func:`train_lmr` that produced the shipped model.
LMR_TRAIN_DEFAULTS = dict(seed=0, n_pairs=60, max_samples_per_pair=400, n_estimators=60, max_depth=3,
                          learning_rate=0.15)


# ----------------------------------------------------------------------------------------------- features


def lmr_features(x: np.ndarray, y: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
    """The ``features="lpm"`` vectors of every match, on LPM's neighbourhoods (IJCV 2019, Eq. (13)-(14)).

    (K, 10): per scale ``k`` of :data:`SCALES`, with ``N_x``, ``N_y`` the ``k`` nearest matches of ``x_i``,
    ``y_i`` and ``v = y - x``: ``|N_x ∩ N_y| / k`` and the sum over the shared neighbours of
    ``min(|v_i|, |v_j|) / max(|v_i|, |v_j|) * cos(v_i, v_j) / k``.

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoints of each match.
    candidates : ndarray of int, optional
        Matches among which neighbours are searched (default: all).
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


def _knn_among(points: np.ndarray, among: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` nearest of the rows ``among`` to every point (itself included when it is among them)."""
    k = min(k, len(among))
    _, j = cKDTree(points[among]).query(points, k=k)
    return among[np.asarray(j).reshape(len(points), k)]


def _shared_sorted(nx: np.ndarray, ny: np.ndarray):
    """Both neighbour lists of each row sorted together, and where an index repeats (it is in both)."""
    both = np.sort(np.concatenate([nx, ny], axis=1), axis=1)
    return both[:, :-1], both[:, 1:] == both[:, :-1]


def mpc_features(x: np.ndarray, y: np.ndarray, *, exact: bool = False) -> np.ndarray:
    """The authors' match representation (``MPC.m``), ``features="mpc"``: (K, 48) in ``MPC.m``'s column order.

    After the consensus stages of :data:`MPC_CONSENSUS`: the shared fraction at each scale of
    :data:`MPC_SCALES`, then per scale the squared-length and angle consistencies with the shared
    neighbours, mapped by ``1 / (1 + u^2)`` (monotone as ``MPC.m``'s ``gaussmf``, the same bits on any CPU).

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoints of each match.
    exact : bool, default False
        ``MPC.m``'s own values (:func:`._lmr_network.mpc_motion`), for the authors' network.
    """
    n = len(x)
    feats = np.zeros((n, 3 * len(MPC_SCALES)))
    idx = np.arange(n)
    for k, frac in MPC_CONSENSUS:  # each stage counts, for every match, among the previous stage's consensus
        if len(idx) == 0:
            return feats
        _, eq = _shared_sorted(_knn_among(x, idx, k + 1), _knn_among(y, idx, k + 1))
        idx = np.flatnonzero((eq.sum(1) - 1) / k > frac)
    if len(idx) == 0:
        return feats
    if exact:
        d2, theta = mpc_motion(x, y)
    else:
        v = y - x
        d2 = v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]
        # Motion direction in [0, 2 pi), the same bits on any CPU (the trees split on the angle consistency).
        theta = atan2(v[:, 1], v[:, 0]) % (2 * np.pi)
    nx0 = _knn_among(x, idx, MPC_SCALES[-1] + 1)
    ny0 = _knn_among(y, idx, MPC_SCALES[-1] + 1)
    ns = len(MPC_SCALES)
    for s, k in enumerate(MPC_SCALES):
        kk = min(k + 1, nx0.shape[1])
        both, eq = _shared_sorted(nx0[:, :kk], ny0[:, :kk])
        # The match itself is counted out as in MPC.m (its "- 1"), also when it is not a consensus match.
        count = eq.sum(1) - 1
        feats[:, s] = np.maximum(count, 0) / k
        den = count + 1e-6
        d2_mean = ((d2[both] * eq).sum(1) - d2) / den
        th_mean = ((theta[both] * eq).sum(1) - theta) / den
        ok = count > 0
        ang = np.abs(theta - th_mean)
        ang = np.where(ang > np.pi, 2 * np.pi - ang, ang)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if exact:  # MATLAB's max ignores a NaN
                length = gaussmf(np.fmax(d2 / d2_mean, d2_mean / d2), *LENGTH_GAUSSMF)
                angle = gaussmf(ang, *ANGLE_GAUSSMF)
            else:
                r = np.maximum(d2 / d2_mean, d2_mean / d2)
                # 1 / (1 + u^2) for MPC.m's gaussmf (see the module notes); 0 where no neighbour is shared.
                length = 1.0 / (1.0 + (r - 1.0) ** 2)
                angle = 1.0 / (1.0 + ang * ang)
        feats[:, ns + 2 * s] = np.where(ok & np.isfinite(length), length, 0.0)
        feats[:, ns + 2 * s + 1] = np.where(ok, angle, 0.0)
    return feats


# ----------------------------------------------------------------------------------------------- the model


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
    from ..testing import apply_homography

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


# ----------------------------------------------------------------------------------------------- the filter


@match_filter(label="LMR", merge="merge_coincident")
def lmr_filter(
    ms: MatchSet,
    *,
    threshold: float = 0.5,
    model: LMRModel | None = None,
    features: str = "mpc",
    network: str | Path | None = None,
) -> np.ndarray:
    """LMR: classify every match from its multi-scale neighbourhood features.

    Parameters
    ----------
    %(common_unused)s
    threshold, model : float, default 0.5, and LMRModel, optional
        Inlier probability above which a match is kept; the classifiers (default: the shipped model).
    features : {"mpc", "lpm"}, default "mpc"
        :func:`mpc_features` in one pass, as the authors' code, or :func:`lmr_features` in two passes.
    network : path-like, optional
        The authors' ``Trained_Model/Net.mat`` (not shipped), classifying ``mpc_features(..., exact=True)``
        instead of ``model`` (first output above the second: inlier).
    %(merge_option)s

    Returns
    -------
    %(keep)s

    Notes
    -----
    %(coincident)s
    ``MPC.m`` counts every row, so there the copies of a wrong match are each other's shared neighbours.
    Agreement with the authors' code and with the paper's Table 2: ``docs/filters.md``.

    References
    ----------
    J. Ma et al., "LMR: learning a two-class classifier for mismatch removal", IEEE TIP 28(8), 2019.
    J. Ma et al., "Locality preserving matching", IJCV 127(5), 2019.
    """
    threshold = check_positive(threshold, "threshold", allow_zero=True)
    if features not in ("mpc", "lpm"):
        raise ValueError(f"features must be 'mpc' or 'lpm', got {features!r}")
    if network is not None:
        if features != "mpc":
            raise ValueError(f"network classifies the 'mpc' features; got features={features!r}")
        net = load_network(network, 3 * len(MPC_SCALES))
    model = _shipped_model() if model is None and network is None else model
    n = len(ms)
    if n < 2:
        return np.zeros(n, bool)
    # Rows best score first, ties by coordinates, the mask mapped back: equidistant neighbours (one image-1
    # keypoint in several candidates) are taken best first whatever the input order.
    order = np.lexsort((ms.y[:, 1], ms.y[:, 0], ms.x[:, 1], ms.x[:, 0], ms.scores))
    x, y = ms.x[order], ms.y[order]
    if network is not None:
        out = net.forward(mpc_features(x, y, exact=True))
        decided = out[:, 0] > out[:, 1]
    elif features == "mpc":
        decided = model.proba(3, mpc_features(x, y)) > threshold
    else:
        decided = model.proba(1, lmr_features(x, y)) > threshold
        if decided.sum() >= 2:
            decided = model.proba(2, lmr_features(x, y, np.flatnonzero(decided))) > threshold
    keep = np.empty(n, bool)
    keep[order] = decided
    return keep


if __name__ == "__main__":  # python -m ctxmatch_lib.filters.lmr: retrain the shipped model
    import time

    t0 = time.perf_counter()
    train_lmr(**LMR_TRAIN_DEFAULTS, path=MODEL_PATH)
    print(f"wrote {MODEL_PATH} in {time.perf_counter() - t0:.1f} s")
