"""Ground-truth labels (method D and A) on planted synthetic pairs with exact expected labels."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ctxmatch_lib.datasets.base import EpipolarGT, FlowGT, HomographyGT
from ctxmatch_lib.groundtruth import (
    PiecewiseAffineMap,
    label_epipolar,
    label_flow,
    label_homography,
    label_matches,
    localisation_check,
    sample_flow,
)


def _one_to_one(k1, k2):
    k1, k2 = np.asarray(k1, float), np.asarray(k2, float)
    return k1, k2, np.c_[np.arange(len(k1)), np.arange(len(k1))]


# ------------------------------------------------------------------------------------------- planar


def test_homography_labels_exact_both_directions():
    # H halves the image: an error e in image 2 is an error 2e back in image 1.
    H = np.array([[0.5, 0.0, 20.0], [0.0, 0.5, 10.0], [0.0, 0.0, 1.0]])
    k1 = np.array([[100.0, 100.0]] * 5)
    x2 = np.array([70.0, 60.0])  # H @ (100, 100)
    k2 = x2 + np.array([[0.0, 0.0], [7.0, 0.0], [7.5, 0.0], [8.0, 0.0], [0.0, 16.0]])
    # forward errors 0, 7, 7.5, 8, 16; backward errors 0, 14, 15, 16, 32
    k1, k2, m = _one_to_one(k1, k2)
    np.testing.assert_array_equal(label_homography(k1, k2, m, H), [True, True, True, False, False])
    gt = HomographyGT(H)
    np.testing.assert_array_equal(label_matches(k1, k2, m, gt), [True, True, True, False, False])
    # Method A has no planar variant: same labels as D.
    np.testing.assert_array_equal(label_matches(k1, k2, m, gt, method="A"), [True, True, True, False, False])


def test_homography_labels_many_to_many_and_empty():
    H = np.eye(3)
    k1 = np.array([[0.0, 0.0], [100.0, 0.0]])
    k2 = np.array([[3.0, 4.0], [100.0, 20.0], [0.0, 0.0]])
    m = np.array([[0, 0], [0, 2], [1, 1], [0, 1]])
    np.testing.assert_array_equal(label_homography(k1, k2, m, H), [True, True, False, False])
    out = label_homography(k1, k2, np.empty((0, 2), np.int64), H)
    assert out.shape == (0,) and out.dtype == bool


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_homography_labels_symmetric_in_the_images(seed):
    """Swapping the images and inverting H gives the same labels (the reason for "both directions")."""
    rng = np.random.default_rng(seed)
    H = np.array([[1.1, 0.1, 5.0], [-0.05, 0.9, 3.0], [1e-4, 2e-4, 1.0]])
    k1 = rng.uniform(0, 300, (40, 2))
    k2 = rng.uniform(0, 300, (40, 2))
    k2[:20] = (np.c_[k1[:20], np.ones(20)] @ H.T)[:, :2] / (np.c_[k1[:20], np.ones(20)] @ H.T)[:, 2:]
    k2[:20] += rng.normal(scale=10, size=(20, 2))
    m = np.c_[rng.integers(0, 40, 60), rng.integers(0, 40, 60)]
    m[:20] = np.c_[np.arange(20), np.arange(20)]
    a = label_homography(k1, k2, m, H)
    b = label_homography(k2, k1, m[:, ::-1], np.linalg.inv(H))
    np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------------------- non-planar

# Rectified stereo: x2 = x1 - 50 on the hand points, epipolar lines are image rows.
F_RECT = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
HAND1 = np.array([[x, y] for x in (100.0, 200.0, 300.0, 400.0, 500.0) for y in (100.0, 200.0, 300.0, 400.0)])
HAND2 = HAND1 - [50.0, 0.0]
# Grid of 100 px squares split in two: the longest triangle edge is 100 * sqrt(2), radius 70.7 px.


def _epipolar_case():
    x1 = np.array(
        [
            [250.0, 250.0],  # exact
            [250.0, 250.0],  # on the epipolar line, 300 px too far along it
            [250.0, 250.0],  # 20 px off the epipolar line
            [250.0, 250.0],  # on the line, 60 px along it: inside the 70.7 px radius
            [250.0, 250.0],  # on the line, 80 px along it: outside the radius
            [50.0, 250.0],  # 50 px outside the hull, 100 px further out: radius 70.7 + 50 = 120.7
            [50.0, 250.0],  # 50 px outside the hull, 130 px further out
        ]
    )
    x2 = x1 - [50.0, 0.0] + np.array([[0, 0], [300, 0], [0, 20], [60, 0], [80, 0], [-100, 0], [-130, 0]], float)
    return _one_to_one(x1, x2)


def test_epipolar_method_d_and_a_exact():
    k1, k2, m = _epipolar_case()
    d = label_epipolar(k1, k2, m, F_RECT, hand_pts1=HAND1, hand_pts2=HAND2)
    np.testing.assert_array_equal(d, [True, False, False, True, False, True, False])
    a = label_epipolar(k1, k2, m, F_RECT, localise=False)
    np.testing.assert_array_equal(a, [True, True, False, True, True, True, True])
    gt = EpipolarGT(F_RECT, HAND1, HAND2)
    np.testing.assert_array_equal(label_matches(k1, k2, m, gt), d)
    np.testing.assert_array_equal(label_matches(k1, k2, m, gt, method="A"), a)


def test_epipolar_threshold_inclusive_and_both_images():
    k1, k2, m = _one_to_one([[250.0, 250.0], [250.0, 250.0]], [[200.0, 265.0], [200.0, 265.5]])
    np.testing.assert_array_equal(label_epipolar(k1, k2, m, F_RECT, localise=False), [True, False])


def test_epipolar_method_d_needs_hand_points():
    k1, k2, m = _epipolar_case()
    with pytest.raises(ValueError, match="hand_pts1"):
        label_epipolar(k1, k2, m, F_RECT)


def test_piecewise_affine_map_reproduces_global_affine():
    A = np.array([[1.2, 0.1, -30.0], [-0.2, 0.8, 12.0]])
    src = np.random.default_rng(0).uniform(0, 500, (12, 2))
    pam = PiecewiseAffineMap(src, src @ A[:, :2].T + A[:, 2])
    q = np.array([[250.0, 250.0], [-100.0, 40.0], [900.0, 700.0]])  # inside and far outside the hull
    np.testing.assert_allclose(pam(q), q @ A[:, :2].T + A[:, 2], atol=1e-8)
    _, dist = pam.locate(q)
    assert dist[1] > 0 and dist[2] > 0


@pytest.mark.parametrize(
    "src",
    [
        np.empty((0, 2)),
        np.array([[0.0, 0.0]]),
        np.array([[0.0, 0.0], [1.0, 1.0]]),
        np.c_[np.arange(5.0), np.arange(5.0)],
    ],
    ids=["0 points", "1 point", "2 points", "collinear"],
)
def test_piecewise_affine_map_degenerate(src):
    with pytest.raises(ValueError, match="src"):
        PiecewiseAffineMap(src, src)
    # Without a triangulation the localisation check cannot reject anything.
    ok = localisation_check(src, src, [[0.0, 0.0]], [[500.0, 500.0]])
    np.testing.assert_array_equal(ok, [True])


def test_localisation_check_is_two_way():
    # Image 2 is image 1 shrunk 8x: hand triangles have longest edge 141.4 px in image 1 (radius 70.7)
    # and 17.7 px in image 2 (radius clamped to the 15 px minimum).
    hand1, hand2 = HAND1, HAND1 / 8
    x1 = np.array([[250.0, 250.0]])
    # 8 px off in image 2 is 64 px off in image 1: within both radii.
    assert localisation_check(hand1, hand2, x1, x1 / 8 + [8.0, 0.0])[0]
    # 9 px off in image 2 passes there (9 <= 15) but is 72 px off in image 1 (> 70.7): rejected.
    assert not localisation_check(hand1, hand2, x1, x1 / 8 + [9.0, 0.0])[0]
    # Same with the images swapped.
    assert not localisation_check(hand2, hand1, x1 / 8 + [9.0, 0.0], x1)[0]
    assert localisation_check(hand2, hand1, x1 / 8 + [8.0, 0.0], x1)[0]


# --------------------------------------------------------------------------------------------- flow


def test_sample_flow_nearest_pixel_and_outside():
    flow = np.zeros((4, 5, 2))
    flow[2, 3] = [7.0, -1.0]
    out = sample_flow(flow, [[3.2, 1.6], [4.6, 0.0], [-0.6, 0.0]])
    np.testing.assert_array_equal(out[0], [7.0, -1.0])
    assert np.isnan(out[1]).all() and np.isnan(out[2]).all()
    with pytest.raises(ValueError, match="flow"):
        sample_flow(np.zeros((4, 5)), [[0.0, 0.0]])


def test_flow_labels_either_direction():
    h, w = 60, 80
    flow12 = np.tile([10.0, 5.0], (h, w, 1))
    flow12[:, 40:] = np.nan  # occluded right half of image 1
    flow21 = np.tile([-10.0, -5.0], (h, w, 1))
    k1 = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 10.0], [10.0, 10.0], [10.0, 10.0], [200.0, 10.0]])
    k2 = np.array([[25.0, 15.0], [60.0, 15.0], [90.0, 45.0], [20.0, 31.0], [20.0, 30.0], [210.0, 15.0]])
    k1, k2, m = _one_to_one(k1, k2)
    # 0: forward error 5. 1: forward unknown, backward lands exactly. 2: both far.
    # 3: forward 16 px off, backward (10, 26) vs (10, 10): 16 off. 4: both exactly 15 px (inclusive).
    # 5: image-1 keypoint outside the field, image-2 keypoint too.
    expected = [True, True, False, False, True, False]
    np.testing.assert_array_equal(label_flow(k1, k2, m, flow12, flow21), expected)
    np.testing.assert_array_equal(label_matches(k1, k2, m, FlowGT(flow12, flow21)), expected)
    # Only one direction available: the occluded match 1 can no longer be confirmed.
    np.testing.assert_array_equal(label_flow(k1, k2, m, flow12), [True, False, False, False, True, False])


# ------------------------------------------------------------------------------------------ dispatch


def test_label_matches_bad_arguments():
    k = np.zeros((1, 2))
    with pytest.raises(ValueError, match="method"):
        label_matches(k, k, [[0, 0]], HomographyGT(np.eye(3)), method="B")
    with pytest.raises(TypeError, match="gt"):
        label_matches(k, k, [[0, 0]], np.eye(3))
    with pytest.raises(ValueError, match="threshold"):
        label_matches(k, k, [[0, 0]], HomographyGT(np.eye(3)), threshold=0)
    with pytest.raises(ValueError, match="matches"):
        label_matches(k, k, [[0, 3]], HomographyGT(np.eye(3)))
