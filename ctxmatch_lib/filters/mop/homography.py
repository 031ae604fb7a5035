"""Batched homography primitives of MOP and MiHo: the normalised DLT fit, the symmetric transfer error with
the side-of-the-camera (sign) check, the orientation check of a minimal sample and MiHo's rotation vote."""

from __future__ import annotations

import numpy as np

from ..._numerics.fixedmath import sincos

__all__ = ["fit_homographies", "fit_minimal", "adjugate", "transfer_errors", "supports", "keeps_orientation",
           "best_rotation", "normalise_scale"]

# Added to the mean distance of the Hartley normalisation, so that coincident points give a finite scale.
_EPS = float(np.finfo(np.float32).eps)
_TRIANGLES = ((0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3))


def _normalised(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (B, m, 2) moved to centroid 0 and mean distance sqrt(2) (Hartley), and the maps T (B, 3, 3)."""
    c = p.mean(axis=1)
    s = np.sqrt(2.0) / (np.sqrt(((p - c[:, None, :]) ** 2).sum(-1)).mean(axis=1) + _EPS)
    T = np.zeros((len(p), 3, 3))
    T[:, 0, 0] = T[:, 1, 1] = s
    T[:, :2, 2] = -c * s[:, None]
    T[:, 2, 2] = 1.0
    return (p - c[:, None, :]) * s[:, None, None], T


def _dlt_system(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``A`` (B, 3m, 9) of the cross-product equations ``dst x (H src) = 0``, three rows per point, ``h`` the
    rows of ``H``."""
    x, y = src.transpose(2, 0, 1)
    u, v = dst.transpose(2, 0, 1)
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows = (
        (zero, zero, zero, -x, -y, -one, v * x, v * y, v),
        (x, y, one, zero, zero, zero, -u * x, -u * y, -u),
        (-v * x, -v * y, -v, u * x, u * y, u, zero, zero, zero),
    )
    return np.concatenate([np.stack(r, axis=-1) for r in rows], axis=1)


def fit_homographies(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homographies ``src -> dst`` by the normalised DLT, one per batch row.

    Parameters
    ----------
    src, dst : ndarray of shape (B, m, 2)
        Corresponding points, ``m >= 4``.

    Returns
    -------
    H : ndarray of shape (B, 3, 3)
        The right singular vector of the smallest singular value of the cross-product system on
        Hartley-normalised points (:func:`_dlt_system`), mapped back to pixels.
    sv : ndarray of shape (B,)
        The second-smallest singular value of that system: near zero for a degenerate sample (collinear
        points), the test of the minimal samples.
    """
    (ns, Ts), (nd, Td) = _normalised(src), _normalised(dst)
    _, s, vt = np.linalg.svd(_dlt_system(ns, nd), full_matrices=False)
    Hn = vt[:, -1, :].reshape(len(src), 3, 3)
    return np.linalg.inv(Td) @ Hn @ Ts, s[:, -2]


def _canonical_basis(p: np.ndarray) -> np.ndarray:
    """``(B, 3, 3)`` maps of the projective basis ``e1, e2, e3, (1, 1, 1)`` onto the four points ``p`` (B, 4, 2):
    the columns ``l_i p_i``, ``(l_1, l_2, l_3)`` solving ``sum l_i p_i = p_4`` (zero for three collinear)."""
    P = np.concatenate([p, np.ones(p.shape[:2] + (1,))], axis=-1).transpose(0, 2, 1)  # (B, 3, 4)
    adj, _ = adjugate(P[:, :, :3])
    lam = (adj @ P[:, :, 3:])[:, :, 0]  # det-scaled: one scale for the whole basis
    return P[:, :, :3] * lam[:, None, :]


def fit_minimal(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homographies ``src -> dst`` through four points, one per batch row, as :func:`fit_homographies` gives
    them, at a fraction of its cost: the exact map through the projective bases of the two quadruples, and
    the system's second-smallest singular value from the eigenvalues of ``A^T A``.

    Parameters
    ----------
    src, dst : ndarray of shape (B, 4, 2)

    Returns
    -------
    H : ndarray of shape (B, 3, 3)
        Zero or not finite where three points are collinear (``sv`` is then near zero).
    sv : ndarray of shape (B,)
    """
    (ns, Ts), (nd, Td) = _normalised(src), _normalised(dst)
    A = _dlt_system(ns, nd)
    sv = np.sqrt(np.maximum(np.linalg.eigvalsh(np.einsum("bki,bkj->bij", A, A))[:, 1], 0.0))
    bs, bd = _canonical_basis(ns), _canonical_basis(nd)
    Hn = bd @ adjugate(bs)[0]
    return np.linalg.inv(Td) @ Hn @ Ts, sv


def adjugate(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``adj(H) = det(H) H^-1`` and ``det(H)`` of (B, 3, 3) matrices: the inverse map up to a scale whose sign
    is shared by all the points of one hypothesis, which is all the sign check needs. Column ``i`` of the
    adjugate is the cross product of the two rows other than ``i``."""
    a, b = H[:, [1, 2, 0], :], H[:, [2, 0, 1], :]  # row pairs (1, 2), (2, 0), (0, 1)
    cross = a[:, :, [1, 2, 0]] * b[:, :, [2, 0, 1]] - a[:, :, [2, 0, 1]] * b[:, :, [1, 2, 0]]
    return cross.transpose(0, 2, 1), (H[:, 0, :] * cross[:, 0, :]).sum(-1)


def transfer_errors(H: np.ndarray, src: np.ndarray, dst: np.ndarray, ref: np.ndarray):
    """Squared symmetric transfer errors ``max(|H s - d|^2, |H^-1 d - s|^2)`` of every point under every
    homography, with the sign check of the authors' code.

    Parameters
    ----------
    H : ndarray of shape (B, 3, 3)
    src, dst : ndarray of shape (n, 2)
    ref : ndarray of shape (B, r) int
        Reference points of each homography (its minimal sample): a point counts only when its projective
        depth has the sign of ``ref[:, 0]``'s in both directions, i.e. it lies on the same side of the
        line at infinity as the sample.

    Returns
    -------
    err : ndarray of shape (B, n)
        The error, ``inf`` where the sign differs, the transfer is not finite or ``H`` is singular.
    consistent : ndarray of shape (B,) bool
        All the points ``ref`` share their sign in both directions.
    """
    adj, det = adjugate(H)
    s = np.c_[src, np.ones(len(src))].T
    d = np.c_[dst, np.ones(len(dst))].T
    fwd = H @ s  # (B, 3, n)
    bwd = adj @ d
    rows = np.arange(len(H))[:, None]
    err = np.zeros((len(H), len(src)))
    consistent = det != 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for proj, target in ((fwd, d), (bwd, s)):
            sign = np.sign(proj[:, 2])
            at_ref = sign[rows, ref]
            consistent &= (at_ref == at_ref[:, :1]).all(axis=1)
            e = ((proj[:, :2] / proj[:, 2:] - target[None, :2]) ** 2).sum(axis=1)
            e[sign != at_ref[:, :1]] = np.inf
            np.maximum(err, e, out=err)
    err[~np.isfinite(err) | (det == 0)[:, None]] = np.inf
    return err, consistent


def _fits(M: np.ndarray, src: np.ndarray, dst: np.ndarray, th2: float) -> np.ndarray:
    """``|M src - dst|^2 < th2`` with a positive projective depth, tested without a division as
    ``|(M src)_xy - w dst|^2 < th2 w^2``, ``w > 0``; ``M`` (..., 3, 3) broadcasts against the points (..., 2)."""
    x, y, u, v = src[..., 0], src[..., 1], dst[..., 0], dst[..., 1]
    w = M[..., 2, 0] * x + M[..., 2, 1] * y + M[..., 2, 2]
    rx = M[..., 0, 0] * x + M[..., 0, 1] * y + M[..., 0, 2] - w * u
    ry = M[..., 1, 0] * x + M[..., 1, 1] * y + M[..., 1, 2] - w * v
    return (w > 0) & (rx * rx + ry * ry < th2 * (w * w))


def supports(H: np.ndarray, pairs, samples: np.ndarray, th2: float) -> np.ndarray:
    """``(B, n)`` bool: the points within ``sqrt(th2)`` of every map of each hypothesis, both ways, on the side of
    the line at infinity of its minimal sample (the authors' ``get_inlier_*``).

    Parameters
    ----------
    H : ndarray of shape (B, J, 3, 3)
        Map ``j`` of each hypothesis takes ``pairs[j][0]`` to ``pairs[j][1]``.
    pairs : sequence of J (src, dst), ndarray of shape (n, 2) each
    samples : ndarray of shape (B, r) int
        A hypothesis counts no point unless all its ``r`` sample points share the projective depth sign of the
        first in each of the ``2 J`` directions; a point counts when it shares it too and its transfer
        error is below ``th2`` in each direction.
    th2 : float
        Squared threshold, pixels squared.

    Notes
    -----
    The first direction is tested on every point; the others only on the points that passed.
    """
    B, n = len(H), len(pairs[0][0])
    tests = []
    valid = np.ones(B, bool)
    for j, (src, dst) in enumerate(pairs):
        adj, det = adjugate(H[:, j])
        valid &= det != 0
        for M, a, b in ((H[:, j], src, dst), (adj, dst, src)):
            ref = a[samples]  # (B, r, 2)
            w = M[:, None, 2, 0] * ref[..., 0] + M[:, None, 2, 1] * ref[..., 1] + M[:, None, 2, 2]
            side = np.sign(w[:, 0])
            valid &= (side != 0) & (w * side[:, None] > 0).all(axis=1)
            tests.append((M * side[:, None, None], a, b))  # the sample's side made w > 0
    M, a, b = tests[0]
    hit = _fits(M[:, None], a[None], b[None], th2) & valid[:, None]
    bi, pi = np.nonzero(hit)
    for M, a, b in tests[1:]:
        keep = _fits(M[bi], a[pi], b[pi], th2)
        bi, pi = bi[keep], pi[keep]
    out = np.zeros((B, n), bool)
    out[bi, pi] = True
    return out


def keeps_orientation(p1: np.ndarray, p2: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """``(S,)`` bool: the four triangles of each 4-point sample (S, 4) turn the same way in both images (no
    mirror map); a degenerate triangle must be degenerate in both (the authors' ``go_check_reflection``)."""
    tri = np.array(_TRIANGLES)
    turns = []
    for p in (p1, p2):
        q = p[samples[:, tri]]  # (S, 4, 3, 2)
        e1, e2 = q[:, :, 1] - q[:, :, 0], q[:, :, 2] - q[:, :, 0]
        turns.append(np.sign(e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]))
    return (turns[0] == turns[1]).all(axis=1)


def _quarter_exact(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of the angles ``a`` (_fixedmath's: the same bits on any CPU), exact (0, +-1) at multiples of a
    quarter turn."""
    s, c = sincos(a)
    c[np.abs(c) < 1e-12], s[np.abs(s) < 1e-12] = 0.0, 0.0
    c[np.abs(np.abs(c) - 1) < 1e-12] = np.sign(c[np.abs(np.abs(c) - 1) < 1e-12])
    s[np.abs(np.abs(s) - 1) < 1e-12] = np.sign(s[np.abs(np.abs(s) - 1) < 1e-12])
    return c, s


def _rotated_gap(a, b, c, d, cos: float, sin: float) -> np.ndarray:
    """``|D1 - R D2|^2`` for the offsets ``D1 = (a, b)``, ``D2 = (c, d)`` and the rotation ``(cos, sin)``, with no
    multiplication by the rotation at a quarter turn (exact there)."""
    if sin == 0:
        ex, ey = (a - c, b - d) if cos > 0 else (a + c, b + d)
    elif cos == 0:
        ex, ey = (a + d, b - c) if sin > 0 else (a - d, b + c)
    else:
        ex, ey = a - (cos * c - sin * d), b - (sin * c + cos * d)
    return ex * ex + ey * ey


def best_rotation(p1: np.ndarray, p2: np.ndarray, n_rot: int, pairs_per_block: int = 1 << 15) -> np.ndarray:
    """MiHo's pre-rotation of image 2: the rotation ``R_k`` (by ``k 360 / n_rot`` degrees about the origin) for
    which most pairs of matches have their middle-point distance strictly between their image-1 and image-2
    distances, the middle points being ``(p1 + R_k p2) / 2``; the smallest angle on ties.

    With ``D1``, ``D2`` the offsets of a pair in the two images and ``q1``, ``q2`` their squared lengths, the
    squared middle distance is ``(q1 + q2) / 2 - |D1 - R_k D2|^2 / 4``, which lies strictly between ``q1``
    and ``q2`` when ``|D1 - R_k D2|^2 < 2 |q1 - q2|``; for the opposite rotation ``-R_k`` the gap is
    ``2 (q1 + q2) - |D1 - R_k D2|^2``, so the test reads ``|D1 - R_k D2|^2 > 4 min(q1, q2)``. The pairs
    ``i < j`` are scored (the relation is symmetric), a block of rows at a time.

    Returns
    -------
    R : ndarray of shape (3, 3)
        Homogeneous rotation applied to image 2.
    """
    n_rot = max(int(n_rot), 1)
    cos, sin = _quarter_exact(np.arange(n_rot) * 2.0 * np.pi / n_rot)
    paired = n_rot % 2 == 0  # rotation k + n_rot / 2 is -R_k
    votes = np.zeros(n_rot, np.int64)
    n = len(p1)
    block = max(1, pairs_per_block // max(n, 1))
    for i0 in range(0, n, block):
        i1 = min(i0 + block, n)
        a, b = p1[None, i0:, 0] - p1[i0:i1, None, 0], p1[None, i0:, 1] - p1[i0:i1, None, 1]
        c, d = p2[None, i0:, 0] - p2[i0:i1, None, 0], p2[None, i0:, 1] - p2[i0:i1, None, 1]
        q1, q2 = a * a + b * b, c * c + d * d
        near = 2.0 * np.abs(q1 - q2)
        far = 4.0 * np.minimum(q1, q2)
        lower = np.tril(np.ones((i1 - i0, i1 - i0), bool))  # pairs j <= i
        near[:, : i1 - i0][lower] = -1.0
        far[:, : i1 - i0][lower] = np.inf
        for k in range(n_rot // 2 if paired else n_rot):
            gap = _rotated_gap(a, b, c, d, cos[k], sin[k])
            votes[k] += np.count_nonzero(gap < near)
            if paired:
                votes[k + n_rot // 2] += np.count_nonzero(gap > far)
    R = np.eye(3)
    k = int(np.argmax(votes))
    R[:2, :2] = [[cos[k], -sin[k]], [sin[k], cos[k]]]
    return R


def normalise_scale(H: np.ndarray) -> np.ndarray:
    """Homographies (P, 3, 3) scaled to ``H[2, 2] = 1``, or to unit Frobenius norm where ``H[2, 2]`` is 0."""
    h22 = H[:, 2, 2]
    scale = np.where(np.abs(h22) > 1e-12 * np.sqrt((H ** 2).sum(axis=(1, 2))), h22,
                     np.sqrt((H ** 2).sum(axis=(1, 2))))
    return H / np.where(scale == 0, 1.0, scale)[:, None, None]
