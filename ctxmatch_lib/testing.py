"""Synthetic match sets with planted inliers and outliers, for tests, benchmarks and examples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import apply_homography  # re-exported: tests and examples use it from here

__all__ = ["PlantedMatches", "planted_homography_matches", "apply_homography"]


@dataclass(frozen=True)
class PlantedMatches:
    """A synthetic match set: ``matches[is_inlier]`` follow ``H``, the rest are uniform outliers."""

    kpts1: np.ndarray  # (N1, 2) (x, y) pixels
    kpts2: np.ndarray  # (N2, 2)
    matches: np.ndarray  # (K, 2) int64
    scores: np.ndarray  # (K,) lower is better
    is_inlier: np.ndarray  # (K,) bool
    H: np.ndarray  # (3, 3) image 1 -> image 2
    image_size: tuple[int, int]  # (width, height) of both images


def planted_homography_matches(
    n_matches: int = 1500,
    inlier_ratio: float = 0.4,
    *,
    noise: float = 0.5,
    image_size: tuple[int, int] = (640, 480),
    H: np.ndarray | None = None,
    informative_scores: bool = False,
    rng=None,
) -> PlantedMatches:
    """One-to-one matches, ``inlier_ratio`` of them moved by ``H`` plus Gaussian ``noise`` (pixels) inside
    both images, the rest uniform; scores uniform in [0, 1], lower for inliers with ``informative_scores``."""
    rng = np.random.default_rng(rng)
    w, h = image_size
    if H is None:
        # A moderate viewpoint change: rotation, scale, shear and a touch of perspective.
        c, s = np.cos(0.15), np.sin(0.15)
        A = np.array([[0.9 * c, -s, 0.0], [s, 1.05 * c, 0.0], [0.0, 0.0, 1.0]])
        P = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [2e-4, -1e-4, 1.0]])
        T1 = np.array([[1.0, 0.0, -w / 2], [0.0, 1.0, -h / 2], [0.0, 0.0, 1.0]])
        T2 = np.array([[1.0, 0.0, w / 2 + 10], [0.0, 1.0, h / 2 - 5], [0.0, 0.0, 1.0]])
        H = T2 @ P @ A @ T1
    n_in = int(round(n_matches * inlier_ratio))
    pts1 = np.empty((0, 2))
    while len(pts1) < n_in:
        cand = rng.uniform([0, 0], [w - 1, h - 1], size=(4 * n_in + 16, 2))
        proj = apply_homography(H, cand)
        ok = (proj[:, 0] >= 0) & (proj[:, 0] <= w - 1) & (proj[:, 1] >= 0) & (proj[:, 1] <= h - 1)
        pts1 = np.vstack([pts1, cand[ok]])
    pts1 = pts1[:n_in]
    # Noise must not push a detection off the image: keypoints are pixel centres in [0, w - 1] x [0, h - 1].
    pts2 = np.clip(apply_homography(H, pts1) + rng.normal(scale=noise, size=pts1.shape), 0, [w - 1, h - 1])
    n_out = n_matches - n_in
    out1 = rng.uniform([0, 0], [w - 1, h - 1], size=(n_out, 2))
    out2 = rng.uniform([0, 0], [w - 1, h - 1], size=(n_out, 2))
    kpts1 = np.vstack([pts1, out1])
    kpts2 = np.vstack([pts2, out2])
    is_inlier = np.r_[np.ones(n_in, bool), np.zeros(n_out, bool)]
    perm = rng.permutation(n_matches)
    kpts1, kpts2, is_inlier = kpts1[perm], kpts2[perm], is_inlier[perm]
    matches = np.repeat(np.arange(n_matches, dtype=np.int64)[:, None], 2, axis=1)
    scores = rng.uniform(size=n_matches)
    if informative_scores:
        scores = np.where(is_inlier, scores * 0.7, 0.3 + scores * 0.7)
    return PlantedMatches(kpts1, kpts2, matches, scores, is_inlier, H, (w, h))
