"""Glue to OpenCV and kornia: keypoints, matches and local affine frames in their formats and back.

OpenCV: :func:`from_cv2_keypoints` / :func:`to_cv2_keypoints` (``size`` = 2 sigma, ``angle`` in degrees
clockwise on screen, -1 for none), :func:`to_cv2_matches` / :func:`from_cv2_matches`. kornia (imported when
called): :func:`from_kornia_lafs` / :func:`to_kornia_lafs` and :func:`match_blob`, blob matching (Sec. 3)
behind ``kornia.feature.match_smnn``'s interface. Shapes are ``patch_radius * sigma * R(angle)``; the LAF
scale ``mr_size`` has no default (kornia: 6, kornia_moons: 12; a wrong one changes the overlap-FGINN).
See docs/interop.md.
"""

from __future__ import annotations

import numpy as np

from .._numerics.docstrings import shared_doc
from .._numerics.extras import require
from .._numerics.fixedmath import atan2, sincos
from .._numerics.validation import as_matches, as_points, as_scores

__all__ = ["from_cv2_keypoints", "to_cv2_keypoints", "to_cv2_matches", "from_cv2_matches", "from_kornia_lafs",
           "to_kornia_lafs", "match_blob"]

#: ``mr_size`` of the project's own shapes (``FeatureConfig.patch_radius``): a 3 sigma patch.
CTXMATCH_MR_SIZE = 3.0


def _torch():
    return require("torch", "kornia", "kornia interop (to_kornia_lafs, match_blob)")


def _rotation(angles: np.ndarray) -> np.ndarray:
    s, c = sincos(angles)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # columns: the patch axes


def _numpy(x):
    """A torch tensor or an array_like as an ndarray; ``None`` stays ``None``."""
    return None if x is None else (x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x))


def _as_shapes(shapes, n: int) -> np.ndarray:
    A = np.asarray(shapes, np.float64)
    if A.size == 0 and n == 0:
        A = A.reshape(0, 2, 2)
    if A.shape != (n, 2, 2):
        raise ValueError(f"shapes must have shape ({n}, 2, 2), got {A.shape}")
    return A


def _check_patch_radius(patch_radius) -> float:
    r = float(patch_radius)
    if not np.isfinite(r) or r <= 0:
        raise ValueError(f"patch_radius must be a positive number, got {patch_radius!r}")
    return r


# ------------------------------------------------------------------------------------------------ OpenCV
def from_cv2_keypoints(keypoints, *, patch_radius: float = 3.0):
    """Arrays from a list of ``cv2.KeyPoint``.

    Parameters
    ----------
    keypoints : sequence of cv2.KeyPoint
    patch_radius : float, default 3
        Patch radius in keypoint sigmas (OpenCV's ``size / 2``).

    Returns
    -------
    kpts : ndarray of shape (N, 2)
    shapes : ndarray of shape (N, 2, 2)
        ``patch_radius * size / 2 * R(angle)``; angle 0 where OpenCV has none (``-1``).
    angles : ndarray of shape (N,)
        Radians in (-pi, pi], clockwise on screen; NaN where OpenCV has ``-1``.
    responses : ndarray of shape (N,)

    Examples
    --------
    >>> import cv2
    >>> kpts, shapes, angles, resp = from_cv2_keypoints([cv2.KeyPoint(10.5, 20.0, 4.0, 90.0, 0.5)])
    >>> kpts.tolist(), shapes[0].round(6).tolist(), angles.round(6).tolist(), resp.tolist()
    ([[10.5, 20.0]], [[0.0, -6.0], [6.0, 0.0]], [1.570796], [0.5])
    """
    r = _check_patch_radius(patch_radius)
    kps = list(keypoints)
    for i, k in enumerate(kps[:1]):
        if not hasattr(k, "pt") or not hasattr(k, "size"):
            raise ValueError(f"keypoints must be cv2.KeyPoint objects, got {type(k).__name__} at index {i}")
    n = len(kps)
    kpts = np.array([k.pt for k in kps], np.float64).reshape(n, 2)
    size = np.array([k.size for k in kps], np.float64)
    deg = np.array([k.angle for k in kps], np.float64)
    resp = np.array([k.response for k in kps], np.float64)
    none = deg < 0  # OpenCV's -1: no orientation
    rad = np.deg2rad(np.where(none, 0.0, deg))
    rad = np.where(rad > np.pi, rad - 2 * np.pi, rad)
    shapes = _rotation(rad) * (r * size / 2)[:, None, None]
    angles = np.where(none, np.nan, rad)
    return kpts, shapes.reshape(n, 2, 2), angles, resp


@shared_doc
def to_cv2_keypoints(kpts, shapes=None, *, angles=None, responses=None, patch_radius: float = 3.0) -> list:
    """A list of ``cv2.KeyPoint``, the exact inverse of :func:`from_cv2_keypoints`.

    Parameters
    ----------
    %(kpts_one)s
    shapes : array_like of shape (N, 2, 2), optional
        ``size = 2 sqrt(|det A|) / patch_radius``, ``angle`` of the first axis; default size 1, angle -1.
    angles : array_like of shape (N,), optional
        Radians (:func:`from_cv2_keypoints`); override the angle of ``shapes`` (NaN -> -1).
    responses : array_like of shape (N,), optional
    patch_radius : float, default 3
    """
    import cv2

    r = _check_patch_radius(patch_radius)
    kpts = as_points(kpts, "kpts")
    n = len(kpts)
    if shapes is None:
        size, deg, oriented = np.ones(n), np.zeros(n), np.zeros(n, bool)
    else:
        A = _as_shapes(shapes, n)
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        size = 2 * np.sqrt(np.abs(det)) / r
        deg, oriented = np.rad2deg(atan2(A[:, 1, 0], A[:, 0, 0])), np.ones(n, bool)
    if angles is not None:
        a = np.asarray(angles, np.float64).reshape(-1)
        if len(a) != n:
            raise ValueError(f"angles must have one value per keypoint ({n}), got {len(a)}")
        deg, oriented = np.rad2deg(np.nan_to_num(a)), ~np.isnan(a)
    deg = np.mod(deg, 360.0)
    deg = np.where(deg >= 360.0, deg - 360.0, deg)  # mod of a tiny negative number rounds to 360
    deg = np.where(oriented, deg, -1.0)
    resp = np.zeros(n) if responses is None else as_scores(responses, n, "responses")
    return [cv2.KeyPoint(float(x), float(y), float(s), float(a), float(q))
            for (x, y), s, a, q in zip(kpts, size, deg, resp)]


def to_cv2_matches(matches, scores=None) -> list:
    """A list of ``cv2.DMatch`` (``queryIdx`` = image-1 row, ``trainIdx`` = image-2 row, ``distance`` = score).

    Parameters
    ----------
    matches : array_like of shape (K, 2), int
    scores : array_like of shape (K,), optional
        Lower is better; 0 when omitted.

    Examples
    --------
    >>> [(d.queryIdx, d.trainIdx, d.distance) for d in to_cv2_matches([[0, 3], [2, 1]], [0.25, 0.5])]
    [(0, 3, 0.25), (2, 1, 0.5)]
    """
    import cv2

    m = as_matches(matches)
    s = as_scores(scores, len(m))
    return [cv2.DMatch(int(i), int(j), float(d)) for (i, j), d in zip(m, s)]


def from_cv2_matches(dmatches, *, return_scores: bool = False):
    """``(K, 2)`` int64 ``(queryIdx, trainIdx)`` matches from a list of ``cv2.DMatch``.

    Parameters
    ----------
    dmatches : sequence of cv2.DMatch, or of sequences of them
        ``knnMatch``'s nested lists are flattened (every neighbour becomes a match).
    return_scores : bool, default False
        Also return the distances as ``(K,)`` scores.

    Examples
    --------
    >>> import cv2
    >>> from_cv2_matches([cv2.DMatch(0, 3, 0.25), cv2.DMatch(2, 1, 0.5)]).tolist()
    [[0, 3], [2, 1]]
    """
    flat = []
    for d in dmatches:
        if hasattr(d, "queryIdx"):
            flat.append(d)
        else:
            try:
                flat.extend(d)
            except TypeError:
                raise ValueError(f"dmatches must hold cv2.DMatch objects, got {type(d).__name__}") from None
    for d in flat:
        if not hasattr(d, "queryIdx"):
            raise ValueError(f"dmatches must hold cv2.DMatch objects, got {type(d).__name__}")
    m = np.array([(d.queryIdx, d.trainIdx) for d in flat], np.int64).reshape(-1, 2)
    if not return_scores:
        return m
    return m, np.array([d.distance for d in flat], np.float64)


# ------------------------------------------------------------------------------------------------ kornia
def _check_mr_size(mr_size) -> float:
    if mr_size is None:
        raise ValueError("mr_size is required: the LAF half-size in keypoint sigmas (ctxmatch shapes: 3, kornia's "
                         "ScaleSpaceDetector: 6, kornia_moons' laf_from_opencv_SIFT_kpts: 12)")
    v = float(mr_size)
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"mr_size must be a positive number, got {mr_size!r}")
    return v


def from_kornia_lafs(lafs, *, mr_size: float, patch_radius: float = 3.0):
    """``(kpts, shapes)``, ``(N, 2)`` and ``(N, 2, 2)``, from kornia local affine frames ``[A | c]``.

    Parameters
    ----------
    lafs : torch.Tensor or ndarray of shape (1, N, 2, 3) or (N, 2, 3)
    mr_size : float
        ``A = mr_size * sigma * R`` (kornia's ``ScaleSpaceDetector``: 6; kornia_moons: 12).
    patch_radius : float, default 3
        Radius of the returned shapes in sigmas (``A * patch_radius / mr_size``).
    """
    mr = _check_mr_size(mr_size)
    r = _check_patch_radius(patch_radius)
    arr = np.asarray(_numpy(lafs), np.float64)
    if arr.ndim == 4:
        if arr.shape[0] != 1:
            raise ValueError(f"lafs must hold one image (B = 1), got B = {arr.shape[0]}; pass lafs[i:i+1]")
        arr = arr[0]
    if arr.ndim != 3 or arr.shape[1:] != (2, 3):
        raise ValueError(f"lafs must have shape (1, N, 2, 3) or (N, 2, 3), got {tuple(np.shape(lafs))}")
    if not np.isfinite(arr).all():
        raise ValueError("lafs contains NaN or infinite values")
    return np.ascontiguousarray(arr[:, :, 2]), np.ascontiguousarray(arr[:, :, :2] * (r / mr))


@shared_doc
def to_kornia_lafs(kpts, shapes, *, mr_size: float, patch_radius: float = 3.0, dtype=None, device=None):
    """kornia local affine frames ``(1, N, 2, 3)`` from keypoints and shapes.

    Parameters
    ----------
    %(kpts_one)s
    shapes : array_like of shape (N, 2, 2)
    mr_size : float
        As in :func:`from_kornia_lafs`; ``mr_size=patch_radius`` keeps the shapes.
    patch_radius : float, default 3
    dtype, device : torch dtype and device, optional
        Default ``torch.float64`` (exact round trips) on the CPU.
    """
    torch = _torch()

    mr = _check_mr_size(mr_size)
    r = _check_patch_radius(patch_radius)
    k = as_points(kpts, "kpts")
    A = _as_shapes(shapes, len(k))
    laf = np.concatenate([A * (mr / r), k[:, :, None]], axis=2)[None]
    return torch.as_tensor(laf, dtype=dtype or torch.float64, device=device)


def match_blob(desc1, desc2, lafs1=None, lafs2=None, dm=None, *, mr_size: float | None = None, blob="paper-best"):
    """Blob matching (Sec. 3) behind kornia's matcher interface (``kornia.feature.match_smnn`` & co).

    Parameters
    ----------
    desc1, desc2 : torch.Tensor or ndarray of shape (B1, D) and (B2, D)
        Descriptors, compared by L2 distance unless ``dm`` is given.
    lafs1, lafs2 : torch.Tensor of shape (1, B1, 2, 3) and (1, B2, 2, 3), optional
        Local affine frames; required by setups with FGINN (``t_o`` set), like the default.
    dm : torch.Tensor or ndarray of shape (B1, B2), optional
        Precomputed distance matrix (replaces the descriptors).
    mr_size : float, optional
        As in :func:`from_kornia_lafs`; required when ``t_o_kind="overlap"``.
    blob : str, dict or BlobConfig, default "paper-best"
        Blob-matching setup (:func:`ctxmatch_lib.match.resolve_blob`).

    Returns
    -------
    dists : torch.Tensor of shape (K, 1)
        Blob scores (lower is better), sorted, float64.
    idxs : torch.Tensor of shape (K, 2), long
        Rows into ``desc1`` and ``desc2``; many-to-many unless f' = 1.
    """
    torch = _torch()

    from ..blob import blob_matching
    from ..match import resolve_blob

    cfg = resolve_blob(blob)
    kwargs = cfg.kwargs()
    kp1 = kp2 = sh1 = sh2 = None
    if lafs1 is not None or lafs2 is not None:
        if lafs1 is None or lafs2 is None:
            raise ValueError("lafs1 and lafs2 must be given together")
        needs_shapes = cfg.t_o is not None and cfg.t_o_kind == "overlap"
        if needs_shapes and mr_size is None:
            _check_mr_size(None)
        mr = CTXMATCH_MR_SIZE if mr_size is None else mr_size  # only the centres are used then
        kp1, sh1 = from_kornia_lafs(lafs1, mr_size=mr)
        kp2, sh2 = from_kornia_lafs(lafs2, mr_size=mr)
    elif cfg.t_o is not None:
        raise ValueError(f"lafs1 and lafs2 are required by the blob setup {cfg.label!r} (FGINN, t_o set); "
                         "pass them or a setup with t_o=None")
    if dm is not None:
        out = blob_matching(distances=_numpy(dm), kpts1=kp1, kpts2=kp2, shapes1=sh1, shapes2=sh2, **kwargs)
    else:
        out = blob_matching(_numpy(desc1), _numpy(desc2), kpts1=kp1, kpts2=kp2, shapes1=sh1, shapes2=sh2, **kwargs)
    device = next((x.device for x in (desc1, desc2, dm) if hasattr(x, "device")), None)
    dists = torch.as_tensor(out.scores, dtype=torch.float64, device=device).reshape(-1, 1)
    idxs = torch.as_tensor(out.matches, dtype=torch.long, device=device).reshape(-1, 2)
    return dists, idxs
