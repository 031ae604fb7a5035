"""Two-view models (normalised DLT ``H``, normalised 8-point ``F``), their errors and 1SAC (Sec. 5.1).

The model step fits ``H`` (planar pairs) or ``F`` (otherwise) and keeps the matches consistent with it;
1SAC fits it once on the ``3 q`` top-ranked matches (Sec. 5.1, footnote). ``x2 ~ H x1``, ``x2^T F x1 = 0``.
The error functions are shared with :mod:`ctxmatch_lib.groundtruth`, so both measure distances alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._numerics.docstrings import shared_doc
from .._numerics.validation import as_matches, as_points, as_scores, cumulative_distinct
from .pose import _fundamental_from_essential, check_intrinsics

__all__ = [
    "MIN_SAMPLE", "dlt_design", "dlt_normal_matrix", "epipolar_errors", "hartley_normalise", "transfer_errors",
    "CONSISTENCY_THRESHOLD_PX", "ModelFit", "normalise_points", "fit_homography", "fit_fundamental",
    "apply_homography", "homography_transfer_errors", "epipolar_distances", "model_errors", "top_ranked_sample",
    "one_sac",
]

ModelKind = Literal["H", "F", "E"]

#: Minimal sample size ``q`` of each model (Sec. 5.1, footnote); ``E`` is the ``essential`` step's.
MIN_SAMPLE = {"H": 4, "F": 8, "E": 5}

#: Consistency threshold of the model step in pixels: the method-D ground-truth tolerance (Sec. 5.1), so the
#: step is never stricter than the evaluation.
CONSISTENCY_THRESHOLD_PX = 15.0


@dataclass(frozen=True)
class ModelFit:
    """Result of a model step: ``keep`` (K,) the matches consistent with ``model`` (the ``kind`` named, ``None``
    on failure), ``sample`` the fitting sample (RANSAC: its inliers), ``errors`` (K,) (``inf`` without model).
    """

    keep: np.ndarray
    model: np.ndarray | None
    kind: str
    sample: np.ndarray
    errors: np.ndarray


def normalise_points(pts) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation of ``(N, 2)`` points: centroid at the origin, mean distance sqrt(2).

    Returns ``(pts_n, T)``: the normalised points and the similarity ``T`` with ``pts_n ~ T @ [x, y, 1]``.
    """
    return hartley_normalise(as_points(pts, "pts"))


# Public functions validate their arguments; the private ``_name`` versions take clean float64 arrays.


def _point_pair(pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """``pts1`` and ``pts2`` validated as corresponding ``(N, 2)`` point arrays."""
    pts1 = as_points(pts1, "pts1")
    return pts1, as_points(pts2, "pts2", n=len(pts1))


def hartley_normalise(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if len(pts) == 0:
        return pts.copy(), np.eye(3)
    c = pts.mean(axis=0)
    d = np.sqrt(((pts - c) ** 2).sum(axis=1)).mean()
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return (pts - c) * s, T


def _null_vector(A: np.ndarray, min_gap: float = 1e-9) -> np.ndarray | None:
    """Right singular vector of the smallest singular value (thin SVD), ``None`` if the null space is not 1-D."""
    _, s, vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])
    n = A.shape[1]
    # Fewer rows than unknowns pads the spectrum with zeros.
    s = np.r_[s, np.zeros(max(0, n - len(s)))]
    if s[0] <= 0 or s[n - 2] <= min_gap * s[0]:
        return None  # degenerate configuration (collinear, duplicated points...): no unique solution
    return vt[-1] if vt.shape[0] == n else None


@shared_doc
def fit_homography(pts1, pts2) -> np.ndarray | None:
    """Least-squares homography by the normalised DLT (Hartley & Zisserman, Alg. 4.2), or ``None``.

    ``H`` maps image 1 to image 2 (``H[2, 2] = 1`` when possible); ``None`` below 4 points or if degenerate.

    Parameters
    ----------
    %(pts)s

    Examples
    --------
    >>> import numpy as np
    >>> p1 = np.array([[0.0, 0.0], [10, 0], [10, 10], [0, 10]])
    >>> np.round(fit_homography(p1, p1 * 2 + 5), 6) + 0.0  # + 0.0 turns -0. into 0.
    array([[2., 0., 5.],
           [0., 2., 5.],
           [0., 0., 1.]])
    """
    return _fit_homography(*_point_pair(pts1, pts2))


def dlt_design(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """The ``(2N, 9)`` DLT design matrix of a homography from normalised points ``n1`` to ``n2``: its null
    vector is ``H`` row by row (Hartley & Zisserman, Alg. 4.2), two interleaved rows per pair."""
    x, y = n1[:, 0], n1[:, 1]
    u, v = n2[:, 0], n2[:, 1]
    z, o = np.zeros_like(x), np.ones_like(x)
    A = np.empty((2 * len(x), 9))
    A[0::2] = np.stack([-x, -y, -o, z, z, z, u * x, u * y, u], axis=1)
    A[1::2] = np.stack([z, z, z, -x, -y, -o, v * x, v * y, v], axis=1)
    return A


def dlt_normal_matrix(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """``A^T A`` of the DLT design matrix (:func:`dlt_design`) from its blocks ``sum w q q^T``.

    ``q = (x, y, 1)``, ``w`` in ``1, u, v, u^2 + v^2``; summed by ``einsum``, not BLAS, so the result does
    not depend on the thread count.
    """
    x, y = n1[:, 0], n1[:, 1]
    u, v = n2[:, 0], n2[:, 1]
    one = np.ones_like(x)
    qq = np.stack([x * x, x * y, x, y * y, y, one], axis=1)  # upper triangle of q q^T
    w = np.stack([one, u, v, u * u + v * v], axis=1)
    sums = np.einsum("kw,km->wm", w, qq)
    full = np.empty((4, 3, 3))
    iu = np.triu_indices(3)
    full[:, iu[0], iu[1]] = sums
    full[:, iu[1], iu[0]] = sums
    s1, su, sv, suv = full
    m = np.zeros((9, 9))
    m[0:3, 0:3] = m[3:6, 3:6] = s1
    m[0:3, 6:9] = m[6:9, 0:3] = -su
    m[3:6, 6:9] = m[6:9, 3:6] = -sv
    m[6:9, 6:9] = suv
    return m


def _normalised_solve(pts1: np.ndarray, pts2: np.ndarray, kind: ModelKind):
    """``(m, T1, T2)``: the 3 x 3 null vector of ``kind``'s design matrix on Hartley-normalised points and the
    similarities to undo; ``None`` below the minimal sample or for a degenerate configuration."""
    if len(pts1) < MIN_SAMPLE[kind]:
        return None
    n1, T1 = hartley_normalise(pts1)
    n2, T2 = hartley_normalise(pts2)
    m = _null_vector(dlt_design(n1, n2) if kind == "H" else _eight_point_design(n1, n2))
    return None if m is None else (m.reshape(3, 3), T1, T2)


def _fit_homography(pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray | None:
    solved = _normalised_solve(pts1, pts2, "H")
    if solved is None:
        return None
    h, T1, T2 = solved
    H = np.linalg.solve(T2, h @ T1)
    if abs(np.linalg.det(H)) < 1e-12 * float(np.abs(H).max()) ** 3:
        return None
    if abs(H[2, 2]) > 1e-12 * np.abs(H).max():
        H = H / H[2, 2]
    else:
        H = H / np.linalg.norm(H)
    return H


@shared_doc
def fit_fundamental(pts1, pts2) -> np.ndarray | None:
    """Least-squares fundamental matrix by the normalised 8-point algorithm (Hartley & Zisserman, Alg. 11.1).

    ``F`` has rank 2 and unit Frobenius norm; ``None`` below 8 points or if degenerate.

    Parameters
    ----------
    %(pts)s
    """
    return _fit_fundamental(*_point_pair(pts1, pts2))


def _eight_point_design(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """The ``(N, 9)`` 8-point design matrix from normalised points ``n1`` to ``n2``: its null vector is
    ``F`` row by row (Hartley & Zisserman, Alg. 11.1), one row ``x2^T F x1 = 0`` per pair."""
    x, y = n1[:, 0], n1[:, 1]
    u, v = n2[:, 0], n2[:, 1]
    return np.stack([u * x, u * y, u, v * x, v * y, v, x, y, np.ones_like(x)], axis=1)


def _fit_fundamental(pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray | None:
    solved = _normalised_solve(pts1, pts2, "F")
    if solved is None:
        return None
    f, T1, T2 = solved
    U, s, Vt = np.linalg.svd(f)
    F = U @ np.diag([s[0], s[1], 0.0]) @ Vt
    F = T2.T @ F @ T1
    nrm = np.linalg.norm(F)
    return F / nrm if nrm > 0 else None


def apply_homography(H, pts) -> np.ndarray:
    """Map ``(N, 2)`` (x, y) points through ``H``; points sent to infinity come back as ``inf``."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    hom = pts @ np.asarray(H, dtype=np.float64)[:, :2].T + np.asarray(H, dtype=np.float64)[:, 2]
    w = hom[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = hom[:, :2] / w
    out[~np.isfinite(out).all(axis=1) | (np.abs(w[:, 0]) < 1e-12)] = np.inf
    return out


@shared_doc
def homography_transfer_errors(H, pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection errors ``(||H x1 - x2||, ||H^-1 x2 - x1||)`` in pixels (backward ``inf`` for a singular
    ``H``) of corresponding points through ``H`` (image 1 -> image 2).

    Parameters
    ----------
    %(pts)s
    """
    return transfer_errors(np.asarray(H, dtype=np.float64), *_point_pair(pts1, pts2))


def transfer_errors(H: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fwd = np.linalg.norm(apply_homography(H, pts1) - pts2, axis=1)
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return fwd, np.full(len(pts1), np.inf)
    bwd = np.linalg.norm(apply_homography(Hinv, pts2) - pts1, axis=1)
    return fwd, bwd


@shared_doc
def epipolar_distances(F, pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-epipolar-line distances ``(d2, d1)`` under ``F`` (``x2^T F x1 = 0``): of ``x2`` from the line
    ``F x1`` and of ``x1`` from ``F^T x2``; ``inf`` for a degenerate line.

    Parameters
    ----------
    %(pts)s
    """
    return epipolar_errors(np.asarray(F, dtype=np.float64), *_point_pair(pts1, pts2))


def epipolar_errors(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    h1 = np.c_[pts1, np.ones(len(pts1))]
    h2 = np.c_[pts2, np.ones(len(pts2))]
    l2 = h1 @ F.T  # lines in image 2
    l1 = h2 @ F  # lines in image 1
    num = np.abs((h2 * l2).sum(axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = num / np.hypot(l2[:, 0], l2[:, 1])
        d1 = num / np.hypot(l1[:, 0], l1[:, 1])
    d2[~np.isfinite(d2)] = np.inf
    d1[~np.isfinite(d1)] = np.inf
    return d2, d1


def model_errors(model, kind: ModelKind, pts1, pts2, *, K1=None, K2=None) -> np.ndarray:
    """Symmetric error in pixels of each correspondence: the larger of the two directions.

    Reprojection (``H``) or epipolar distances (``F``; ``E`` through ``F = K2^-T E K1^-1``, needs ``K1``, ``K2``).
    """
    kind = _check_kind(kind, MIN_SAMPLE)
    model = np.asarray(model, np.float64)
    if kind == "E":
        model = _fundamental_from_essential(model, check_intrinsics(K1, "K1"), check_intrinsics(K2, "K2"))
        kind = "F"
    return _model_errors(model, kind, *_point_pair(pts1, pts2))


def _model_errors(model: np.ndarray, kind: ModelKind, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    a, b = transfer_errors(model, pts1, pts2) if kind == "H" else epipolar_errors(model, pts1, pts2)
    return np.maximum(a, b)


def top_ranked_sample(matches, scores=None, *, size: int) -> np.ndarray:
    """Indices of the shortest top-ranked prefix holding ``size`` matches once normalised.

    Ranked by ascending score (stable); a prefix counts ``min(#distinct image-1, #distinct image-2
    keypoints)`` as the recall of Sec. 5.1. Returns indices into ``matches``, best first (all if too few).

    Examples
    --------
    >>> top_ranked_sample([[0, 0], [0, 1], [1, 1], [2, 2]], [0.1, 0.2, 0.3, 0.4], size=2)
    array([0, 1, 2])
    """
    matches = as_matches(matches)
    return _top_ranked_sample(matches, as_scores(scores, len(matches)), size)


def _top_ranked_sample(matches: np.ndarray, scores: np.ndarray, size: int) -> np.ndarray:
    if len(matches) == 0 or size <= 0:
        return np.empty(0, np.int64)
    order = np.argsort(scores, kind="stable")
    ranked = matches[order]
    count = np.minimum(cumulative_distinct(ranked[:, 0]), cumulative_distinct(ranked[:, 1]))
    reached = np.flatnonzero(count >= size)
    stop = reached[0] + 1 if len(reached) else len(order)
    return order[:stop].astype(np.int64)


def _fit(kind: ModelKind, p1: np.ndarray, p2: np.ndarray) -> np.ndarray | None:
    return _fit_homography(p1, p2) if kind == "H" else _fit_fundamental(p1, p2)


def _check_kind(kind, kinds=("H", "F")) -> ModelKind:
    """``kind`` if among ``kinds``: 1SAC and :func:`~ctxmatch_lib.geometry.ransac` fit ``H`` and ``F`` only."""
    if kind not in kinds:
        raise ValueError(f"kind must be {' or '.join(map(repr, kinds))}, got {kind!r}")
    return kind


def _too_few_distinct(matches: np.ndarray, q: int) -> bool:
    """Fewer than ``q`` distinct keypoints on one side of ``matches``: no model of sample size ``q`` fits."""
    return min(len(np.unique(matches[:, 0])), len(np.unique(matches[:, 1]))) < q


def _failed(k: int, kind: str, sample=None) -> ModelFit:
    sample = np.empty(0, np.int64) if sample is None else sample
    return ModelFit(np.zeros(k, bool), None, kind, sample, np.full(k, np.inf))


@shared_doc
def one_sac(kpts1, kpts2, matches, scores=None, *, kind: ModelKind = "H", threshold: float = CONSISTENCY_THRESHOLD_PX,
            sample_factor: int = 3) -> ModelFit:
    """1SAC: fit one model on the top-ranked matches and keep those consistent with it (Sec. 5.1).

    Fits on :func:`top_ranked_sample` of ``sample_factor * q`` matches; keeps those whose
    :func:`model_errors` is at most ``threshold`` pixels (none for a too small or degenerate sample).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    %(scores)s
    kind : {"H", "F"}
    threshold, sample_factor : float, int
        Consistency threshold in pixels; sample size factor (3 in the paper).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> p1 = rng.uniform(0, 100, (20, 2))
    >>> m = np.c_[np.arange(20), np.arange(20)]
    >>> fit = one_sac(p1, p1 + [5.0, -3.0], m, kind="H")
    >>> int(fit.keep.sum()), len(fit.sample)
    (20, 12)
    """
    kind, kpts1, kpts2, matches, scores = _check_step(kind, kpts1, kpts2, matches, scores, threshold)
    return _one_sac(kpts1, kpts2, matches, scores, kind, threshold, sample_factor)


def _check_step(kind, kpts1, kpts2, matches, scores, threshold):
    """The arguments of a model step, validated once."""
    kind = _check_kind(kind)
    kpts1 = as_points(kpts1, "kpts1")
    kpts2 = as_points(kpts2, "kpts2")
    matches = as_matches(matches, len(kpts1), len(kpts2))
    scores = as_scores(scores, len(matches))
    if not (np.isscalar(threshold) and np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a positive number of pixels, got {threshold!r}")
    return kind, kpts1, kpts2, matches, scores


def _one_sac(kpts1, kpts2, matches, scores, kind, threshold, sample_factor=3) -> ModelFit:
    q = MIN_SAMPLE[kind]
    k = len(matches)
    sample = _top_ranked_sample(matches, scores, sample_factor * q)
    if len(sample) == 0:
        return _failed(k, kind)
    s = matches[sample]
    if _too_few_distinct(s, q):
        return _failed(k, kind, sample)
    model = _fit(kind, kpts1[s[:, 0]], kpts2[s[:, 1]])
    if model is None:
        return _failed(k, kind, sample)
    err = _model_errors(model, kind, kpts1[matches[:, 0]], kpts2[matches[:, 1]])
    return ModelFit(err <= threshold, model, kind, sample, err)
