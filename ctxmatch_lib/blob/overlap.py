"""Elliptical patches and their overlap error, for FGINN by overlap (Sec. 3, step 3, Fig. 1b)."""

from __future__ import annotations

import numpy as np

from .._numerics.fixedmath import acos, hypot, sincos

__all__ = ["as_shapes", "shapes_from_scale_angle", "ellipse_overlap_error", "circle_overlap_bounds"]


def shapes_from_scale_angle(scale, angle=None) -> np.ndarray:
    """Affine shapes ``A = scale * R(angle)`` ``(N, 2, 2)`` of circular patches ``{kpts[k] + A[k] @ u : |u| <= 1}``;
    ``scale`` in pixels (``keypoint.size / 2`` for OpenCV SIFT), ``angle`` in radians (default 0)."""
    scale = np.asarray(scale, dtype=np.float64).reshape(-1)
    angle = np.zeros_like(scale) if angle is None else np.asarray(angle, dtype=np.float64).reshape(-1)
    s, c = sincos(angle)  # _fixedmath's: the same shapes on any CPU
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    return scale[:, None, None] * rot


def as_shapes(shapes, n: int, name: str) -> np.ndarray:
    """Validate keypoint shapes: ``(N, 2, 2)`` affine shapes, or ``(N,)`` / ``(N, 1)`` radii."""
    arr = np.asarray(shapes, dtype=np.float64)
    radii = arr.ndim in (1, 2) and arr.shape[0] == n and (arr.ndim == 1 or arr.shape[1] == 1)
    if not radii and arr.shape != (n, 2, 2):
        raise ValueError(f"{name} must have shape ({n}, 2, 2) (affine shapes) or ({n},) (radii), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    if radii:
        arr = arr.reshape(-1)
        area = arr * arr  # r R(0)'s determinant: zero for r = 0 (and where r² underflows, |r| < 1e-154)
        arr = shapes_from_scale_angle(arr)
    else:
        area = np.abs(np.linalg.det(arr)) if n else np.empty(0)
    if not (area > 0).all():
        raise ValueError(f"{name} holds degenerate (zero-area) shapes")
    return arr


def _bounding_circles(c1, A1, c2, A2) -> tuple[np.ndarray, np.ndarray]:
    """Squared centre distances of the pairs, and whether their bounding circles intersect (else error 1)."""
    r1, r2 = _largest_singular_value(A1), _largest_singular_value(A2)
    d2 = np.sum((c1 - c2) ** 2, axis=1)
    return d2, d2 < (r1 + r2) ** 2


def _unit_polygon(k: int = 32) -> np.ndarray:
    """Vertices of a regular ``k``-gon with the area of the unit disk (radius scaled up from 1)."""
    t = np.linspace(0.0, 2.0 * np.pi, k, endpoint=False)
    # fixedmath's sines: the same polygon, hence overlap errors, on any CPU.
    scale = np.sqrt(2.0 * np.pi / (k * float(sincos(2.0 * np.pi / k)[0])))
    s, c = sincos(t)
    return scale * np.stack([c, s], axis=1)


_POLYGON = _unit_polygon()


def _largest_singular_value(A: np.ndarray) -> np.ndarray:
    """Largest singular value of each 2x2 ``[[a, b], [c, d]]``: ``(|(a + d, c - b)| + |(a - d, c + b)|) / 2``,
    element-wise (the same bits on any CPU, no LAPACK)."""
    a, b, c, d = A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1]
    return 0.5 * (np.sqrt((a + d) ** 2 + (c - b) ** 2) + np.sqrt((a - d) ** 2 + (c + b) ** 2))


def _apply(A: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``A[p] @ pts[s]`` for every shape ``p`` and point ``s``, (P, S, 2), one IEEE operation at a time."""
    return A[:, None, :, 0] * pts[None, :, 0, None] + A[:, None, :, 1] * pts[None, :, 1, None]


def _det(A: np.ndarray) -> np.ndarray:
    """Determinants of (P, 2, 2) matrices, one IEEE operation at a time."""
    return A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]


def ellipse_overlap_error(c1, A1, c2, A2, *, chunk: int = 16384) -> np.ndarray:
    """Overlap error ``1 - |E1 ∩ E2| / |E1 ∪ E2|`` of pairs of elliptical patches, element-wise.

    Ellipses ``E = {c + A u : |u| <= 1}`` with centres ``c1, c2`` ``(P, 2)`` and shapes ``A1, A2``
    ``(P, 2, 2)``; the intersection is that of 32-gons of equal area (GEOS), the areas are exact
    ``pi |det A|``. Disjoint bounding circles give exactly 1. Returns ``(P,)`` errors in [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> A = np.eye(2)[None] * 2.0
    >>> err = ellipse_overlap_error([[0.0, 0.0], [0, 0]], np.r_[A, A], [[0.0, 0.0], [10, 0]], np.r_[A, A])
    >>> np.round(err, 6) + 0.0
    array([0., 1.])
    """
    import shapely

    c1, c2 = np.asarray(c1, float).reshape(-1, 2), np.asarray(c2, float).reshape(-1, 2)
    A1, A2 = np.asarray(A1, float).reshape(-1, 2, 2), np.asarray(A2, float).reshape(-1, 2, 2)
    out = np.ones(len(c1))
    near = np.flatnonzero(_bounding_circles(c1, A1, c2, A2)[1])
    for s in range(0, len(near), chunk):
        idx = near[s : s + chunk]
        # Element-wise products, not einsum (FMA on some CPUs) nor LAPACK: the same errors on any CPU.
        p = shapely.polygons(c1[idx, None, :] + _apply(A1[idx], _POLYGON))
        q = shapely.polygons(c2[idx, None, :] + _apply(A2[idx], _POLYGON))
        inter = shapely.area(shapely.intersection(p, q))
        a1 = np.pi * np.abs(_det(A1[idx]))
        a2 = np.pi * np.abs(_det(A2[idx]))
        out[idx] = 1.0 - inter / (a1 + a2 - inter)
    return np.clip(out, 0.0, 1.0)


#: Circumradius of :data:`_POLYGON` (the 32-gon of :func:`ellipse_overlap_error` for the unit disk) and the
#: ratio of its inradius to it: the polygon of a circle of radius r lies between the circles r * these.
_OUTER = float(hypot(*_POLYGON[0]))
_INNER = _OUTER * float(sincos(np.pi / len(_POLYGON))[1])


def _lens_area(r1: np.ndarray, r2: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Area of the intersection of two disks of radii ``r1``, ``r2`` whose centres are ``dist`` apart."""
    out = np.zeros(len(dist))
    inside = dist <= np.abs(r1 - r2)
    out[inside] = np.pi * np.minimum(r1, r2)[inside] ** 2
    cut = np.flatnonzero(~inside & (dist < r1 + r2))
    a, b, t = r1[cut], r2[cut], dist[cut]
    u = np.clip((t * t + a * a - b * b) / (2 * t * a), -1.0, 1.0)
    v = np.clip((t * t + b * b - a * a) / (2 * t * b), -1.0, 1.0)
    k = np.maximum((-t + a + b) * (t + a - b) * (t - a + b) * (t + a + b), 0.0)
    out[cut] = a * a * acos(u) + b * b * acos(v) - 0.5 * np.sqrt(k)
    return out


def circle_overlap_bounds(c1, A1, c2, A2) -> tuple[np.ndarray, np.ndarray]:
    """Bounds ``lo <= e <= hi`` of :func:`ellipse_overlap_error`'s ``e`` for each pair, without polygons.

    For circular patches each 32-gon lies between its in- and circumcircle, so ``e`` lies between two lens
    values. Disjoint bounding circles give ``lo = hi = 1``; non-circular shapes ``(0, 1)``.
    """
    c1, c2 = np.asarray(c1, float).reshape(-1, 2), np.asarray(c2, float).reshape(-1, 2)
    A1, A2 = np.asarray(A1, float).reshape(-1, 2, 2), np.asarray(A2, float).reshape(-1, 2, 2)
    lo, hi = np.zeros(len(c1)), np.ones(len(c1))
    d2, near = _bounding_circles(c1, A1, c2, A2)
    far = ~near  # the function's own test, on the same values: exactly 1
    lo[far] = 1.0
    circle = ((A1[:, 0, 0] == A1[:, 1, 1]) & (A1[:, 0, 1] == -A1[:, 1, 0])
              & (A2[:, 0, 0] == A2[:, 1, 1]) & (A2[:, 0, 1] == -A2[:, 1, 0]))
    idx = np.flatnonzero(circle & ~far)
    if not len(idx):
        return lo, hi
    s1, s2 = np.hypot(A1[idx, 0, 0], A1[idx, 1, 0]), np.hypot(A2[idx, 0, 0], A2[idx, 1, 0])
    dist = np.sqrt(d2[idx])
    # Absolute slack for the rounding of the polygons' vertices (centre + A p) and of the distance.
    tol = 1e-9 * (1.0 + np.abs(c1[idx]).max(axis=1) + np.abs(c2[idx]).max(axis=1) + s1 + s2)
    most = _lens_area(_OUTER * s1 + tol, _OUTER * s2 + tol, np.maximum(dist - tol, 0.0))
    least = _lens_area(np.maximum(_INNER * s1 - tol, 0.0), np.maximum(_INNER * s2 - tol, 0.0), dist + tol)
    area = np.pi * (s1 * s1 + s2 * s2)
    with np.errstate(divide="ignore", invalid="ignore"):
        lo[idx] = np.clip(1.0 - most / (area - most) - 1e-6, 0.0, 1.0)
        hi[idx] = np.clip(1.0 - least / (area - least) + 1e-6, 0.0, 1.0)
    lo[idx[~np.isfinite(lo[idx])]] = 0.0
    return lo, hi
