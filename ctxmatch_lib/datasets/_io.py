"""Small readers shared by the loaders: matrices, MATLAB point files, image sizes, F fitting."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["read_matrix", "read_vpts", "image_size", "fit_fundamental", "find_image"]

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


def read_vpts(path):
    """Read a Lebeda ``*_vpts.mat`` file.

    Returns
    -------
    ptsA, ptsB : ndarray of shape (N, 2)
        Hand-taken corresponding points of images A and B, (x, y) pixels, origin at the centre of the
        top-left pixel (checked against SIFT matches on the zoom pairs of homogr: the files need no
        MATLAB one-pixel shift).
    model : ndarray of shape (3, 3) or None
        ``validation.model`` when present and not all zeros.
    """
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
    ptsA = (pts[0:2] / pts[2]).T
    ptsB = (pts[3:5] / pts[5]).T
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


def _normalise(pts):
    c = pts.mean(0)
    d = np.sqrt(((pts - c) ** 2).sum(1)).mean()
    s = np.sqrt(2) / d if d > 0 else 1.0
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])


def _oriented_ok(F, pts1, pts2) -> bool:
    """Oriented epipolar constraint (Chum, Werner, Matas 2004): one sign of e2 x x2 . F x1 for all points."""
    _, _, vt = np.linalg.svd(F.T)
    e2 = vt[-1]
    x1 = np.c_[pts1, np.ones(len(pts1))]
    x2 = np.c_[pts2, np.ones(len(pts2))]
    s = np.einsum("ij,ij->i", np.cross(e2, x2), x1 @ F.T)
    return bool(np.all(s > 0) or np.all(s < 0))


def fit_fundamental(pts1, pts2) -> np.ndarray:
    """Fundamental matrix with ``x2^T F x1 = 0`` from hand-taken correspondences.

    Normalised 8-point algorithm (Hartley 1997) with rank-2 enforcement for N >= 8. With exactly 7
    points the 7-point algorithm gives one or three exact solutions: the one satisfying the oriented
    epipolar constraint is kept (the first such if several do). ``F`` is scaled to unit Frobenius norm.

    Parameters
    ----------
    pts1, pts2 : ndarray of shape (N, 2)
        Corresponding (x, y) pixels, N >= 7.
    """
    pts1 = np.asarray(pts1, np.float64).reshape(-1, 2)
    pts2 = np.asarray(pts2, np.float64).reshape(-1, 2)
    if len(pts1) != len(pts2):
        raise ValueError(f"pts1 and pts2 must have the same length, got {len(pts1)} and {len(pts2)}")
    if len(pts1) < 7:
        raise ValueError(f"fitting F needs at least 7 correspondences, got {len(pts1)}")
    T1, T2 = _normalise(pts1), _normalise(pts2)
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
    Fs = [T2.T @ Fn @ T1 for Fn in candidates]
    Fs = [F / np.linalg.norm(F) for F in Fs]
    oriented = [F for F in Fs if _oriented_ok(F, pts1, pts2)]
    return (oriented or Fs)[0]
