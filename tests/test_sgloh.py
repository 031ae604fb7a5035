"""RootsGLOH2 (ctxmatch_lib.features.sgloh) and blob matching's distance hook."""

from __future__ import annotations

import numpy as np
import pytest

from ctxmatch_lib.blob import BlobContext, blob_matching
from ctxmatch_lib.features import Features, descriptor_distance
from ctxmatch_lib.features.sgloh import (
    SGLOH_DIM, SGLOH2Distance, sgloh_descriptors, sgloh_distance_matrix, sgloh_from_patches, sgloh_rotate,
)


def _patches(n=6, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 43, 43)).astype(np.float32)
    return np.stack([cv2.GaussianBlur(q, (0, 0), 1.5) for q in p]) * 100


def _descs(n, seed):
    return sgloh_from_patches(_patches(n, seed))


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rot90_of_the_patch_is_a_permutation(k):
    p = _patches()
    d = sgloh_from_patches(p)
    # np.rot90 turns the content by -90° in φ = atan2(y, x) (y down): four steps of π/8 back.
    r = sgloh_from_patches(np.rot90(p, k, axes=(1, 2)).copy())
    assert np.allclose(r, sgloh_rotate(d, -4 * k), atol=1e-5)
    assert not np.allclose(r, d, atol=1e-3)


def test_rotate_composes_and_cycles():
    d = _descs(3, 1)
    assert np.array_equal(sgloh_rotate(d, 16), d)
    assert np.array_equal(sgloh_rotate(sgloh_rotate(d, 5), 7), sgloh_rotate(d, 12))
    # A permutation: same multiset of values.
    assert np.array_equal(np.sort(sgloh_rotate(d, 3), axis=1), np.sort(d, axis=1))


@pytest.mark.parametrize("a", range(16))
def test_distance_is_zero_under_every_discrete_rotation(a):
    d = _descs(4, 2)
    D = SGLOH2Distance()(d, sgloh_rotate(d, a))
    assert np.allclose(np.diag(D), 0, atol=2e-3)  # float32 GEMM: sqrt of a rounding-level residue
    other = _descs(4, 3)
    assert np.allclose(SGLOH2Distance()(d, sgloh_rotate(other, a)), SGLOH2Distance()(d, other), atol=1e-4)


def test_hook_equals_brute_force():
    d1, d2 = _descs(7, 4), _descs(5, 5)
    D = SGLOH2Distance()(d1, d2)
    assert D.shape == (7, 5) and D.dtype == np.float32
    assert np.allclose(D, sgloh_distance_matrix(d1, d2), atol=2e-4)
    sub = SGLOH2Distance(rotations=[0, 1, 15])
    assert np.allclose(sub(d1, d2), sgloh_distance_matrix(d1, d2, rotations=[0, 1, 15]), atol=2e-4)
    assert np.all(sub(d1, d2) >= D - 1e-6)


def test_rootsift_normalisation():
    p = _patches(5, 6)
    root, plain = sgloh_from_patches(p), sgloh_from_patches(p, root=False)
    for k in range(2):
        h_root = root[:, k * 128 : (k + 1) * 128].astype(np.float64)
        h_plain = plain[:, k * 128 : (k + 1) * 128].astype(np.float64)
        assert np.all(h_root >= 0)
        assert np.allclose((h_root ** 2).sum(1), 0.5, atol=1e-5)  # each half: L2 norm 1/sqrt(2)
        # Square rooting of the L1-normalised histogram: squares give back the histogram's proportions.
        assert np.allclose(h_root ** 2 / (h_root ** 2).sum(1, keepdims=True),
                           h_plain / h_plain.sum(1, keepdims=True), atol=1e-5)


def test_empty_and_bad_input():
    assert sgloh_from_patches(np.zeros((0, 43, 43))).shape == (0, SGLOH_DIM)
    assert np.all(sgloh_from_patches(np.ones((2, 43, 43))) == 0)  # flat patch: no gradient
    with pytest.raises(ValueError, match="patches"):
        sgloh_from_patches(np.zeros((2, 41, 41)))
    assert SGLOH2Distance()(np.zeros((0, SGLOH_DIM)), _descs(3, 7)).shape == (0, 3)
    with pytest.raises(ValueError, match="rotations"):
        SGLOH2Distance(rotations=[])
    assert sgloh_descriptors(np.zeros((32, 32)), np.empty((0, 2)), np.empty((0, 2, 2))).shape == (0, SGLOH_DIM)


def test_rotated_image_is_found_at_the_right_rotation():
    """A 45° turn of the image about a keypoint is the discrete rotation of ±2 steps, the closest one."""
    import cv2

    rng = np.random.default_rng(8)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (200, 200)).astype(np.float32), (0, 0), 2.0)
    c = np.array([[99.5, 99.5]])
    A = np.eye(2)[None] * 12.0
    rot = cv2.warpAffine(img, cv2.getRotationMatrix2D((99.5, 99.5), 45, 1.0), (200, 200),
                         flags=cv2.INTER_CUBIC)
    d1, d2 = sgloh_descriptors(img, c, A), sgloh_descriptors(rot, c, A)
    dists = [np.linalg.norm(d1[0, :128] - sgloh_rotate(d2, a)[0, :128]) for a in range(16)]
    # getRotationMatrix2D turns counter-clockwise on screen, i.e. φ decreases: undo with +2 steps.
    assert int(np.argmin(dists)) == 2
    assert min(dists) < 0.5 * np.median(dists)


def test_blob_matching_with_the_hook_equals_precomputed():
    rng = np.random.default_rng(9)
    d1, d2 = _descs(40, 10), _descs(35, 11)
    d2[:20] = sgloh_rotate(d1[:20], 5) + rng.normal(0, 0.01, (20, SGLOH_DIM)).astype(np.float32)
    k1, k2 = rng.uniform(0, 100, (40, 2)), rng.uniform(0, 100, (35, 2))
    for kw in ({"f": 3, "prefilter": "cup", "f_prime": 2, "ratio": "D+", "t_o": 10.0},
               {"f": "omega", "f_prime": 1, "ratio": "D>=", "t_o": None},
               {"f": 5, "prefilter": "cap", "f_prime": 5, "ratio": "D+>=", "t_o": 5.0}):
        hook = blob_matching(d1, d2, kpts1=k1, kpts2=k2, distance=SGLOH2Distance(), **kw)
        ref = blob_matching(distances=sgloh_distance_matrix(d1, d2), kpts1=k1, kpts2=k2, **kw)
        assert np.array_equal(hook.matches, ref.matches)
        assert np.allclose(hook.scores, ref.scores, atol=1e-4)
    # The rotated copies are matched to their originals first.
    out = blob_matching(d1, d2, kpts1=k1, kpts2=k2, distance=SGLOH2Distance(), f=1, f_prime=1, t_o=None)
    top = {tuple(m) for m in out.matches[:10].tolist()}
    assert top <= {(i, i) for i in range(20)}
    with pytest.raises(ValueError, match="distance"):
        blob_matching(distances=np.ones((2, 2)), distance=SGLOH2Distance())


def test_hook_is_called_on_row_blocks_only():
    """The hook keeps BlobContext's memory bound: it only ever sees row blocks, or a few rows/columns."""
    d1, d2 = _descs(200, 12), _descs(180, 13)
    calls = []
    hook = SGLOH2Distance()

    def spy(a, b):
        calls.append((len(a), len(b)))
        return hook(a, b)

    ctx = BlobContext(d1, d2, distance=spy, depth=5, keep_dense=False, block_bytes=32 * 180 * 4)
    assert len(calls) > 2 and all(r <= 32 or c <= 8 for r, c in calls)
    assert max(r * c for r, c in calls) <= 32 * 180
    ref = BlobContext(distances=hook(d1, d2), depth=5)  # the whole matrix in one call
    assert np.array_equal(ctx.rows.idx, ref.rows.idx) and np.array_equal(ctx.cols.idx, ref.cols.idx)
    # float32 GEMMs of other shapes round differently in the last bits.
    assert np.allclose(ctx.rows.val, ref.rows.val, atol=1e-5) and np.allclose(ctx.cols.val, ref.cols.val, atol=1e-5)
    # Whole rows and columns (the rare second-best look-ups) come from the hook too.
    assert np.allclose(ctx._lines(1, np.array([3, 7])), ref._lines(1, np.array([3, 7])), atol=1e-5)


def test_features_carry_their_distance():
    assert descriptor_distance("l2") is None
    assert isinstance(descriptor_distance("sgloh2"), SGLOH2Distance)
    assert isinstance(Features.empty(256, "sgloh2").distance(), SGLOH2Distance)
    assert Features.empty().distance() is None
    with pytest.raises(ValueError, match="metric"):
        descriptor_distance("cosine")
