"""LLT: Locally Linear Transforming (Ma et al., IEEE TGRS 2015), non-rigid model (the authors' ``LLTV``).

The EM of VFC (:mod:`.vfc`) with a *local geometrical constraint*: the transformed points keep the locally
linear embedding weights ``W`` of their ``n_neighbors`` nearest keypoints (Sec. III-A, Eq. (5) and (7)).
``T(x) = x + v(x)``, ``v`` spanned by the Gaussian kernels of ``n_control`` control points (Sec. III-C).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..._numerics.blas import one_blas_thread
from ..._numerics.fixedmath import log
from .._common import MatchSet, knn_without_self, match_filter, zero_mean_unit_rms
from .._em_kernels import dot, solve, solve_batched, weighted_gram_t
from ._kernels import em_residuals, lle_solve, offset_norms
from ..vfc import control_points, gaussian_kernel, posterior

__all__ = ["llt_filter", "lle_weights", "m_step"]


def lle_weights(x: np.ndarray, k: int, reg: float = 1e-5) -> sp.csr_matrix:
    """Sparse (K, K) locally-linear-embedding weights of every point from its ``k`` nearest neighbours.

    Rows sum to one and minimise ``|x_i - sum_j W_ij x_j|^2`` (Roweis and Saul, Science 2000), the local
    Gram matrix regularised by ``reg`` times its trace.
    """
    n = len(x)
    nb = knn_without_self(x, np.arange(n), k)
    kk = nb.shape[1]
    if kk == 0:
        return sp.csr_matrix((n, n))
    # Compiled Gram matrices of the offsets and solve (no BLAS, whose rounding follows the CPU's kernel).
    t = reg * np.maximum(offset_norms(x, nb).sum(1), 1e-12)
    w, ok = lle_solve(x, nb, t)
    bad = np.flatnonzero(~ok)
    if len(bad):  # exactly singular: LAPACK's least squares, as solve_batched answers
        z = x[nb[bad]] - x[bad, None, :]
        gram = z[:, :, None, 0] * z[:, None, :, 0] + z[:, :, None, 1] * z[:, None, :, 1]
        gram += t[bad, None, None] * np.eye(kk)
        w[bad] = solve_batched(gram, np.ones((len(bad), kk, 1)))[..., 0]
    w /= w.sum(1, keepdims=True)
    rows = np.repeat(np.arange(n), kk)
    return sp.csr_matrix((w.ravel(), (rows, nb.ravel())), shape=(n, n))


@match_filter(label="LLT", integer=("n_neighbors", "n_control", "max_iter"), positive=("beta", "gamma", "a"),
              non_negative=("lam", "tau", "reg"))
def llt_filter(
    ms: MatchSet,
    *,
    n_neighbors: int = 15,
    lam: float = 9e9,
    beta: float = 0.1,
    tau: float = 0.75,
    gamma: float = 0.9,
    a: float = 10.0,
    n_control: int = 15,
    max_iter: int = 500,
    tol: float = 1e-5,
    min_p: float = 1e-5,
    reg: float = 1e-5,
    rng=0,
) -> np.ndarray:
    """Locally Linear Transforming, non-rigid, with the sparse kernel approximation.

    %(parameters_unused)s
    n_neighbors, reg : int, float, default 15 and 1e-5
        Neighbours (``conf.Kn``) and regulariser (times the local Gram trace) of the linear reconstruction.
    lam : float, default 9e9
        Weight of the local geometrical constraint, ``conf.lambda`` of ``LLTV.m`` (see :func:`m_step`).
    %(em_mixture)s
    n_control : int, default 15
        Control points of the sparse approximation (Sec. III-C; ``conf.M``).
    max_iter, tol : int, float, default 500 and 1e-5
        At most ``max_iter - 1`` EM iterations, or until a relative energy change of at most ``tol``.
    %(em_rng)s

    Returns
    -------
    %(keep)s

    Notes
    -----
    The paper (and Bellavia's, Sec. 5.2) leaves the variant and constants open; they follow the
    ``method = 'nonrigid'`` branch of the authors' ``demo.m`` (jiayi-ma/LLT), with its energy (Eq. (8)
    with the constraint's norm not squared) and stopping rule. Comparison: ``docs/filters.md``.

    References
    ----------
    J. Ma et al., "Robust feature matching for remote sensing image registration via locally linear
    transforming", IEEE TGRS 53(12), 2015.
    """
    if gamma >= 1:
        raise ValueError(f"gamma must lie in (0, 1), got {gamma!r}")
    rng = np.random.default_rng(rng)
    n = len(ms)
    if n == 0:
        return np.zeros(0, bool)
    with one_blas_thread():  # skinny products in a loop: threads cost more than they give
        x = zero_mean_unit_rms(ms.x)
        y = zero_mean_unit_rms(ms.y)
        target = y - x  # T(x) = x + U C, so the kernel part fits the motion
        ctrl = control_points(x, n_control, rng)
        U = gaussian_kernel(x, ctrl, beta)
        B = sp.identity(n, format="csr") - lle_weights(x, n_neighbors, reg)  # I - W
        return _em(target, U, B @ U, B @ x, lam, tau, gamma, a, max_iter, tol, min_p)


def m_step(G: np.ndarray, Z: np.ndarray, pw: np.ndarray, c: float) -> np.ndarray:
    """M-step of LLTV (Sec. III-C): the (m, 2) kernel coefficients ``C``.

    Solves ``(U' P U + c (BU)' P (BU)) C = U' P (y - x) - c (BU)' P (B x)``, ``G = [U, BU]`` (K, 2m),
    ``Z = [y - x, B x]`` (K, 4), ``P = diag(pw)``, ``c = lam sigma^2``.
    """
    m = G.shape[1] // 2
    return _m_step(_stacked(G, Z), pw, c, m)


def _stacked(G: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[U, y - x]'`` and ``[BU, Bx]'`` (each (m + 2, K), contiguous): the two operands of :func:`_m_step`."""
    m = G.shape[1] // 2
    return (np.ascontiguousarray(np.hstack([G[:, :m], Z[:, :2]]).T),
            np.ascontiguousarray(np.hstack([G[:, m:], Z[:, 2:]]).T))


def _m_step(HT, pw, c, m):
    A1 = weighted_gram_t(HT[0], pw)
    A2 = weighted_gram_t(HT[1], pw)
    lhs = A1[:m, :m] + c * A2[:m, :m]
    rhs = A1[:m, m:] - c * A2[:m, m:]
    return solve(lhs, rhs)  # exactly singular: the least-squares answer


def _em(target, U, BU, BX, lam, tau, gamma, a, max_iter, tol, min_p) -> np.ndarray:
    """The EM of LLTV (Sec. III) on normalised data, ``U`` (K, m) the kernel matrix of the control points,
    ``BU`` and ``BX`` the residuals ``(I - W) U`` and ``(I - W) x``: the posteriors thresholded at ``tau``."""
    n, m = U.shape
    G = np.ascontiguousarray(np.hstack([U, BU]))  # row i = [U_i, (BU)_i]
    Z = np.hstack([target, BX])
    HT = _stacked(G, Z)
    GT = np.ascontiguousarray(G.reshape(2 * n, m).T)  # [U, BU] as (2K, m), transposed once for em_residuals
    C = np.zeros((m, 2))
    res, loc = target, BX  # y - x - U C and (I - W)(x + U C) at C = 0
    r2 = np.einsum("ij,ij->i", res, res)
    local = np.einsum("ij,ij->i", loc, loc)
    sigma2 = float(r2.sum() / (2 * n))
    p = np.ones(n)
    energy, change = 1.0, 1.0
    # The authors' loop: `while iter < MaxIter && |change| > ecr && sigma2 > 1e-8`, iter from 1.
    for _ in range(max_iter - 1):
        if abs(change) <= tol or sigma2 <= 1e-8:
            break
        p = posterior(r2, sigma2, gamma, a)
        pw = np.maximum(p, min_p)
        # Eq. (8) as the authors' code evaluates it (see llt_filter, Notes); _fixedmath's logarithms.
        old, ps = energy, p.sum()
        energy = (dot(p, r2) / (2 * sigma2) + ps * float(log(sigma2)) - float(log(gamma)) * ps
                  - float(log(1 - gamma)) * (n - ps)
                  + lam / 2 * np.sqrt(dot(pw, local)))
        change = (energy - old) / energy if energy != 0 else 0.0
        C = _m_step(HT, pw, lam * sigma2, m)  # Sec. III-C, see m_step
        r2, local = em_residuals(GT, C, target, BX)  # |y - x - U C|^2 and |(I - W)(x + U C)|^2
        sigma2 = dot(pw, r2) / (2 * pw.sum())
        gamma = min(max(float((p > tau).mean()), 0.05), 0.95)
    return p > tau
