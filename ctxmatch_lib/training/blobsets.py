"""Training sets like what the learned filters see (Sec. 5.1): the project's blob candidates (:data:`BLOBS`,
:data:`FEATURES`) on generated pairs of scikit-image photos (:func:`make_scene`), labelled by the known warp
within :data:`~ctxmatch_lib.groundtruth.GT_THRESHOLD_PX` (:func:`scene_sets`); never reads ``CTXMATCH_DATA``.
:func:`build_sets` caches one ``.npz`` per scene under ``cache_dir("learned-sets")``, keyed by
:data:`GENERATOR_VERSION`, the seed and the scene index. Overview: ``docs/filters.md``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..filters.learned.data import random_homography
from ..geometry import apply_homography
from ..groundtruth import GT_THRESHOLD_PX

__all__ = ["SOURCE_IMAGES", "FEATURES", "BLOBS", "GENERATOR_VERSION", "BlobSet", "source_images", "make_scene",
           "scene_sets", "build_sets", "load_sets"]

#: scikit-image photos used as training images (bundled with the package: no download). None of them is an
#: evaluation image.
SOURCE_IMAGES = ("astronaut", "camera", "coffee", "chelsea", "rocket", "immunohistochemistry", "coins", "moon",
                 "brick", "grass", "gravel", "cat", "retina", "hubble_deep_field", "cell", "page", "text")
#: Feature presets of the sets (at the paper budget) and blob presets.
FEATURES = ("sift-rootsift", "harrisz-rootsift")
BLOBS = ("baseline", "paper-best-overlap")
MAX_KEYPOINTS = 1500
LONG_SIDE = 1024
#: Range of the strength of the background homography (1: the view changes of :mod:`.data`; the real pairs
#: are wide-baseline: 20 % inliers among the baseline candidates, 12-15 % among the best setup's).
STRENGTH_RANGE = (0.6, 1.8)
#: Bumped whenever the generation changes, so that cached sets are never reused across versions.
GENERATOR_VERSION = 1


@dataclass(frozen=True, eq=False)
class BlobSet:
    """Blob candidates of one generated pair: ``x1[i] <-> x2[i]`` with label ``is_inlier[i]``."""

    x1: np.ndarray  # (K, 2) (x, y) pixels in image 1
    x2: np.ndarray  # (K, 2) in image 2
    scores: np.ndarray  # (K,) blob scores, lower is better
    is_inlier: np.ndarray  # (K,) bool
    size1: tuple[int, int]  # (width, height)
    size2: tuple[int, int]
    kind: str  # "homography" or "layered"
    features: str
    blob: str

    @property
    def inlier_ratio(self) -> float:
        return float(self.is_inlier.mean()) if len(self.is_inlier) else 0.0


# ------------------------------------------------------------------------------------------- images
def source_images() -> list[np.ndarray]:
    """The :data:`SOURCE_IMAGES` as gray uint8, longer side :data:`LONG_SIDE` px (cubic resampling)."""
    import cv2
    import skimage.data

    from ..features import as_gray_uint8

    out = []
    for name in SOURCE_IMAGES:
        g = as_gray_uint8(getattr(skimage.data, name)())
        s = LONG_SIDE / max(g.shape)
        out.append(cv2.resize(g, (round(g.shape[1] * s), round(g.shape[0] * s)), interpolation=cv2.INTER_CUBIC))
    return out


def _photometric(img: np.ndarray, rng) -> np.ndarray:
    import cv2

    f = img.astype(np.float64) / 255.0
    f = np.clip(f * rng.uniform(0.7, 1.3) + rng.uniform(-0.1, 0.1), 0, 1) ** np.exp(rng.normal(0, 0.2))
    sigma = rng.uniform(0, 1.5)
    if sigma > 0.3:
        f = cv2.GaussianBlur(f, (0, 0), sigma)
    f = f + rng.normal(0, rng.uniform(0, 0.02), size=f.shape)
    return np.clip(np.round(f * 255), 0, 255).astype(np.uint8)


def _warp(img, H, size):
    import cv2

    return cv2.warpPerspective(img, H, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _ellipse_mask(size, rng):
    import cv2

    w, h = size
    mask = np.zeros((h, w), np.uint8)
    centre = rng.uniform(0.2, 0.8, size=2) * np.array([w, h])
    axes = rng.uniform(0.1, 0.28, size=2) * min(w, h)
    cv2.ellipse(mask, (int(centre[0]), int(centre[1])), (int(axes[0]), int(axes[1])), rng.uniform(0, 180), 0, 360,
                1, -1)
    return mask


@dataclass(frozen=True)
class Scene:
    """A generated pair: the images and what the ground truth needs (layer maps and homographies)."""

    image1: np.ndarray  # gray uint8
    image2: np.ndarray
    layers1: np.ndarray  # (h1, w1) int: topmost layer at each pixel of image 1 (0 = background)
    layers2: np.ndarray  # (h2, w2) int: topmost layer in image 2, -1 where nothing is seen
    homographies: tuple  # per layer, image 1 -> image 2
    kind: str

    def true_positions(self, pts: np.ndarray) -> np.ndarray:
        """Image-2 position of each image-1 point (NaN: out of view or occluded)."""
        h1, w1 = self.layers1.shape
        ij = np.clip(np.round(pts).astype(np.int64), 0, [w1 - 1, h1 - 1])
        lab = self.layers1[ij[:, 1], ij[:, 0]]
        dest = np.full((len(pts), 2), np.nan)
        for i, H in enumerate(self.homographies):
            sel = lab == i
            if sel.any():
                dest[sel] = apply_homography(H, pts[sel])
        h2, w2 = self.layers2.shape
        inside = np.isfinite(dest[:, 0]) & (dest[:, 0] >= -0.5) & (dest[:, 0] <= w2 - 0.5) & \
            (dest[:, 1] >= -0.5) & (dest[:, 1] <= h2 - 0.5)
        ij2 = np.clip(np.round(np.nan_to_num(dest)).astype(np.int64), 0, [w2 - 1, h2 - 1])
        seen = inside & (self.layers2[ij2[:, 1], ij2[:, 0]] == lab)
        dest[~seen] = np.nan
        return dest


def make_scene(images, rng, kind: str | None = None) -> Scene:
    """One random pair from ``images``: a ``"homography"`` warp, or ``"layered"`` (one to three elliptical
    layers of other photos, each with its own homography, hiding what lies behind); image 2 also gets a
    photometric change. ``kind`` default: either, equally likely."""
    rng = np.random.default_rng(rng)
    kind = kind or ("homography" if rng.uniform() < 0.5 else "layered")
    if kind not in ("homography", "layered"):
        raise ValueError(f"kind must be 'homography' or 'layered', got {kind!r}")
    order = rng.permutation(len(images))
    img1 = images[order[0]].copy()
    h, w = img1.shape
    size = (w, h)
    H0 = random_homography(size, rng, strength=rng.uniform(*STRENGTH_RANGE))
    img2 = _warp(img1, H0, size)
    layers1 = np.zeros((h, w), np.int64)
    layers2 = np.where(_warp(np.ones((h, w), np.uint8), H0, size) > 0, 0, -1).astype(np.int64)
    hs = [H0]
    if kind == "layered":
        for i in range(int(rng.integers(1, 4))):
            fg = images[order[1 + i]]
            # The foreground photo, resized to image 1 and shifted at random, inside an ellipse.
            fg = _warp(fg, np.array([[1, 0, rng.uniform(-0.2, 0.2) * w], [0, 1, rng.uniform(-0.2, 0.2) * h],
                                     [0, 0, 1.0]]), size)
            mask = _ellipse_mask(size, rng)
            Hi = random_homography(size, rng, strength=0.35) @ H0
            Hi[:2] += np.outer(rng.uniform(-0.12, 0.12, size=2) * np.array(size), Hi[2])
            img1 = np.where(mask > 0, fg, img1)
            layers1[mask > 0] = i + 1
            m2 = _warp(mask, Hi, size) > 0
            img2 = np.where(m2, _warp(fg, Hi, size), img2)
            layers2[m2] = i + 1
            hs.append(Hi)
    return Scene(img1, _photometric(img2, rng), layers1, layers2, tuple(hs), kind)


# ------------------------------------------------------------------------------------- candidate sets
def scene_sets(scene: Scene, features=FEATURES, blobs=BLOBS, max_keypoints: int = MAX_KEYPOINTS) -> list[BlobSet]:
    """The blob candidates of ``scene`` for every feature preset and blob preset, labelled by the warp."""
    from ..blob import BLOB_PRESETS
    from ..evaluation.steps import blob_candidates
    from ..features import FEATURE_PRESETS, extract_features

    out = []
    for fname in features:
        cfg = dataclasses.replace(FEATURE_PRESETS[fname], max_keypoints=max_keypoints)
        f1 = extract_features(scene.image1, cfg, cache_dir=False)
        f2 = extract_features(scene.image2, cfg, cache_dir=False)
        dest = scene.true_positions(f1.kpts)
        for bname in blobs:
            matches, scores, _ = blob_candidates(f1, f2, BLOB_PRESETS[bname])
            x1, x2 = f1.kpts[matches[:, 0]], f2.kpts[matches[:, 1]]
            err = np.linalg.norm(x2 - dest[matches[:, 0]], axis=1)
            lab = np.nan_to_num(err, nan=np.inf) <= GT_THRESHOLD_PX
            size1 = (scene.image1.shape[1], scene.image1.shape[0])
            size2 = (scene.image2.shape[1], scene.image2.shape[0])
            out.append(BlobSet(x1, x2, scores, lab, size1, size2, scene.kind, fname, bname))
    return out


def _save(path: Path, sets: list[BlobSet]) -> None:
    from ..cache import atomic_path

    arrays = {}
    meta = []
    for j, s in enumerate(sets):
        arrays.update({f"x1_{j}": s.x1.astype(np.float32), f"x2_{j}": s.x2.astype(np.float32),
                       f"scores_{j}": s.scores.astype(np.float32), f"lab_{j}": s.is_inlier})
        meta.append({"size1": s.size1, "size2": s.size2, "kind": s.kind, "features": s.features, "blob": s.blob})
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, __meta__=np.array(json.dumps(meta)), **arrays)


def _load(path: Path) -> list[BlobSet]:
    with np.load(path) as z:
        meta = json.loads(str(z["__meta__"]))
        return [BlobSet(z[f"x1_{j}"].astype(np.float64), z[f"x2_{j}"].astype(np.float64),
                        z[f"scores_{j}"].astype(np.float64), z[f"lab_{j}"].astype(bool), tuple(m["size1"]),
                        tuple(m["size2"]), m["kind"], m["features"], m["blob"]) for j, m in enumerate(meta)]


def build_sets(n_scenes: int, seed: int = 0, *, cache_dir=None, progress: bool = False) -> list[BlobSet]:
    """The sets (:func:`scene_count` per scene) of scenes ``0 .. n_scenes - 1``, computed once and cached in
    ``cache_dir`` (default ``cache_dir("learned-sets")``). Scene ``i`` draws from ``SeedSequence([seed, i])``,
    so it is the same whatever ``n_scenes``."""
    from ..cache import cache_dir as default_cache_dir

    if not isinstance(n_scenes, (int, np.integer)) or n_scenes < 1:
        raise ValueError(f"n_scenes must be a positive int, got {n_scenes!r}")
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir("learned-sets")
    images = None
    out = []
    it = range(int(n_scenes))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="blob training sets", unit="scene")
    for i in it:
        path = root / f"v{GENERATOR_VERSION}" / f"seed{int(seed)}" / f"scene{i:05d}.npz"
        if not path.is_file():
            images = source_images() if images is None else images
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), i]))
            _save(path, scene_sets(make_scene(images, rng)))
        out.extend(_load(path))
    return out


def load_sets(n_scenes: int, seed: int = 0, *, cache_dir=None) -> list[BlobSet]:
    """Alias of :func:`build_sets` without a progress bar (reads the cache, fills what is missing)."""
    return build_sets(n_scenes, seed, cache_dir=cache_dir)


def scene_count() -> int:
    """Sets per scene: one per (feature preset, blob preset)."""
    return len(FEATURES) * len(BLOBS)


def describe() -> dict:
    """The generator's settings, for the training metadata."""
    return {"version": GENERATOR_VERSION, "images": list(SOURCE_IMAGES), "features": list(FEATURES),
            "blobs": list(BLOBS), "max_keypoints": MAX_KEYPOINTS, "long_side": LONG_SIDE,
            "strength_range": list(STRENGTH_RANGE), "gt_threshold_px": GT_THRESHOLD_PX}
