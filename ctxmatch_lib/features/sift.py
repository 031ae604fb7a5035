"""SIFT (OpenCV's DoG detector and SIFT/RootSIFT descriptors): keypoints, elliptical frames, descriptors."""

from __future__ import annotations

import numpy as np

from .._numerics.fixedmath import sincos
from .base import Features
from .config import FeatureConfig

__all__: list[str] = []


def _shapes(scales: np.ndarray, angles: np.ndarray, radius: float) -> np.ndarray:
    s, c = sincos(angles)  # not np.sin / np.cos, whose last bit follows numpy's SIMD loop
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (N, 2, 2), columns = patch axes
    return rot * (radius * scales)[:, None, None]


def _sift(config: FeatureConfig):
    import cv2

    return cv2.SIFT_create(
        0, int(config.n_octave_layers), float(config.contrast_threshold), float(config.edge_threshold),
        float(config.sigma), bool(config.precise_upscale),
    )


def _keypoint_arrays(kps) -> tuple[np.ndarray, ...]:
    """``(pts, size, angle, |response|, octave)`` of OpenCV keypoints (``octave``: OpenCV's packed field)."""
    pts = np.array([k.pt for k in kps], np.float64).reshape(-1, 2)
    size = np.array([k.size for k in kps], np.float64)
    ang = np.array([k.angle for k in kps], np.float64)
    resp = np.abs(np.array([k.response for k in kps], np.float64))
    octave = np.array([k.octave for k in kps], np.int64)  # compute() reads the pyramid level from it
    return pts, size, ang, resp, octave


def _strongest(pts, size, ang, resp, config: FeatureConfig) -> np.ndarray:
    """Indices of the keypoints strongest first, capped at ``config.max_keypoints``; ties broken by position,
    size and angle, so the order never depends on OpenCV's."""
    order = np.lexsort((ang, size, pts[:, 1], pts[:, 0], -resp))
    return order[: int(config.max_keypoints)] if config.max_keypoints else order


def _sift_detect(gray: np.ndarray, config: FeatureConfig, *, merge: bool):
    """OpenCV SIFT keypoints sorted strongest first and capped; ``merge`` folds orientation duplicates."""
    sift = _sift(config)
    kps = sift.detect(gray, None)
    if not kps:
        return sift, None
    pts, size, ang, resp, octave = _keypoint_arrays(kps)
    if merge:
        ang = np.zeros_like(ang)
        # SIFT duplicates a blob for each secondary orientation peak; without its orientation they are one.
        _, first = np.unique(np.c_[pts, size], axis=0, return_index=True)
        keep = np.sort(first)
        pts, size, ang, resp, octave = pts[keep], size[keep], ang[keep], resp[keep], octave[keep]
    order = _strongest(pts, size, ang, resp, config)
    return sift, (pts[order], size[order], ang[order], resp[order], octave[order])


def _normalise(desc: np.ndarray, root: bool) -> np.ndarray:
    desc = desc.astype(np.float64)
    if root:
        return np.sqrt(desc / np.maximum(desc.sum(1, keepdims=True), 1e-12))
    return desc / np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)


def _described(gray: np.ndarray, config: FeatureConfig, *, upright: bool):
    """The capped keypoints (as :func:`_sift_detect`) and their SIFT descriptors (uint8-valued float32).

    Oriented keypoints are detected and described in one pass over one scale space. OpenCV's ``compute`` on
    a given keypoint set builds its scale space from the lowest octave among them: the one pass gives the same
    descriptors where that octave is the upsampled one (-1), which it is unless upsampling is off or every kept
    keypoint lies higher; then the kept keypoints are described on their own scale space, as ``compute`` does.
    Upright keypoints (angle 0) need a second pass.
    """
    import cv2

    if not upright:
        sift = _sift(config)
        kps, desc = sift.detectAndCompute(gray, None)
        if not kps or desc is None or len(desc) != len(kps):
            return None
        pts, size, ang, resp, octave = _keypoint_arrays(kps)
        order = _strongest(pts, size, ang, resp, config)
        octave_index = (octave[order] & 255).astype(np.int64)
        octave_index = np.where(octave_index < 128, octave_index, octave_index - 256)
        if octave_index.min() < 0:
            return pts[order], size[order], ang[order], resp[order], desc[order]
        det = (pts[order], size[order], ang[order], resp[order], octave[order])
    else:
        sift, det = _sift_detect(gray, config, merge=True)
        if det is None:
            return None
    pts, size, ang, resp, octave = det
    kps = [
        cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o))
        for (x, y), s, a, r, o in zip(pts, size, ang, resp, octave)
    ]
    kps_out, desc = sift.compute(gray, kps)
    if desc is None or not kps_out:
        return None
    if len(kps_out) != len(kps):  # compute() may drop keypoints; re-align on what it kept
        pts, size, ang, resp, _ = _keypoint_arrays(kps_out)
    return pts, size, ang, resp, desc


def _extract_sift(gray: np.ndarray, config: FeatureConfig, *, upright: bool) -> Features:
    """SIFT keypoints described by OpenCV's SIFT at their own orientation (or upright)."""
    det = _described(gray, config, upright=upright)
    if det is None:
        return Features.empty()
    pts, size, ang, resp, desc = det
    desc = _normalise(desc, config.descriptor == "rootsift")
    scales = size / 2.0  # OpenCV's KeyPoint.size is twice the detection sigma
    # OpenCV angles are degrees measured in the image frame (clockwise on screen, y down).
    angles = np.deg2rad(ang)
    angles = np.where(angles > np.pi, angles - 2 * np.pi, angles)
    return Features(
        kpts=np.ascontiguousarray(pts), shapes=_shapes(scales, angles, float(config.patch_radius)),
        desc=np.ascontiguousarray(desc, dtype=np.float32), scales=scales, angles=angles, responses=resp,
    )
