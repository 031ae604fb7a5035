"""LMR's match representations: the authors' multi-scale consensus features (``MPC.m``, :func:`mpc_features`)
and LPM's neighbourhood features (:func:`lmr_features`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..._numerics.fixedmath import atan2
from .._common import knn_without_self
from ._network import ANGLE_GAUSSMF, LENGTH_GAUSSMF, gaussmf, mpc_motion

__all__ = ["SCALES", "MPC_SCALES", "MPC_CONSENSUS", "lmr_features", "mpc_features"]

#: Neighbourhood sizes of the ``features="lpm"`` representation.
SCALES = (4, 8, 12, 16, 20)
#: Neighbourhood sizes of the authors' match representation (``Klist`` of their ``LMR_Test.m``).
MPC_SCALES = (2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 15, 18, 20, 25)
#: The consensus stages of the authors' ``MPC.m``: (neighbours, shared fraction a match must exceed).
MPC_CONSENSUS = ((10, 0.1), (10, 0.3), (10, 0.5))


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
        ``MPC.m``'s own values (:func:`._network.mpc_motion`), for the authors' network.
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
