"""Small readers shared by the loaders: matrices, MATLAB point files, image sizes, F fitting."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._numerics.fixedmath import sincos

__all__ = ["read_matrix", "read_vpts", "image_size", "fundamental_from_hand_points", "find_image",
           "homography_gt", "epipolar_gt", "fitted_epipolar_gt", "flow_gt"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm", ".bmp", ".tif", ".tiff")


def read_matrix(path, shape=(3, 3), *, what: str = "matrix") -> np.ndarray:
    """Read a whitespace-separated text matrix, raising errors that name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    try:
        arr = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"cannot parse {what} file {path}: {exc}") from None
    if shape is not None:
        if arr.size == np.prod(shape) and arr.shape != shape:
            arr = arr.reshape(shape)
        if arr.shape != tuple(shape):
            raise ValueError(f"{what} file {path} must hold a {shape[0]}x{shape[1]} matrix, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} file {path} contains NaN or infinite values")
    return arr


@contextmanager
def named_errors(where):
    """Re-raise a ValueError inside the block as ``ValueError(f"{where}: {exc}")`` (``where``: file, line)."""
    try:
        yield
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def homography_gt(H, source, pts1=None, pts2=None):
    """A :class:`~.base.HomographyGT` scaled to ``H[2, 2] = 1``, or a ValueError naming ``source`` (the
    file it came from) when ``H`` is not finite and invertible or the hand points ``pts1``, ``pts2`` bad."""
    from .base import HomographyGT, _check_matrix

    with named_errors(source):
        _check_matrix(H, "H", "homography", min_rank=3)
        H = np.asarray(H, np.float64)
        return HomographyGT(H / H[2, 2] if H[2, 2] != 0 else H / np.linalg.norm(H), pts1, pts2)


def epipolar_gt(F, source, pts1, pts2):
    """An :class:`~.base.EpipolarGT` scaled to unit Frobenius norm, or a ValueError naming ``source``."""
    from .base import EpipolarGT, _check_matrix

    with named_errors(source):
        _check_matrix(F, "F", "fundamental matrix", min_rank=2)
        F = np.asarray(F, np.float64)
        return EpipolarGT(F / np.linalg.norm(F), np.asarray(pts1, np.float64).copy(),
                          np.asarray(pts2, np.float64).copy())


def fitted_epipolar_gt(pts1, pts2, source):
    """:func:`epipolar_gt` with F fitted by :func:`fundamental_from_hand_points`; degenerate points raise."""
    why = "degenerate hand points (coincident or collinear?)"
    try:
        with np.errstate(all="ignore"):
            F = fundamental_from_hand_points(pts1, pts2)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ValueError(f"{source}: cannot fit F to its hand points, {why}: {exc}") from None
    return epipolar_gt(F, f"{source} (F fitted to its hand points: {why})", pts1, pts2)


def flow_gt(flow12, flow21, source):
    """A :class:`~.base.FlowGT`, or a ValueError naming ``source`` (wrong shape, infinities, nothing known)."""
    from .base import FlowGT

    with named_errors(source):
        return FlowGT(flow12, flow21)


def read_vpts(path):
    """Read a Lebeda ``*_vpts.mat`` file as ``(ptsA, ptsB, model)``: the hand points ``(N, 2)`` of images A
    and B in (x, y) pixels, no MATLAB one-pixel shift (checked against SIFT matches on homogr's zoom pairs),
    and ``validation.model`` (3, 3), ``None`` when absent or all zeros."""
    import scipy.io

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ground-truth file not found: {path}")
    try:
        mat = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
        val = mat["validation"]
        pts = np.asarray(val.pts, dtype=np.float64)
    except Exception as exc:  # scipy raises several types on bad files
        raise ValueError(f"cannot read hand-taken points from {path}: {exc}") from None
    if pts.ndim != 2 or pts.shape[0] != 6:
        raise ValueError(f"{path}: validation.pts must be 6xN, got {pts.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):
        ptsA = (pts[0:2] / pts[2]).T
        ptsB = (pts[3:5] / pts[5]).T
    if not (np.isfinite(ptsA).all() and np.isfinite(ptsB).all()):
        raise ValueError(f"{path}: validation.pts has points at infinity or NaN (homogeneous w = 0?)")
    model = getattr(val, "model", None)
    if model is not None:
        model = np.asarray(model, dtype=np.float64)
        if model.shape != (3, 3) or not np.any(model) or not np.isfinite(model).all():
            model = None
    return np.ascontiguousarray(ptsA), np.ascontiguousarray(ptsB), model


def image_size(path) -> tuple[int, int]:
    """(width, height) of an image file, read from its header when possible."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    try:
        from PIL import Image

        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except ImportError:
        pass
    except Exception:
        raise ValueError(f"cannot decode image file {path} (corrupt or unsupported format)") from None
    from ..features import load_image

    img = load_image(path)
    return int(img.shape[1]), int(img.shape[0])


def find_image(folder: Path, stem: str) -> Path:
    """The image file ``folder/stem.<ext>`` for a known image extension."""
    for suffix in IMAGE_SUFFIXES:
        for cand in (folder / f"{stem}{suffix}", folder / f"{stem}{suffix.upper()}"):
            if cand.is_file():
                return cand
    raise FileNotFoundError(f"image file not found: {folder / stem}.* (tried {', '.join(IMAGE_SUFFIXES)})")


def _oriented_ok(F, pts1, pts2) -> bool:
    """Oriented epipolar constraint (Chum, Werner, Matas 2004): one sign of e2 x x2 . F x1 for all points."""
    _, _, vt = np.linalg.svd(F.T)
    e2 = vt[-1]
    x1 = np.c_[pts1, np.ones(len(pts1))]
    x2 = np.c_[pts2, np.ones(len(pts2))]
    s = np.einsum("ij,ij->i", np.cross(e2, x2), x1 @ F.T)
    return bool(np.all(s > 0) or np.all(s < 0))


def _rotation(w):
    theta = np.linalg.norm(w)
    if theta < 1e-12:
        return np.eye(3)
    k = w / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = sincos(theta)
    return np.eye(3) + s * K + (1 - c) * K @ K


def _line_residuals(F, x1, x2):
    l2 = x1 @ F.T  # epipolar lines in image 2
    l1 = x2 @ F  # epipolar lines in image 1
    alg = np.einsum("ij,ij->i", x2, l2)
    return np.r_[alg / np.hypot(l2[:, 0], l2[:, 1]), alg / np.hypot(l1[:, 0], l1[:, 1])]


def _refine(F0, x1, x2):
    """Rank-2 F near ``F0`` minimising the symmetric point-to-line distances (normalised coordinates)."""
    from scipy.optimize import least_squares

    u0, s0, vt0 = np.linalg.svd(F0)
    if s0[0] <= 0:
        return F0

    def build(p):
        U = _rotation(p[:3]) @ u0
        V = _rotation(p[3:6]) @ vt0.T
        return U @ np.diag([1.0, p[6], 0.0]) @ V.T

    p0 = np.r_[np.zeros(6), s0[1] / s0[0]]
    res = least_squares(lambda p: _line_residuals(build(p), x1, x2), p0, method="lm" if 2 * len(x1) >= 7 else "trf")
    F = build(res.x)
    before = np.abs(_line_residuals(F0, x1, x2)).mean()
    return F if np.abs(_line_residuals(F, x1, x2)).mean() <= before else F0


def fundamental_from_hand_points(pts1, pts2) -> np.ndarray:
    """Ground-truth F (``x2^T F x1 = 0``, unit Frobenius norm) from ``N >= 7`` hand points ``(N, 2)``.

    N >= 8: normalised 8-point (Hartley 1997) refined over rank-2 matrices on the symmetric point-to-line
    distances (Bartoli & Sturm 2004; with few points, plain rank-2 truncation moves the lines by pixels).
    N = 7: the roots meeting the oriented epipolar constraint (Chum, Werner & Matas 2004), then the one with
    the epipoles farthest from the points (a wide-baseline pair's lateral motion).
    """
    pts1 = np.asarray(pts1, np.float64).reshape(-1, 2)
    pts2 = np.asarray(pts2, np.float64).reshape(-1, 2)
    if len(pts1) != len(pts2):
        raise ValueError(f"pts1 and pts2 must have the same length, got {len(pts1)} and {len(pts2)}")
    if len(pts1) < 7:
        raise ValueError(f"fitting F needs at least 7 correspondences, got {len(pts1)}")
    from ..geometry import normalise_points

    T1, T2 = normalise_points(pts1)[1], normalise_points(pts2)[1]
    x1 = np.c_[pts1, np.ones(len(pts1))] @ T1.T
    x2 = np.c_[pts2, np.ones(len(pts2))] @ T2.T
    A = np.einsum("ni,nj->nij", x2, x1).reshape(-1, 9)  # row: vec(x2 x1^T) so that A @ vec(F) = x2^T F x1
    _, _, vt = np.linalg.svd(A)
    if len(pts1) >= 8:
        Fn = vt[-1].reshape(3, 3)
        u, s, v = np.linalg.svd(Fn)
        candidates = [u @ np.diag([s[0], s[1], 0.0]) @ v]
    else:
        F1, F2 = vt[-1].reshape(3, 3), vt[-2].reshape(3, 3)
        # det(a F1 + (1 - a) F2) is a cubic in a: sample it at 4 points and solve.
        xs = np.array([-1.0, 0.0, 1.0, 2.0])
        ys = [np.linalg.det(a * F1 + (1 - a) * F2) for a in xs]
        roots = np.roots(np.polyfit(xs, ys, 3))
        candidates = [r.real * F1 + (1 - r.real) * F2 for r in roots if abs(r.imag) < 1e-9]
    if len(pts1) >= 8:
        candidates = [_refine(candidates[0], x1, x2)]
    Fs = [T2.T @ Fn @ T1 for Fn in candidates]
    Fs = [F / np.linalg.norm(F) for F in Fs]
    oriented = [F for F in Fs if _oriented_ok(F, pts1, pts2)] or Fs
    if len(oriented) == 1:
        return oriented[0]
    return max(oriented, key=lambda F: _epipole_distance(F, pts1, pts2))


def _epipole_distance(F, pts1, pts2) -> float:
    """Distance of the nearer epipole from its image's points, in units of their spread (inf at infinity)."""
    out = np.inf
    for M, pts in ((F, pts1), (F.T, pts2)):
        e = np.linalg.svd(M)[2][-1]
        c = pts.mean(0)
        spread = np.sqrt(((pts - c) ** 2).sum(1).mean()) or 1.0
        if abs(e[2]) > 1e-12:
            out = min(out, float(np.linalg.norm(e[:2] / e[2] - c) / spread))
    return out
