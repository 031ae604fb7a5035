"""VFC: Vector Field Consensus (Ma et al., IEEE TIP 2014), in its sparse form (SparseVFC, Sec. IV-B).

:func:`vfc_filter`: the normalised motions ``y_n - x_n`` are a smooth field ``f`` in a Gaussian RKHS plus
Gaussian noise and uniform outliers; EM alternates the posteriors ``p_n`` (Eq. (9)) and the fit of ``f``,
``sigma^2``, ``gamma`` (Eq. (14)-(16)), ``f`` spanned by the kernels of ``n_control`` control points.
"""

from __future__ import annotations

import numpy as np

from .._numerics import fixedmath as _fixedmath
from .._numerics.blas import one_blas_thread
from ._common import MatchSet, match_filter, zero_mean_unit_rms
from ._em_kernels import dot, matmul, matmul_t, solve, weighted_gram_t

__all__ = ["vfc_filter"]


def gaussian_kernel(a: np.ndarray, b: np.ndarray, beta: float) -> np.ndarray:
    """``exp(-beta * |a_i - b_j|^2)`` (len(a), len(b)) by ``_fixedmath.exp``: the same bits on any CPU."""
    d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return _fixedmath.exp(-beta * d2)


def control_points(x: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """``m`` distinct rows of ``x`` drawn at random (all of them if fewer)."""
    uniq = np.unique(x, axis=0)
    if len(uniq) <= m:
        return uniq
    return uniq[np.sort(rng.choice(len(uniq), size=m, replace=False))]


def posterior(residual2: np.ndarray, sigma2: float, gamma: float, a: float, dim: int = 2) -> np.ndarray:
    """E-step of VFC, Eq. (9): the inlier posterior of every sample, evaluated the same way on any CPU."""
    inl = _fixedmath.exp(-residual2 / (2.0 * sigma2))
    # A Python float's power (the C library's pow): exact for dim = 2, x ** 1.0 = x in any C library.
    out = float(2.0 * np.pi * sigma2) ** (dim / 2.0) * (1.0 - gamma) / (gamma * a)
    return inl / (inl + out)


@match_filter(label="VFC", positive=("beta", "gamma", "a"), non_negative=("lam", "tau"),
              integer=("n_control", "max_iter"))
def vfc_filter(
    ms: MatchSet,
    *,
    beta: float = 0.1,
    lam: float = 3.0,
    tau: float = 0.75,
    gamma: float = 0.9,
    a: float = 10.0,
    n_control: int = 16,
    max_iter: int = 500,
    tol: float = 1e-5,
    min_p: float = 1e-5,
    rng=0,
) -> np.ndarray:
    """Vector Field Consensus (SparseVFC).

    %(parameters_unused)s
    %(em_mixture)s
    lam : float, default 3
        Weight of the RKHS regulariser (Sec. V).
    n_control : int, default 16
        Control points of the sparse approximation (Sec. IV-B), as the authors' ``SparseVFC.m``.
    max_iter, tol : int, float, default 500 and 1e-5
        EM stops after ``max_iter`` iterations or when the relative energy change is at most ``tol``.
    %(em_rng)s

    Returns
    -------
    %(keep)s

    Notes
    -----
    Normalisation, constants and EM steps follow the authors' ``norm2.m``, ``VFC_init.m`` and ``SparseVFC.m``
    (jiayi-ma/VFC), with a seeded draw of the control points. Comparison: ``docs/filters.md``.

    References
    ----------
    J. Ma et al., "Robust point matching via vector field consensus", IEEE TIP 23(4), 2014.
    """
    rng = np.random.default_rng(rng)
    n = len(ms)
    if n == 0:
        return np.zeros(0, bool)
    # Rows by coordinates (x1, y1, x2, y2): the EM, which amplifies the last bits, sums in one order.
    order = np.lexsort((ms.y[:, 1], ms.y[:, 0], ms.x[:, 1], ms.x[:, 0]))
    keep = np.empty(n, bool)
    keep[order] = _vfc(ms.x[order], ms.y[order], beta, lam, tau, gamma, a, n_control, max_iter, tol, min_p, rng)
    return keep


def _vfc(x1, y1, beta, lam, tau, gamma, a, n_control, max_iter, tol, min_p, rng) -> np.ndarray:
    """The EM of :func:`vfc_filter` on the keypoints ``x1``, ``y1`` (K, 2) of the matches: the inlier mask."""
    n = len(x1)
    with one_blas_thread():  # skinny products in a loop: threads cost more than they give
        x = zero_mean_unit_rms(x1)
        motion = zero_mean_unit_rms(y1) - x
        ctrl = control_points(x, n_control, rng)
        U = gaussian_kernel(x, ctrl, beta)  # (K, M)
        G = gaussian_kernel(ctrl, ctrl, beta)  # (M, M)
        C = np.zeros((len(ctrl), 2))
        field = np.zeros_like(motion)
        sigma2 = float((motion**2).sum() / (2 * n))
        if sigma2 <= 1e-8:
            return np.ones(n, bool)  # every motion vector is the same: a perfectly consistent field
        gamma = min(max(gamma, 0.05), 0.95)
        energy, change = 1.0, 1.0
        p = np.ones(n)
        # Products and solve in _em_kernels (fixed summation order, no BLAS). One weighted Gram of
        # H = [U, motion] gives U' P U and U' P motion; the first m rows of H' give the field U C.
        m = len(ctrl)
        HT = np.ascontiguousarray(np.hstack([U, motion]).T)
        for _ in range(max_iter):
            if change <= tol or sigma2 <= 1e-8:
                break
            r2 = ((motion - field) ** 2).sum(1)
            p = posterior(r2, sigma2, gamma, a)
            # Eq. (12): the expected complete-data energy, plus the regulariser.
            old = energy
            energy = (dot(p, r2) / (2 * sigma2) + p.sum() * float(_fixedmath.log(sigma2))
                      + lam / 2 * float((C * matmul(G, C)).sum()))
            change = abs((energy - old) / energy) if energy != 0 else 0.0
            pw = np.maximum(p, min_p)
            # Sparse M-step: (U' P U + lam sigma^2 G) C = U' P motion.
            A = weighted_gram_t(HT, pw)
            C = solve(A[:m, :m] + lam * sigma2 * G, A[:m, m:])
            field = matmul_t(HT[:m], C)
            sigma2 = dot(pw, ((motion - field) ** 2).sum(1)) / (2 * pw.sum())
            gamma = min(max(float((p > tau).mean()), 0.05), 0.95)
        return p > tau
