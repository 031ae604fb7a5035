"""One uncached extraction: the detector, orientation and descriptor of a :class:`.config.FeatureConfig`."""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path

import numpy as np

from .._numerics.fixedmath import opencv_baseline
from ..cache import atomic_path
from .base import Features
from .config import _CACHE_FORMAT, _DEEP, FeatureConfig
from .harrisz import harrisz
from .io import _image_size
from .sift import _extract_sift, _normalise, _shapes, _sift_detect

__all__: list[str] = []


def _extract(gray: np.ndarray, config: FeatureConfig, memo: Path | None = None) -> Features:
    """The features of ``gray`` under ``config``; ``memo``: the folder of :func:`_memo` (``None``: none)."""
    ori = config.resolved_orientation()
    metric = "sgloh2" if config.descriptor == "rootsgloh2" else "l2"
    dim = 256 if metric == "sgloh2" else 128
    # OpenCV's baseline code on every CPU: its SIMD builds and IPP move SIFT's keypoints and descriptors.
    with opencv_baseline():
        if gray.size == 0 or min(gray.shape) < 8:
            feats = Features.empty(dim, metric)
        elif config.detector == "sift" and config.descriptor in ("rootsift", "sift") and ori in ("sift", "none"):
            feats = _extract_sift(gray, config, upright=ori == "none")
        else:
            feats = _extract_patches(gray, config, ori, metric, dim, memo)
    return replace(feats, image_size=_image_size(gray))


def _memo(memo: Path | None, what: str, parts: tuple, compute, check) -> dict:
    """``compute()`` (a dict of arrays), or what a call with the same ``what`` and ``parts`` stored.

    Shares steps between blocks of an image (detections, OriNet angles); ``check`` validates a loaded value.
    """
    if memo is None:
        return compute()
    h = hashlib.sha1(what.encode())
    for part in parts:
        h.update(np.ascontiguousarray(part).tobytes() if isinstance(part, np.ndarray) else repr(part).encode())
        h.update(b"|")
    path = Path(memo) / what / f"{h.hexdigest()}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                hit = {k: z[k] for k in z.files}
            if check(hit):
                return hit
        except Exception:  # a partial or foreign file: recompute and overwrite it
            pass
    out = compute()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **out)
    return out


def _harrisz(gray: np.ndarray, config: FeatureConfig, memo: Path | None):
    """HarrisZ's (kpts, scales, responses, shapes), shared by the four HarrisZ blocks of an image."""

    def compute():
        hz = harrisz(gray, patch_radius=float(config.patch_radius), max_keypoints=int(config.max_keypoints))
        return {"kpts": hz.kpts, "scales": hz.scales, "responses": hz.responses, "shapes": hz.shapes}

    n_ok = lambda d: len({len(d[k]) for k in ("kpts", "scales", "responses", "shapes")}) == 1  # noqa: E731
    out = _memo(memo, f"harrisz-v{_CACHE_FORMAT}-blas_independent",
                (gray.shape, gray, float(config.patch_radius), int(config.max_keypoints)), compute, n_ok)
    return out["kpts"], out["scales"], out["responses"], out["shapes"]


_DETECTION = ("pts", "size", "ang", "resp", "octave")


def _sift_merged(gray: np.ndarray, config: FeatureConfig, memo: Path | None):
    """SIFT's detections with orientation duplicates merged, shared by the patch-described SIFT blocks."""

    def compute():
        _, det = _sift_detect(gray, config, merge=True)
        if det is None:
            return {"pts": np.empty((0, 2)), "size": np.empty(0), "ang": np.empty(0), "resp": np.empty(0),
                    "octave": np.empty(0, np.int64)}
        return dict(zip(_DETECTION, det))

    parts = (gray.shape, gray, int(config.n_octave_layers), float(config.contrast_threshold),
             float(config.edge_threshold), float(config.sigma), bool(config.precise_upscale), config.max_keypoints)
    n_ok = lambda d: len({len(d[k]) for k in _DETECTION}) == 1  # noqa: E731
    out = _memo(memo, f"sift-merged-v{_CACHE_FORMAT}", parts, compute, n_ok)
    return tuple(out[k] for k in _DETECTION) if len(out["pts"]) else None


def _orinet(gray: np.ndarray, pts: np.ndarray, base: np.ndarray, config: FeatureConfig, memo: Path | None):
    """OriNet's angles of the frames ``base`` at ``pts``, shared by the HardNet2 and SOSNet blocks."""
    from .deep import orinet_angles, weights_digest

    def compute():
        return {"angles": orinet_angles(gray, pts, base, weights=config.orinet_weights, support=config.support)}

    if config.orinet_weights is None:  # kornia's published weights run in torch: not kept
        memo = None
    parts = (gray.shape, gray, np.asarray(pts, np.float64), np.asarray(base, np.float64), float(config.support),
             weights_digest(config.orinet_weights, "orinet_weights"))
    return _memo(memo, "orinet-angles", parts, compute, lambda d: d["angles"].shape == (len(pts),))["angles"]


def _extract_patches(gray: np.ndarray, config: FeatureConfig, ori: str, metric: str, dim: int,
                     memo: Path | None = None) -> Features:
    """Any detector, orientation and descriptor through affine-normalised patches."""
    from .patches import dominant_orientation, rotation_shapes, sift_from_patches

    if config.detector == "sift":
        det = _sift_detect(gray, config, merge=False)[1] if ori == "sift" else _sift_merged(gray, config, memo)
        if det is None:
            return Features.empty(dim, metric)
        pts, size, ang, resp, _ = det
        scales = size / 2.0
        angles = np.deg2rad(ang) if ori == "sift" else np.zeros(len(pts))
        angles = np.where(angles > np.pi, angles - 2 * np.pi, angles)
        base = _shapes(scales, np.zeros(len(pts)), float(config.patch_radius))
    else:
        pts, scales, resp, base = _harrisz(gray, config, memo)
        if len(pts) == 0:
            return Features.empty(dim, metric)
        angles = np.zeros(len(pts))
    if ori == "dominant":
        angles = dominant_orientation(gray, pts, base, support=config.support)
    elif ori == "orinet":
        angles = _orinet(gray, pts, base, config, memo)
    shapes = rotation_shapes(base, angles)
    if config.descriptor == "rootsgloh2":
        from .sgloh import sgloh_descriptors

        desc = sgloh_descriptors(gray, pts, base, support=config.support)
    elif config.descriptor in _DEEP:
        from .deep import deep_descriptors

        desc = deep_descriptors(gray, pts, shapes, descriptor=config.descriptor, net=config.net,
                                weights=config.weights, support=config.support)
    else:
        desc = _normalise(sift_from_patches(gray, pts, shapes, support=config.support),
                          config.descriptor == "rootsift")
    return Features(
        kpts=np.ascontiguousarray(pts, dtype=np.float64), shapes=np.ascontiguousarray(shapes, dtype=np.float64),
        desc=np.ascontiguousarray(desc, dtype=np.float32), scales=np.asarray(scales, np.float64),
        angles=np.asarray(angles, np.float64), responses=np.asarray(resp, np.float64), metric=metric,
    )
