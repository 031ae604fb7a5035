"""Argument checks: each returns a clean array or raises a ``ValueError`` naming the argument."""

from __future__ import annotations

import numpy as np

__all__ = ["Presets", "as_points", "as_matches", "as_scores", "as_image_size", "as_finite_matrix", "as_matrix3",
           "as_vector3", "as_intrinsics", "as_rotation", "check_inside", "cumulative_distinct"]


class Presets(dict):
    """A ``dict`` of presets whose ``KeyError`` names ``what`` and lists the known keys.

    Examples
    --------
    >>> p = Presets("colour", {"red": 1, "green": 2})
    >>> p["blue"]
    Traceback (most recent call last):
    ...
    KeyError: "unknown colour 'blue'; known: red, green"
    >>> p.get("blue") is None, isinstance(p, dict)
    (True, True)
    """

    def __init__(self, what: str, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.what = what

    def __missing__(self, key):
        raise KeyError(f"unknown {self.what} {key!r}; known: {', '.join(map(str, self))}")

    def __reduce__(self):
        return (type(self), (self.what, dict(self)))


def as_finite_matrix(x, name: str, *, ndim: int = 2, dtype=None) -> np.ndarray:
    """Return ``x`` as an array of ``ndim`` dimensions with only finite values."""
    arr = np.asarray(x, dtype=dtype)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-D array, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got dtype {arr.dtype}")
    if arr.size and not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def as_matrix3(M, name: str) -> np.ndarray:
    """``M`` as a finite float64 ``(3, 3)`` matrix; the error names ``name``."""
    if M is None:
        raise ValueError(f"{name} is required (a (3, 3) matrix), got None")
    arr = np.asarray(M)
    if arr.shape != (3, 3) or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must be a (3, 3) numeric matrix, got shape {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def as_vector3(v, name: str) -> np.ndarray:
    """``v`` (shape ``(3,)`` or ``(3, 1)``) as a finite float64 ``(3,)`` vector; the error names ``name``."""
    arr = np.asarray(v)
    if arr.shape not in ((3,), (3, 1)) or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must have shape (3,), got {arr.shape}")
    arr = arr.astype(np.float64).reshape(3)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def as_intrinsics(K, name: str = "K") -> np.ndarray:
    """``K`` as an upper-triangular intrinsic matrix with non-zero focals, divided by ``K[2, 2]``.

    Examples
    --------
    >>> as_intrinsics([[500, 0, 320], [0, 500, 240], [0, 0, 2]], "K1")[0].tolist()
    [250.0, 0.0, 160.0]
    >>> as_intrinsics([[0, 0, 320], [0, 500, 240], [0, 0, 1]], "K1")
    Traceback (most recent call last):
    ...
    ValueError: K1 has a zero focal length (fx = 0, fy = 500)
    """
    if K is None:
        raise ValueError(f"{name} is required (a (3, 3) intrinsic matrix), got None")
    arr = as_matrix3(K, name)
    if arr[2, 2] == 0 or arr[1, 0] != 0 or arr[2, 0] != 0 or arr[2, 1] != 0:
        raise ValueError(f"{name} must be upper triangular with K[2, 2] != 0, got {arr.tolist()}")
    arr = arr / arr[2, 2]
    if arr[0, 0] == 0 or arr[1, 1] == 0:
        raise ValueError(f"{name} has a zero focal length (fx = {arr[0, 0]:g}, fy = {arr[1, 1]:g})")
    return arr


def as_rotation(R, name: str = "R", tol: float = 1e-6) -> np.ndarray:
    """``R`` as a rotation: ``R^T R`` within ``tol`` of the identity, positive determinant."""
    arr = as_matrix3(R, name)
    err = float(np.abs(arr.T @ arr - np.eye(3)).max())
    if err > tol:
        raise ValueError(f"{name} is not a rotation: R^T R differs from the identity by {err:.3g}")
    det = float(np.linalg.det(arr))
    if det < 0:
        raise ValueError(f"{name} is not a rotation: its determinant is {det:.6g} (a reflection)")
    return arr


def _first_cv2_object(x, cls: str) -> bool:
    """Whether ``x`` is a non-empty sequence whose first item is an OpenCV ``cls`` (checked by name: no import)."""
    if isinstance(x, np.ndarray) and x.dtype != object:
        return False
    try:
        first = next(iter(x))
    except (TypeError, StopIteration):
        return False
    if isinstance(first, (list, tuple)) and first:  # knnMatch's nested lists
        first = first[0]
    t = type(first)
    return t.__name__ == cls and t.__module__.split(".")[0] == "cv2"


def as_points(x, name: str, *, n: int | None = None) -> np.ndarray:
    """Keypoints as float64 ``(N, 2)``; extra columns are dropped, ``None`` gives ``(0, 2)``."""
    if _first_cv2_object(x, "KeyPoint"):
        raise ValueError(
            f"{name} must be an (N, 2) array of (x, y) pixels, got a list of cv2.KeyPoint; convert it with "
            f"ctxmatch_lib.io.interop.from_cv2_keypoints({name}) (returns kpts, shapes, angles, responses)")
    arr = np.empty((0, 2)) if x is None else np.asarray(x, dtype=np.float64)
    if arr.size == 0:
        arr = arr.reshape(0, 2)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"{name} must have shape (N, 2), got {arr.shape}")
    arr = arr[:, :2]
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    if n is not None and len(arr) != n:
        raise ValueError(f"{name} must have {n} rows, got {len(arr)}")
    return np.ascontiguousarray(arr)


def as_matches(matches, n1: int | None = None, n2: int | None = None, name: str = "matches") -> np.ndarray:
    """Return matches as an int64 ``(K, 2)`` array, checking the indices against ``n1`` and ``n2``."""
    if _first_cv2_object(matches, "DMatch"):
        raise ValueError(f"{name} must be a (K, 2) array of indices, got a list of cv2.DMatch; convert it with "
                         f"ctxmatch_lib.io.interop.from_cv2_matches({name})")
    arr = np.asarray(matches)
    if arr.size == 0:
        return np.empty((0, 2), np.int64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must have shape (K, 2), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer) and not np.all(np.equal(np.mod(arr, 1), 0)):
        raise ValueError(f"{name} must hold integer indices")
    arr = arr.astype(np.int64)
    if arr.min() < 0:
        raise ValueError(f"{name} holds negative indices")
    for col, n in ((0, n1), (1, n2)):
        if n is not None and arr[:, col].max() >= n:
            raise ValueError(
                f"{name}[:, {col}] indexes row {arr[:, col].max()} but only {n} keypoints were given"
            )
    return arr


def as_scores(scores, k: int, name: str = "scores") -> np.ndarray:
    """Return per-match scores as float64 ``(K,)`` (lower is better); ``None`` gives all zeros."""
    if scores is None:
        return np.zeros(k)
    arr = np.asarray(scores, dtype=np.float64).reshape(-1)
    if len(arr) != k:
        raise ValueError(f"{name} must have one value per match ({k}), got {len(arr)}")
    if np.isnan(arr).any():
        raise ValueError(f"{name} contains NaN values")
    return arr


def as_image_size(size, name: str) -> tuple[int, int]:
    """Return an image size as ``(width, height)`` of positive ints."""
    try:
        w, h = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be (width, height), got {size!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"{name} must be positive, got {(w, h)}")
    return w, h


def check_inside(kpts, image_size, name: str = "kpts", *, tol: float = 0.5) -> np.ndarray:
    """``kpts`` as ``(N, 2)``; ``ValueError`` unless each lies within ``tol`` of the outer pixel centres.

    Examples
    --------
    >>> check_inside([[639.4, 10.0]], (640, 480)).shape
    (1, 2)
    >>> check_inside([[10.0, 639.0]], (640, 480), "kpts1")
    Traceback (most recent call last):
    ...
    ValueError: kpts1 has keypoints outside the image of size (width, height) = (640, 480): ...
    """
    pts = as_points(kpts, name)
    w, h = as_image_size(image_size, f"image size of {name}")
    if len(pts) == 0:
        return pts
    lo = -tol
    bad = (pts[:, 0] < lo) | (pts[:, 1] < lo) | (pts[:, 0] > w - 1 + tol) | (pts[:, 1] > h - 1 + tol)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        hint = ""
        if (pts[:, 0].max() <= h - 1 + tol) and (pts[:, 1].max() <= w - 1 + tol):
            hint = "; they would fit (height, width): was the size given as (height, width)?"
        raise ValueError(
            f"{name} has keypoints outside the image of size (width, height) = ({w}, {h}): "
            f"{int(bad.sum())} of {len(pts)}, e.g. row {i} at (x, y) = ({pts[i, 0]:g}, {pts[i, 1]:g}); keypoints "
            f"are (x, y) pixels with the origin at the centre of the top-left pixel, so x must lie in "
            f"[{lo:g}, {w - 1 + tol:g}] and y in [{lo:g}, {h - 1 + tol:g}]{hint}"
        )
    return pts


def cumulative_distinct(values) -> np.ndarray:
    """``out[k]`` = number of distinct values among ``values[:k + 1]`` (non-negative ints), in O(K + max).

    Examples
    --------
    >>> cumulative_distinct([3, 1, 3, 0, 1])
    array([1, 2, 2, 3, 3])
    """
    v = np.asarray(values, np.int64).reshape(-1)
    k = len(v)
    if k == 0:
        return np.zeros(0, np.int64)
    first = np.full(int(v.max()) + 1, k, np.int64)
    np.minimum.at(first, v, np.arange(k))
    return np.cumsum(first[v] == np.arange(k))
