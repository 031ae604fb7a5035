"""HarrisZ (ctxmatch_lib.features.harrisz): exact corners on synthetic images, covariance, presets."""

from __future__ import annotations

import os

import numpy as np
import pytest

from ctxmatch_lib.features import FEATURE_PRESETS, FeatureConfig, extract_features
from ctxmatch_lib.features.harrisz import _ellipses, harrisz


def _smooth_step(t, w=0.7):
    return np.tanh(t / w)


def _checkerboard(size=144, cell=24, offset=12):
    """Smooth checkerboard whose X-junctions sit exactly on pixel centres (x, y ≡ offset mod cell)."""
    y, x = np.mgrid[0:size, 0:size].astype(float)
    sx = _smooth_step(np.sin(np.pi * (x - offset) / cell) * cell / np.pi)
    sy = _smooth_step(np.sin(np.pi * (y - offset) / cell) * cell / np.pi)
    return 127.5 + 127.5 * sx * sy


def _square(size=100, lo=30, hi=70):
    """A bright square with anti-aliased edges through the pixel centres x, y = lo and hi."""
    y, x = np.mgrid[0:size, 0:size].astype(float)
    inside = (1 + _smooth_step(x - lo)) * (1 + _smooth_step(hi - x)) * (1 + _smooth_step(y - lo)) \
        * (1 + _smooth_step(hi - y)) / 16
    return 255 * inside


@pytest.mark.parametrize("level", [3, 4])
def test_checkerboard_junctions_exact(level):
    out = harrisz(_checkerboard(), levels=[level])
    interior = np.array([(x, y) for x in (36, 60, 84, 108) for y in (36, 60, 84, 108)], float)
    # Every interior junction is found exactly (the response is symmetric about it).
    d = np.linalg.norm(out.kpts[:, None] - interior[None], axis=2)
    nearest = d.min(axis=0)
    assert np.all(nearest < 1e-4), nearest  # exact up to float32 rounding
    # And no interior keypoint lies anywhere else.
    inner = np.all((out.kpts > 24) & (out.kpts < 120), axis=1)
    assert inner.sum() == len(interior)


def test_square_corners():
    out = harrisz(_square(), levels=[3])
    assert len(out) == 4
    corners = np.array([[30, 30], [30, 70], [70, 30], [70, 70]], float)
    d = np.linalg.norm(out.kpts[:, None] - corners[None], axis=2)
    assert sorted(d.argmin(axis=1).tolist()) == [0, 1, 2, 3]
    # Harris corners sit inside the corner on its bisector, less than one integration scale away.
    off = out.kpts - corners[d.argmin(axis=1)]
    assert np.allclose(np.abs(off[:, 0]), np.abs(off[:, 1]), atol=1e-6)
    inward = np.sign(50 - corners[d.argmin(axis=1)])
    assert np.all(off * inward > 0) and np.all(np.abs(off) < out.scales[:, None])
    # The four detections are mirror images of each other (exact symmetry of the image).
    assert np.allclose(np.sort(out.kpts[:, 0]), 100 - np.sort(out.kpts[:, 0])[::-1])


def test_empty_and_flat():
    assert len(harrisz(np.zeros((0, 0)))) == 0
    out = harrisz(np.full((64, 64), 7.0))
    assert out.kpts.shape == (0, 2) and out.shapes.shape == (0, 2, 2)
    with pytest.raises(ValueError, match="image"):
        harrisz(np.zeros((4, 4, 4)))


def _texture(n=256, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.normal(size=(2 * n, 2 * n)).astype(np.float32), (0, 0), 3)
    return (base - base.min()) / (base.max() - base.min()) * 255


def _warp(base, T, n=256):
    import cv2

    c, C = np.array([n / 2, n / 2]), np.array([n, n], float)
    Ti = np.linalg.inv(T)
    M = np.c_[Ti, C - Ti @ c]  # output pixel x reads base at Ti (x - c) + C
    return cv2.warpAffine(base, M, (n, n), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)


def test_rotation_by_90_degrees_is_exact():
    img = _texture()[:200, :160]
    a, b = harrisz(img), harrisz(np.rot90(img).copy())
    assert len(a) == len(b) > 50
    # np.rot90 (counter-clockwise on screen): pixel (x, y) -> (y, W - 1 - x).
    W = img.shape[1]
    mapped = np.c_[a.kpts[:, 1], W - 1 - a.kpts[:, 0]]
    P = np.array([[0.0, 1.0], [-1.0, 0.0]])
    ia = np.lexsort((mapped[:, 1], mapped[:, 0], a.levels))
    ib = np.lexsort((b.kpts[:, 1], b.kpts[:, 0], b.levels))
    assert np.allclose(mapped[ia], b.kpts[ib], atol=1e-3)  # float32 blurs: exact up to rounding
    Ea = P @ (a.shapes @ np.swapaxes(a.shapes, 1, 2)) @ P.T
    Eb = b.shapes @ np.swapaxes(b.shapes, 1, 2)
    assert np.allclose(Ea[ia], Eb[ib], rtol=1e-2, atol=1e-2)


@pytest.mark.parametrize("deg", [0, 30, 100])
def test_shapes_follow_a_stretch(deg):
    """Stretching the image by 1.5 along a direction elongates the ellipses along it."""
    base = _texture()
    th = np.deg2rad(deg)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    T = R @ np.diag([1.5, 1 / 1.5]) @ R.T

    def mean_shape(img):
        out = harrisz(img)
        E = out.shapes @ np.swapaxes(out.shapes, 1, 2)
        E = E / np.sqrt(np.linalg.det(E))[:, None, None]
        w, V = np.linalg.eigh(E.mean(axis=0))
        return np.degrees(np.arctan2(V[1, 1], V[0, 1])) % 180, np.sqrt(w[1] / w[0])

    _, iso = mean_shape(_warp(base, np.eye(2)))
    angle, aniso = mean_shape(_warp(base, T))
    assert iso < 1.1
    assert aniso > 1.2
    assert min(abs(angle - deg % 180), 180 - abs(angle - deg % 180)) < 10


def test_ellipses_are_affine_covariant():
    """The ellipse of M^{-1/2} follows x -> T x exactly when M does (M' = T^-T M T^-1)."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        L = rng.normal(size=(2, 2))
        M = L @ L.T + 0.1 * np.eye(2)
        T = rng.normal(size=(2, 2)) + 2 * np.eye(2)
        Ti = np.linalg.inv(T)
        M2 = Ti.T @ M @ Ti
        A1, _ = _ellipses(*M[[0, 1, 0], [0, 1, 1]][:, None], np.ones(1))
        A2, _ = _ellipses(*M2[[0, 1, 0], [0, 1, 1]][:, None], np.ones(1))
        E1 = T @ A1[0] @ A1[0].T @ T.T
        E2 = A2[0] @ A2[0].T
        assert np.allclose(E1 / np.sqrt(np.linalg.det(E1)), E2 / np.sqrt(np.linalg.det(E2)), atol=1e-9)


def test_harrisz_presets_extract(tmp_path):
    from skimage.data import camera

    img = camera()[::2, ::2]
    for name in ("harrisz-rootsift", "harrisz-rootsgloh2"):
        cfg = FEATURE_PRESETS[name]
        f = extract_features(img, cfg, cache_dir=tmp_path)
        assert len(f) > 50
        assert f.shapes.shape == (len(f), 2, 2)
        assert np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-4)
        # Cached round trip keeps the metric.
        g = extract_features(img, cfg, cache_dir=tmp_path)
        assert g.metric == f.metric and np.array_equal(g.desc, f.desc)
    assert extract_features(img, FEATURE_PRESETS["harrisz-rootsgloh2"], cache_dir=False).metric == "sgloh2"
    capped = extract_features(img, FeatureConfig(detector="harrisz", max_keypoints=20), cache_dir=False)
    assert len(capped) == 20


@pytest.mark.realdata
@pytest.mark.slow
def test_repeatability_next_to_sift():
    """Repeatability on Oxford graf 1→2 (known H): reported for HarrisZ next to SIFT, both well above chance."""
    root = os.environ.get("CTXMATCH_DATA")
    if not root or not os.path.isdir(os.path.join(root, "planar", "oxford", "graf")):
        pytest.skip("CTXMATCH_DATA with planar/oxford/graf is not available")
    from ctxmatch_lib.features import load_image

    d = os.path.join(root, "planar", "oxford", "graf")
    im1, im2 = load_image(os.path.join(d, "img1.png")), load_image(os.path.join(d, "img2.png"))
    H = np.loadtxt(os.path.join(d, "H1to2p"))
    rep = {}
    for det in ("sift", "harrisz"):
        cfg = FeatureConfig(detector=det, descriptor="rootsift", max_keypoints=2000)
        f1, f2 = extract_features(im1, cfg, cache_dir=False), extract_features(im2, cfg, cache_dir=False)
        p = np.c_[f1.kpts, np.ones(len(f1))] @ H.T
        p = p[:, :2] / p[:, 2:]
        inside = (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] < im2.shape[1]) & (p[:, 1] < im2.shape[0])
        from scipy.spatial import cKDTree

        dist, _ = cKDTree(f2.kpts).query(p[inside])
        rep[det] = float(np.mean(dist < 3.0))
    print(f"repeatability (3 px) graf 1->2: SIFT {rep['sift']:.2f}, HarrisZ {rep['harrisz']:.2f}")
    assert rep["sift"] > 0.3 and rep["harrisz"] > 0.3
