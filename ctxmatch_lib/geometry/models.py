"""Two-view models: normalised DLT homography, normalised 8-point fundamental matrix, their errors and 1SAC.

The model step of the pipeline (Sec. 5.1): after the spatial filter, a global model -- a homography
``H`` for planar pairs, a fundamental matrix ``F`` otherwise -- is fitted and only the matches consistent
with it are kept. 1SAC (one SAmple Consensus, Sec. 5.1 and its footnote) fits the model once, on the
``3 q`` top-ranked matches (``q = 4`` for ``H``, ``q = 8`` for ``F``); the seeded robust alternatives
(OpenCV's USAC) live in :mod:`~ctxmatch_lib.geometry.usac`.

Keypoints everywhere are ``(N, 2)`` float arrays of (x, y) pixels, origin at the centre of the top-left
pixel. ``H`` maps image-1 points to image 2 (``x2 ~ H x1``); ``F`` satisfies ``x2^T F x1 = 0``.

The error functions here (:func:`homography_transfer_errors`, :func:`epipolar_distances`) are shared with
:mod:`ctxmatch_lib.groundtruth`, so the model step and the ground truth measure distances the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._validation import as_matches, as_points, as_scores, cumulative_distinct
from .pose import _fundamental_from_essential, check_intrinsics

__all__ = [
    "MIN_SAMPLE",
    "CONSISTENCY_THRESHOLD_PX",
    "ModelFit",
    "normalise_points",
    "fit_homography",
    "fit_fundamental",
    "apply_homography",
    "homography_transfer_errors",
    "epipolar_distances",
    "model_errors",
    "top_ranked_sample",
    "one_sac",
]

ModelKind = Literal["H", "F", "E"]

#: Minimal sample size ``q`` of each model (Sec. 5.1, footnote); ``E`` (the five-point solver of the ``essential``
#: model step, which 1SAC and :func:`~ctxmatch_lib.geometry.ransac` do not fit) needs five.
MIN_SAMPLE = {"H": 4, "F": 8, "E": 5}

#: Default consistency threshold of the model step, in pixels. It equals the method-D ground-truth
#: tolerance (15 px, Sec. 5.1): a correct model then keeps what the ground truth would call correct, so
#: the model step removes outliers without being stricter than the evaluation itself.
CONSISTENCY_THRESHOLD_PX = 15.0


@dataclass(frozen=True)
class ModelFit:
    """Result of a model step.

    Attributes
    ----------
    keep : ndarray of shape (K,), bool
        Matches consistent with the model (all ``False`` when no model could be fitted).
    model : ndarray of shape (3, 3) or None
        The fitted ``H`` (image 1 -> image 2), ``F`` (``x2^T F x1 = 0``) or ``E`` (``x2n^T E x1n = 0`` on
        points normalised by the intrinsics; the ``essential`` step); ``None`` on failure.
    kind : {"H", "F", "E"}
        Which model was fitted.
    sample : ndarray of shape (S,), int64
        Indices (into the matches given) of the sample the model was fitted on; for RANSAC, its inliers.
    errors : ndarray of shape (K,)
        Per-match error against the model (``inf`` when there is no model).
    """

    keep: np.ndarray
    model: np.ndarray | None
    kind: str
    sample: np.ndarray
    errors: np.ndarray


# --------------------------------------------------------------------------------------------- fitting


def normalise_points(pts) -> tuple[np.ndarray, np.ndarray]:
    """Hartley normalisation: centroid at the origin, mean distance sqrt(2).

    Parameters
    ----------
    pts : array_like of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.

    Returns
    -------
    pts_n : ndarray of shape (N, 2)
        Normalised points, ``pts_n ~ T @ [x, y, 1]``.
    T : ndarray of shape (3, 3)
        The similarity that normalises.
    """
    return _normalise(as_points(pts, "pts"))


# Public functions validate their arguments once; the private ``_name`` versions they call (and that call
# each other inside 1SAC, RANSAC and the pipeline) take clean float64 arrays and skip the checks.


def _point_pair(pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """``pts1`` and ``pts2`` validated as corresponding ``(N, 2)`` point arrays."""
    pts1 = as_points(pts1, "pts1")
    return pts1, as_points(pts2, "pts2", n=len(pts1))


def _normalise(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if len(pts) == 0:
        return pts.copy(), np.eye(3)
    c = pts.mean(axis=0)
    d = np.sqrt(((pts - c) ** 2).sum(axis=1)).mean()
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    T = np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    return (pts - c) * s, T


def _null_vector(A: np.ndarray, min_gap: float = 1e-9) -> np.ndarray | None:
    """Right singular vector of the smallest singular value, or ``None`` if the null space is not 1-D.

    The thin SVD of the ``(M, n)`` design matrix costs ``O(M n^2)`` time and ``O(M n)`` memory; the full
    SVD would also build the ``(M, M)`` left factor (12.8 GB for 20 000 correspondences).
    """
    _, s, vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])
    n = A.shape[1]
    # Fewer rows than unknowns pads the spectrum with zeros.
    s = np.r_[s, np.zeros(max(0, n - len(s)))]
    if s[0] <= 0 or s[n - 2] <= min_gap * s[0]:
        return None  # degenerate configuration (collinear, duplicated points...): no unique solution
    return vt[-1] if vt.shape[0] == n else None


def fit_homography(pts1, pts2) -> np.ndarray | None:
    """Least-squares homography by the normalised DLT (Hartley & Zisserman, Alg. 4.2).

    Parameters
    ----------
    pts1, pts2 : array_like of shape (N, 2), N >= 4
        Corresponding (x, y) pixels (origin at the centre of the top-left pixel) in images 1 and 2.

    Returns
    -------
    H : ndarray of shape (3, 3) or None
        Maps image 1 to image 2, scaled so that ``H[2, 2] = 1`` when possible; ``None`` for fewer than 4
        points or a degenerate configuration (e.g. three or more collinear points leaving no unique
        solution).

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


def _dlt_design(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """The ``(2N, 9)`` DLT design matrix of a homography from normalised points ``n1`` to ``n2``: its null
    vector is ``H`` row by row (Hartley & Zisserman, Alg. 4.2), two interleaved rows per pair."""
    x, y = n1[:, 0], n1[:, 1]
    u, v = n2[:, 0], n2[:, 1]
    z, o = np.zeros_like(x), np.ones_like(x)
    A = np.empty((2 * len(x), 9))
    A[0::2] = np.stack([-x, -y, -o, z, z, z, u * x, u * y, u], axis=1)
    A[1::2] = np.stack([z, z, z, -x, -y, -o, v * x, v * y, v], axis=1)
    return A


def _dlt_normal_matrix(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """``A^T A`` of the DLT design matrix ``A`` (:func:`_dlt_design`), from its block structure.

    With ``q = (x, y, 1)`` the two rows of a pair are ``(-q, 0, u q)`` and ``(0, -q, v q)``, so the 9 x 9
    matrix is made of the sums ``S_w = sum w q q^T`` for ``w`` in ``1, u, v, u^2 + v^2``: 24 sums over the
    pairs instead of 81 over twice as many rows. They are summed without BLAS (``einsum``), so the result
    does not depend on the thread count.
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
    """The null vector of ``kind``'s design matrix built on Hartley-normalised points, as a 3 x 3 matrix in
    normalised coordinates, with the two normalising similarities ``T1`` and ``T2`` to undo; ``None`` for
    fewer points than the minimal sample or a degenerate configuration."""
    if len(pts1) < MIN_SAMPLE[kind]:
        return None
    n1, T1 = _normalise(pts1)
    n2, T2 = _normalise(pts2)
    m = _null_vector(_dlt_design(n1, n2) if kind == "H" else _eight_point_design(n1, n2))
    return None if m is None else (m.reshape(3, 3), T1, T2)


def _fit_homography(pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray | None:
    solved = _normalised_solve(pts1, pts2, "H")
    if solved is None:
        return None
    h, T1, T2 = solved
    H = np.linalg.solve(T2, h @ T1)
    if abs(np.linalg.det(H)) < 1e-12 * np.abs(H).max() ** 3:
        return None
    if abs(H[2, 2]) > 1e-12 * np.abs(H).max():
        H = H / H[2, 2]
    else:
        H = H / np.linalg.norm(H)
    return H


def fit_fundamental(pts1, pts2) -> np.ndarray | None:
    """Least-squares fundamental matrix by the normalised 8-point algorithm with rank-2 enforcement.

    Parameters
    ----------
    pts1, pts2 : array_like of shape (N, 2), N >= 8
        Corresponding (x, y) pixels (origin at the centre of the top-left pixel) in images 1 and 2.

    Returns
    -------
    F : ndarray of shape (3, 3) or None
        Rank-2 matrix with ``x2^T F x1 = 0``, unit Frobenius norm; ``None`` for fewer than 8 points or a
        degenerate configuration.
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


# ---------------------------------------------------------------------------------------------- errors


def apply_homography(H, pts) -> np.ndarray:
    """Map ``(N, 2)`` (x, y) points through ``H``; points sent to infinity come back as ``inf``."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    hom = pts @ np.asarray(H, dtype=np.float64)[:, :2].T + np.asarray(H, dtype=np.float64)[:, 2]
    w = hom[:, 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = hom[:, :2] / w
    out[~np.isfinite(out).all(axis=1) | (np.abs(w[:, 0]) < 1e-12)] = np.inf
    return out


def homography_transfer_errors(H, pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """Reprojection errors of corresponding points in both directions.

    Parameters
    ----------
    H : array_like of shape (3, 3)
        Image 1 -> image 2.
    pts1, pts2 : array_like of shape (N, 2)
        Corresponding (x, y) pixels, origin at the centre of the top-left pixel.

    Returns
    -------
    forward : ndarray of shape (N,)
        ``||H x1 - x2||`` in image-2 pixels.
    backward : ndarray of shape (N,)
        ``||H^-1 x2 - x1||`` in image-1 pixels (``inf`` everywhere when ``H`` is singular).
    """
    return _transfer_errors(np.asarray(H, dtype=np.float64), *_point_pair(pts1, pts2))


def _transfer_errors(H: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fwd = np.linalg.norm(apply_homography(H, pts1) - pts2, axis=1)
    try:
        Hinv = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return fwd, np.full(len(pts1), np.inf)
    bwd = np.linalg.norm(apply_homography(Hinv, pts2) - pts1, axis=1)
    return fwd, bwd


def epipolar_distances(F, pts1, pts2) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-epipolar-line distances in both images.

    Parameters
    ----------
    F : array_like of shape (3, 3)
        Fundamental matrix with ``x2^T F x1 = 0``.
    pts1, pts2 : array_like of shape (N, 2)
        Corresponding (x, y) pixels, origin at the centre of the top-left pixel.

    Returns
    -------
    d2 : ndarray of shape (N,)
        Distance in image 2 of ``x2`` from the epipolar line ``F x1``.
    d1 : ndarray of shape (N,)
        Distance in image 1 of ``x1`` from the epipolar line ``F^T x2``.
        A degenerate line (``x`` at an epipole) gives ``inf``.
    """
    return _epipolar(np.asarray(F, dtype=np.float64), *_point_pair(pts1, pts2))


def _epipolar(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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
    """Symmetric error of each correspondence against ``model``: the larger of the two directions.

    For ``kind="H"`` the larger of the forward and backward reprojection errors, for ``kind="F"`` the larger
    of the two point-to-epipolar-line distances, in pixels; for ``kind="E"`` the same distances to
    ``F = K2^-T E K1^-1``, so an essential matrix is judged in pixels like a fundamental one (``K1`` and ``K2``,
    the intrinsics of images 1 and 2, are required then and ignored otherwise).
    """
    kind = _check_kind(kind, MIN_SAMPLE)
    model = np.asarray(model, np.float64)
    if kind == "E":
        model = _fundamental_from_essential(model, check_intrinsics(K1, "K1"), check_intrinsics(K2, "K2"))
        kind = "F"
    return _model_errors(model, kind, *_point_pair(pts1, pts2))


def _model_errors(model: np.ndarray, kind: ModelKind, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    a, b = _transfer_errors(model, pts1, pts2) if kind == "H" else _epipolar(model, pts1, pts2)
    return np.maximum(a, b)


# -------------------------------------------------------------------------------------------- sampling


def top_ranked_sample(matches, scores=None, *, size: int) -> np.ndarray:
    """Indices of the shortest top-ranked prefix holding ``size`` matches once normalised.

    Matches are ranked by ascending score (stable: ties keep their given order). A prefix is counted
    like the recall of Sec. 5.1, as ``min(#distinct image-1 keypoints, #distinct image-2 keypoints)``,
    so many-to-many duplicates of a keypoint count once; the sample is the shortest prefix whose count
    reaches ``size`` (or every match when the whole set counts less).

    Parameters
    ----------
    matches : array_like of shape (K, 2), int
        Indices into the keypoints of images 1 and 2.
    scores : array_like of shape (K,), optional
        Lower is better; ``None`` keeps the given order.
    size : int
        Normalised sample size, ``3 q`` for 1SAC.

    Returns
    -------
    ndarray of shape (S,), int64
        Indices into ``matches``, best first.

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


# ---------------------------------------------------------------------------------------- model steps


def _fit(kind: ModelKind, p1: np.ndarray, p2: np.ndarray) -> np.ndarray | None:
    return _fit_homography(p1, p2) if kind == "H" else _fit_fundamental(p1, p2)


def _check_kind(kind, kinds=("H", "F")) -> ModelKind:
    """``kind`` if among ``kinds``: 1SAC and :func:`~ctxmatch_lib.geometry.ransac` fit ``H`` and ``F`` only."""
    if kind not in kinds:
        raise ValueError(f"kind must be {' or '.join(map(repr, kinds))}, got {kind!r}")
    return kind


def _failed(k: int, kind: str, sample=None) -> ModelFit:
    sample = np.empty(0, np.int64) if sample is None else sample
    return ModelFit(np.zeros(k, bool), None, kind, sample, np.full(k, np.inf))


def one_sac(
    kpts1,
    kpts2,
    matches,
    scores=None,
    *,
    kind: ModelKind = "H",
    threshold: float = CONSISTENCY_THRESHOLD_PX,
    sample_factor: int = 3,
) -> ModelFit:
    """1SAC: fit one model on the top-ranked matches and keep those consistent with it (Sec. 5.1).

    The sample is the shortest top-ranked prefix counting ``sample_factor * q`` matches with the
    normalisation of the recall (see :func:`top_ranked_sample`); ``q = 4`` for ``H`` (normalised DLT) and
    ``q = 8`` for ``F`` (normalised 8-point). Every match whose :func:`model_errors` is at most
    ``threshold`` pixels is kept. With fewer than ``q`` normalised matches, or a degenerate sample, no model
    exists and nothing is kept.

    Parameters
    ----------
    kpts1, kpts2 : array_like of shape (N1, 2), (N2, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.
    matches : array_like of shape (K, 2), int
        Indices into ``kpts1`` and ``kpts2`` (many-to-many allowed).
    scores : array_like of shape (K,), optional
        Lower is better; ``None`` uses the given order as the ranking.
    kind : {"H", "F"}
        Homography (planar pairs) or fundamental matrix (non-planar and depth pairs).
    threshold : float
        Consistency threshold in pixels (default: 15, the method-D ground-truth tolerance).
    sample_factor : int
        The sample holds ``sample_factor * q`` normalised matches (3 in the paper).

    Returns
    -------
    ModelFit

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
    if min(len(np.unique(s[:, 0])), len(np.unique(s[:, 1]))) < q:
        return _failed(k, kind, sample)
    model = _fit(kind, kpts1[s[:, 0]], kpts2[s[:, 1]])
    if model is None:
        return _failed(k, kind, sample)
    err = _model_errors(model, kind, kpts1[matches[:, 0]], kpts2[matches[:, 1]])
    return ModelFit(err <= threshold, model, kind, sample, err)
