"""Training correspondences the project generates itself (numpy only), for the learned filters trained here.

SIFT keypoints of the embedded images (:func:`keypoint_pool`; never ``CTXMATCH_DATA``) moved by a random
homography or layered scene with occlusion (:func:`random_training_set`); 0.3-2.5 px inlier noise; outliers
uniform, on other keypoints, or near misses 20-100 px off; 5-60 % inliers, labelled by
:data:`~ctxmatch_lib.groundtruth.GT_THRESHOLD_PX`; scores of random informativeness ``q`` (inliers
``u ** (1 + 3q)``, outliers ``u ** (1 / (1 + 3q))``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ...geometry import hartley_normalise as _hartley
from ...geometry import apply_homography
from ...groundtruth import GT_THRESHOLD_PX

__all__ = ["TrainingSet", "keypoint_pool", "random_training_set", "normalise_coordinates", "score_rank",
           "network_input"]

INLIER_RATIO_RANGE = (0.05, 0.60)
NOISE_RANGE_PX = (0.3, 2.5)
NEAR_MISS_RANGE_PX = (20.0, 100.0)


@dataclass(frozen=True)
class TrainingSet:
    """One generated candidate set: ``x1[i] <-> x2[i]`` with label ``is_inlier[i]``."""

    x1: np.ndarray  # (K, 2) (x, y) pixels in image 1
    x2: np.ndarray  # (K, 2) in image 2
    scores: np.ndarray  # (K,) lower is better
    is_inlier: np.ndarray  # (K,) bool
    image_size: tuple[int, int]  # (width, height) of both images
    kind: str  # "homography" or "layered"


# ----------------------------------------------------------------------------------- network input
def normalise_coordinates(pts: np.ndarray, image_size, mode: str = "image") -> np.ndarray:
    """Keypoints (K, 2) in the coordinates the networks read (float64).

    Parameters
    ----------
    pts, image_size : ndarray of shape (K, 2), (int, int)
        (x, y) pixels (origin at the centre of the top-left pixel) and their image's (width, height).
    mode : {"image", "hartley"}
        ``"image"`` (weights trained here): the longer side spans [-1, 1]; ``"hartley"`` (OANet authors'
        demo): zero mean, mean distance sqrt(2).

    Examples
    --------
    >>> normalise_coordinates(np.array([[-0.5, -0.5], [319.5, 239.5]]), (640, 480)).tolist()
    [[-1.0, -0.75], [0.0, 0.0]]
    """
    pts = np.asarray(pts, np.float64)
    if mode == "image":
        w, h = image_size
        return (pts + 0.5 - np.array([w, h]) / 2.0) / (max(w, h) / 2.0)
    if mode == "hartley":
        return _hartley(pts.reshape(-1, 2))[0]
    raise ValueError(f"normalization must be 'image' or 'hartley', got {mode!r}")


def score_rank(scores: np.ndarray) -> np.ndarray:
    """Scores (lower is better) as their average rank scaled to [0, 1] (0 best); all equal -> 0.5.

    Examples
    --------
    >>> score_rank(np.array([0.3, 0.1, 0.3, 0.9])).tolist()
    [0.5, 0.0, 0.5, 1.0]
    """
    s = np.asarray(scores, np.float64)
    k = len(s)
    if k <= 1:
        return np.full(k, 0.5)
    order = np.argsort(s, kind="stable")
    sorted_s = s[order]
    # Average rank of ties, so that equal scores get equal inputs whatever their order.
    starts = np.r_[0, np.flatnonzero(sorted_s[1:] != sorted_s[:-1]) + 1]
    ends = np.r_[starts[1:], k]
    avg = (starts + ends - 1) / 2.0
    ranks = np.empty(k)
    ranks[order] = np.repeat(avg, ends - starts)
    return ranks / (k - 1)


def network_input(x1, x2, scores, size1, size2, *, normalization: str = "image", side: str = "none") -> np.ndarray:
    """The ``(C, K)`` float32 input of a network: normalised x1, y1, x2, y2, then the side channels.

    ``side``: ``"none"``, ``"score_rank"`` (OANet trained here) or ``"ratio_mutual"`` (the OANet authors'
    models: the score as ratio-test value, 1 as mutual-check flag).
    """
    a = normalise_coordinates(x1, size1, normalization)
    b = normalise_coordinates(x2, size2, normalization)
    chans = [a[:, 0], a[:, 1], b[:, 0], b[:, 1]]
    s = np.zeros(len(a)) if scores is None else np.asarray(scores, np.float64)
    if side == "score_rank":
        chans.append(score_rank(s))
    elif side == "ratio_mutual":
        chans += [s, np.ones(len(a))]
    elif side != "none":
        raise ValueError(f"side must be 'none', 'score_rank' or 'ratio_mutual', got {side!r}")
    return np.stack(chans).astype(np.float32)


# ------------------------------------------------------------------------------------ keypoint pool
@lru_cache(maxsize=4)
def keypoint_pool(max_images: int | None = None, max_keypoints: int = 3000) -> tuple:
    """SIFT keypoint positions of the embedded images, in pair order: a tuple of ``(points (M, 2), (w, h))``."""
    import cv2

    from ...datasets import load_dataset
    from ...features import load_image

    paths = list(dict.fromkeys(p for pair in load_dataset("embedded") for p in (pair.image1, pair.image2)))
    if max_images is not None:
        paths = paths[:max_images]
    # A low contrast threshold: dense pools, so that sets of 2000 candidates at 60 % inliers can be drawn.
    sift = cv2.SIFT_create(nfeatures=max_keypoints, contrastThreshold=0.01)
    pool = []
    for p in paths:
        gray = load_image(p, gray=True)
        kps = sift.detect(gray, None)
        pts = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
        pts = np.unique(np.round(pts, 2), axis=0)  # orientations duplicate positions
        pool.append((pts, (gray.shape[1], gray.shape[0])))
    return tuple(pool)


# ------------------------------------------------------------------------------------------ geometry
def random_homography(size, rng, strength: float = 1.0) -> np.ndarray:
    w, h = size
    rot = rng.uniform(-np.pi / 6, np.pi / 6) * strength
    if rng.uniform() < 0.1 * strength:
        rot = rng.uniform(-np.pi, np.pi)  # now and then an arbitrary rotation
    zoom = np.exp(rng.uniform(np.log(0.6), np.log(1.6)) * strength)
    aniso = np.exp(rng.normal(0, 0.1 * strength))
    shear = rng.normal(0, 0.1 * strength)
    c, s = np.cos(rot), np.sin(rot)
    A = np.array([[c, -s], [s, c]]) @ np.array([[zoom * aniso, shear], [0, zoom / aniso]])
    persp = rng.normal(0, 4e-4 * strength, size=2) * (640.0 / max(w, h))
    shift = rng.uniform(-0.15, 0.15, size=2) * np.array([w, h]) * strength
    T1 = np.array([[1, 0, -(w - 1) / 2], [0, 1, -(h - 1) / 2], [0, 0, 1.0]])
    M = np.eye(3)
    M[:2, :2] = A
    M[2, :2] = persp
    T2 = np.array([[1, 0, (w - 1) / 2 + shift[0]], [0, 1, (h - 1) / 2 + shift[1]], [0, 0, 1.0]])
    return T2 @ M @ T1


def _inside(p, size):
    w, h = size
    return (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)


def _ellipse(size, rng):
    w, h = size
    centre = rng.uniform(0.25, 0.75, size=2) * np.array([w, h])
    radii = rng.uniform(0.12, 0.3, size=2) * min(w, h)
    ang = rng.uniform(0, np.pi)
    return centre, radii, ang


def _in_ellipse(p, ell):
    centre, radii, ang = ell
    c, s = np.cos(ang), np.sin(ang)
    d = p - centre
    u = (c * d[:, 0] + s * d[:, 1]) / radii[0]
    v = (-s * d[:, 0] + c * d[:, 1]) / radii[1]
    return u**2 + v**2 <= 1


def _layer_polygon(ell, H, n: int = 48):
    centre, radii, ang = ell
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(ang), np.sin(ang)
    xy = np.c_[radii[0] * np.cos(t), radii[1] * np.sin(t)] @ np.array([[c, s], [-s, c]]) + centre
    return apply_homography(H, xy)


def _true_positions(pts, size, rng, kind):
    """Image-2 position of every pool point under a random geometry (NaN: out of view or occluded)."""
    from matplotlib.path import Path as MplPath

    H0 = random_homography(size, rng)
    dest = apply_homography(H0, pts)
    if kind == "layered":
        labels = np.zeros(len(pts), np.int64)
        layers = []
        for i in range(rng.integers(1, 3)):
            ell = _ellipse(size, rng)
            Hi = random_homography(size, rng, strength=0.35) @ H0
            # The foreground moves on its own: an extra shift of up to 12 % of the image on top of H0.
            Hi[:2] += np.outer(rng.uniform(-0.12, 0.12, size=2) * np.array(size), Hi[2])
            inside = _in_ellipse(pts, ell)
            labels[inside] = i + 1
            dest[inside] = apply_homography(Hi, pts[inside])
            layers.append((ell, Hi))
        # Occlusion: a point is hidden in image 2 by any layer above its own that covers its destination.
        for i, (ell, Hi) in enumerate(layers):
            poly = MplPath(_layer_polygon(ell, Hi))
            hidden = (labels < i + 1) & poly.contains_points(dest)
            dest[hidden] = np.nan
    dest[~_inside(np.nan_to_num(dest, nan=-1.0), size)] = np.nan
    return dest


def random_training_set(pool, n_candidates: int, rng=None, *, kind: str | None = None,
                        inlier_ratio: float | None = None) -> TrainingSet:
    """One generated :class:`TrainingSet` of ``n_candidates`` rows from ``pool`` (:func:`keypoint_pool`).

    ``kind`` (default: either) and ``inlier_ratio`` (default: uniform in 5-60 %) fix those draws.
    """
    rng = np.random.default_rng(rng)
    kind = kind or ("homography" if rng.uniform() < 0.5 else "layered")
    if kind not in ("homography", "layered"):
        raise ValueError(f"kind must be 'homography' or 'layered', got {kind!r}")
    ratio = rng.uniform(*INLIER_RATIO_RANGE) if inlier_ratio is None else float(inlier_ratio)
    k = int(n_candidates)
    for _ in range(20):
        pts, size = pool[rng.integers(len(pool))]
        dest = _true_positions(pts, size, rng, kind)
        ok = np.flatnonzero(np.isfinite(dest[:, 0]))
        if len(ok) >= max(8, round(ratio * k)):
            break
    n_in = min(int(round(ratio * k)), len(ok))
    noise = rng.uniform(*NOISE_RANGE_PX)
    sel = rng.choice(ok, size=n_in, replace=False)
    x1_in = pts[sel]
    x2_in = dest[sel] + rng.normal(0, noise, size=(n_in, 2))

    n_out = k - n_in
    mix = rng.dirichlet(np.ones(3))
    counts = rng.multinomial(n_out, mix)
    w, h = size
    # (a) uniform position in image 2
    ia = rng.integers(len(pts), size=counts[0])
    a1 = pts[ia]
    a2 = rng.uniform([0, 0], [w - 1, h - 1], size=(counts[0], 2))
    # (b) another keypoint's position in image 2
    ib = rng.integers(len(pts), size=counts[1])
    b1 = pts[ib]
    b2 = dest[ok[rng.integers(len(ok), size=counts[1])]] + rng.normal(0, noise, size=(counts[1], 2))
    # (c) near miss of a true correspondence, sharing its image-1 keypoint
    src = ok[rng.integers(len(ok), size=counts[2])]
    r = rng.uniform(*NEAR_MISS_RANGE_PX, size=counts[2])
    t = rng.uniform(0, 2 * np.pi, size=counts[2])
    c1 = pts[src]
    c2 = np.clip(dest[src] + np.c_[r * np.cos(t), r * np.sin(t)], 0, [w - 1, h - 1])

    x1 = np.vstack([x1_in, a1, b1, c1])
    x2 = np.vstack([x2_in, a2, b2, c2])
    # Labels by the evaluation's rule: within the ground-truth threshold of the true position.
    true2 = np.vstack([dest[sel], dest[ia], dest[ib], dest[src]])
    err = np.linalg.norm(x2 - true2, axis=1)
    is_inlier = np.isfinite(err) & (np.nan_to_num(err, nan=np.inf) <= GT_THRESHOLD_PX)

    q = rng.uniform()
    u = rng.uniform(size=k)
    scores = np.where(is_inlier, u ** (1 + 3 * q), u ** (1 / (1 + 3 * q)))
    if rng.uniform() < 0.1:
        scores = np.zeros(k)
    perm = rng.permutation(k)
    return TrainingSet(x1[perm], x2[perm], scores[perm], is_inlier[perm], (int(w), int(h)), kind)

