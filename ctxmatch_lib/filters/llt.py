"""LLT: Locally Linear Transforming (Ma et al., IEEE TGRS 2015), non-rigid model.

Like VFC, LLT is an EM on a Gaussian-inlier / uniform-outlier mixture, with posteriors ``p_n`` for every
match, but the transformation is regularised by a *local geometrical constraint*: each keypoint ``x_i`` is
reconstructed from its ``n_neighbors`` nearest keypoints with locally linear embedding weights ``W`` (Sec.
III-A, Eq. (5)), and the transformed points must keep those weights,
``sum_i p_i |T(x_i) - sum_j W_ij T(x_j)|^2`` (Eq. (7)), weighted by ``lam``.

The non-rigid transformation is ``T(x) = x + v(x)`` with ``v`` in a Gaussian RKHS (Sec. III-C), under the
sparse approximation of the paper (``v`` spanned by the kernels of ``n_control`` control points), so the
M-step is an ``n_control x n_control`` linear system and memory stays O(K): the locality term only adds a
sparse ``(I - W)`` product. Coordinates are normalised to zero mean and unit RMS norm, as in VFC.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ._common import check_positive, knn_without_self, zero_mean_unit_rms, prepare, serial_blas
from .vfc import control_points, gaussian_kernel, posterior

__all__ = ["llt_filter", "lle_weights"]


def lle_weights(x: np.ndarray, k: int, reg: float = 1e-3) -> sp.csr_matrix:
    """Sparse (K, K) locally-linear-embedding weights of every point from its ``k`` nearest neighbours.

    Each row sums to one and minimises ``|x_i - sum_j W_ij x_j|^2`` (Roweis and Saul, Science 2000); the
    local Gram matrix is regularised by ``reg`` times its trace because ``k`` exceeds the dimension 2.
    """
    n = len(x)
    nb = knn_without_self(x, np.arange(n), k)
    kk = nb.shape[1]
    if kk == 0:
        return sp.csr_matrix((n, n))
    z = x[nb] - x[:, None, :]  # (n, kk, 2)
    gram = z @ z.transpose(0, 2, 1)
    trace = np.trace(gram, axis1=1, axis2=2)
    gram += (reg * np.maximum(trace, 1e-12))[:, None, None] * np.eye(kk)
    w = np.linalg.solve(gram, np.ones((n, kk, 1)))[..., 0]
    w /= w.sum(1, keepdims=True)
    rows = np.repeat(np.arange(n), kk)
    return sp.csr_matrix((w.ravel(), (rows, nb.ravel())), shape=(n, n))


def llt_filter(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    image_size1,
    image_size2,
    shapes1=None,
    shapes2=None,
    n_neighbors: int = 15,
    lam: float = 1000.0,
    beta: float = 0.1,
    tau: float = 0.75,
    gamma: float = 0.9,
    a: float = 10.0,
    n_control: int = 15,
    max_iter: int = 500,
    tol: float = 1e-5,
    min_p: float = 1e-5,
    rng=0,
) -> np.ndarray:
    """Locally Linear Transforming, non-rigid, with the sparse kernel approximation.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2``; many-to-many allowed.
    scores : ndarray of shape (K,) or None
        Unused by LLT (validated only).
    image_size1, image_size2 : (int, int)
        Image sizes (width, height), validated only.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    n_neighbors : int, default 15
        Neighbours of the locally linear reconstruction (Sec. IV-A).
    lam : float, default 1000
        Weight of the local geometrical constraint (Sec. IV-A).
    beta : float, default 0.1
        Width of the Gaussian kernel on normalised coordinates (Sec. IV-A).
    tau : float, default 0.75
        Posterior threshold for an inlier and for the inlier-fraction update, as in VFC (same EM). With
        0.5 the EM settled on the all-inlier solution in 4 of 10 planted-outlier cases.
    gamma, a : float, default 0.9 and 10
        Initial inlier fraction and outlier-distribution volume of the mixture (as VFC, Sec. IV-A).
    n_control : int, default 15
        Control points of the sparse approximation (Sec. III-C).
    max_iter, tol, min_p : int, float, float
        EM stopping rule (500 iterations or relative energy change below 1e-5) and posterior floor, as
        in VFC.
    rng : None, int or numpy.random.Generator, default 0
        Seed of the control-point draw; the fixed default makes the result deterministic.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    J. Ma, H. Zhou, J. Zhao, Y. Gao, J. Jiang, J. Tian, "Robust feature matching for remote sensing image
    registration via locally linear transforming", IEEE TGRS 53(12), 2015.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
    >>> y = g + (7.0, -3.0)
    >>> y[0] = (300.0, 200.0)  # one outlier
    >>> keep = llt_filter(g, y, np.c_[np.arange(64), np.arange(64)], image_size1=(400, 300),
    ...                   image_size2=(400, 300))
    >>> bool(keep[0]), int(keep[1:].sum())
    (False, 63)
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    n_neighbors = check_positive(n_neighbors, "n_neighbors", integer=True)
    lam = check_positive(lam, "lam", allow_zero=True)
    beta, a, gamma = check_positive(beta, "beta"), check_positive(a, "a"), check_positive(gamma, "gamma")
    tau = check_positive(tau, "tau", allow_zero=True)
    n_control = check_positive(n_control, "n_control", integer=True)
    max_iter = check_positive(max_iter, "max_iter", integer=True)
    rng = np.random.default_rng(rng)
    n = len(ms)
    if n == 0:
        return np.zeros(0, bool)
    with serial_blas():  # skinny products in a loop: threads cost more than they give
        x = zero_mean_unit_rms(ms.x)
        y = zero_mean_unit_rms(ms.y)
        target = y - x  # T(x) = x + U C, so the kernel part fits the motion
        ctrl = control_points(x, n_control, rng)
        U = gaussian_kernel(x, ctrl, beta)
        B = sp.identity(n, format="csr") - lle_weights(x, n_neighbors)  # I - W
        BU, BX = B @ U, B @ x
        C = np.zeros((len(ctrl), 2))
        field = np.zeros_like(target)
        sigma2 = float((target**2).sum() / (2 * n))
        if sigma2 <= 1e-8:
            return np.ones(n, bool)
        gamma = min(max(gamma, 0.05), 0.95)
        energy, change = 1.0, 1.0
        p = np.ones(n)
        ridge = 1e-8 * np.eye(len(ctrl))
        for _ in range(max_iter):
            if change <= tol or sigma2 <= 1e-8:
                break
            r2 = ((target - field) ** 2).sum(1)
            p = posterior(r2, sigma2, gamma, a)
            local = ((BX + BU @ C) ** 2).sum(1)
            # Eq. (8): expected complete-data energy with the local geometrical constraint.
            old = energy
            energy = p @ r2 / (2 * sigma2) + p.sum() * np.log(sigma2) + lam * (p @ local)
            change = abs((energy - old) / energy) if energy != 0 else 0.0
            pw = np.maximum(p, min_p)
            # M-step for C (Sec. III-C), multiplied through by sigma^2:
            # (U' P U + 2 lam sigma^2 (BU)' P (BU)) C = U' P (y - x) - 2 lam sigma^2 (BU)' P (B x).
            lhs = U.T @ (pw[:, None] * U) + 2 * lam * sigma2 * BU.T @ (pw[:, None] * BU) + ridge
            rhs = U.T @ (pw[:, None] * target) - 2 * lam * sigma2 * BU.T @ (pw[:, None] * BX)
            C = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
            field = U @ C
            sigma2 = float(pw @ ((target - field) ** 2).sum(1) / (2 * pw.sum()))
            gamma = min(max(float((p > tau).mean()), 0.05), 0.95)
        return p > tau
