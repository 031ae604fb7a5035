"""Elliptical patches and their overlap error, for FGINN by overlap (Sec. 3, step 3, Fig. 1b)."""

from __future__ import annotations

import numpy as np

__all__ = ["as_shapes", "shapes_from_scale_angle", "ellipse_overlap_error"]


def shapes_from_scale_angle(scale, angle=None) -> np.ndarray:
    """Affine shapes ``A = scale * R(angle)`` of circular patches of radius ``scale``.

    Parameters
    ----------
    scale : array_like of shape (N,)
        Patch radius in pixels (for OpenCV SIFT, ``keypoint.size / 2``).
    angle : array_like of shape (N,), optional
        Orientation in radians (it does not change a circle, but it is kept in the frame).

    Returns
    -------
    ndarray of shape (N, 2, 2)
        The elliptical patch of keypoint ``k`` is ``{kpts[k] + A[k] @ u : |u| <= 1}``.
    """
    scale = np.asarray(scale, dtype=np.float64).reshape(-1)
    angle = np.zeros_like(scale) if angle is None else np.asarray(angle, dtype=np.float64).reshape(-1)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
    return scale[:, None, None] * rot


def as_shapes(shapes, n: int, name: str) -> np.ndarray:
    """Validate keypoint shapes: ``(N, 2, 2)`` affine shapes, or ``(N,)`` / ``(N, 1)`` radii."""
    arr = np.asarray(shapes, dtype=np.float64)
    if arr.ndim in (1, 2) and arr.shape[0] == n and (arr.ndim == 1 or arr.shape[1] == 1):
        arr = shapes_from_scale_angle(arr.reshape(-1))
    if arr.shape != (n, 2, 2):
        raise ValueError(f"{name} must have shape ({n}, 2, 2) (affine shapes) or ({n},) (radii), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    det = np.abs(np.linalg.det(arr)) if n else np.empty(0)
    if n and not (det > 0).all():
        raise ValueError(f"{name} holds degenerate (zero-area) shapes")
    return arr


def _unit_disk_samples(n: int = 400) -> np.ndarray:
    """Deterministic, evenly spread points in the unit disk (sunflower pattern), equal-area cells."""
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n)
    theta = k * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)


_SAMPLES = _unit_disk_samples()


def ellipse_overlap_error(c1, A1, c2, A2, *, chunk: int = 4096) -> np.ndarray:
    """Overlap error ``1 - |E1 ∩ E2| / |E1 ∪ E2|`` of pairs of elliptical patches, element-wise.

    Ellipse ``E = {c + A u : |u| <= 1}``. The intersection area is a quadrature over 400 evenly spread
    points of each ellipse (the mean of the two one-sided estimates); the absolute error of the result is
    within 0.01 (tested against 2048-gon polygons). Pairs whose bounding circles are disjoint get exactly 1.

    Parameters
    ----------
    c1, c2 : ndarray of shape (P, 2)
        Centres (x, y) in pixels.
    A1, A2 : ndarray of shape (P, 2, 2)
        Affine shapes.

    Returns
    -------
    ndarray of shape (P,)
        Overlap errors in [0, 1].
    """
    c1, c2 = np.asarray(c1, float).reshape(-1, 2), np.asarray(c2, float).reshape(-1, 2)
    A1, A2 = np.asarray(A1, float).reshape(-1, 2, 2), np.asarray(A2, float).reshape(-1, 2, 2)
    out = np.ones(len(c1))
    # Bounding radius of an ellipse = its largest singular value.
    r1 = np.linalg.norm(A1, ord=2, axis=(1, 2))
    r2 = np.linalg.norm(A2, ord=2, axis=(1, 2))
    near = np.flatnonzero(np.sum((c1 - c2) ** 2, axis=1) < (r1 + r2) ** 2)
    for s in range(0, len(near), chunk):
        idx = near[s : s + chunk]
        a1 = np.abs(np.linalg.det(A1[idx]))
        a2 = np.abs(np.linalg.det(A2[idx]))
        f12 = _fraction_inside(c1[idx], A1[idx], c2[idx], A2[idx])  # share of E1 inside E2
        f21 = _fraction_inside(c2[idx], A2[idx], c1[idx], A1[idx])
        inter = 0.5 * (f12 * a1 + f21 * a2)  # areas up to the common factor pi
        union = a1 + a2 - inter
        out[idx] = 1.0 - inter / union
    return np.clip(out, 0.0, 1.0)


def _fraction_inside(ca, Aa, cb, Ab) -> np.ndarray:
    """Share of the quadrature points of ellipse a that fall inside ellipse b."""
    pts = ca[:, None, :] + np.einsum("pij,sj->psi", Aa, _SAMPLES)  # (P, S, 2)
    inv_b = np.linalg.inv(Ab)
    u = np.einsum("pij,psj->psi", inv_b, pts - cb[:, None, :])
    return np.mean(np.sum(u * u, axis=2) <= 1.0, axis=1)
