"""Ground-truth methods B and C (region overlap, Sec. 5.1 and Appendix "Ground truth estimation methods")."""

import numpy as np
import pytest

from ctxmatch_lib.blob.overlap import ellipse_overlap_error
from ctxmatch_lib.datasets.base import EpipolarGT, FlowGT, HomographyGT
from ctxmatch_lib.groundtruth import (
    CENTRE_THRESHOLD_PX,
    GT_METHODS,
    OVERLAP_MAX,
    homography_ellipses,
    label_matches,
    region_errors,
    region_overlap_error,
)


def _circle(r):
    return np.eye(2)[None] * float(r)


def _lens_error(r1, r2, d):
    """Exact overlap error of two disks of radii r1, r2 at distance d."""
    if d >= r1 + r2:
        return 1.0
    if d <= abs(r1 - r2):
        inter = np.pi * min(r1, r2) ** 2
    else:
        a1 = r1**2 * np.arccos((d**2 + r1**2 - r2**2) / (2 * d * r1))
        a2 = r2**2 * np.arccos((d**2 + r2**2 - r1**2) / (2 * d * r2))
        tri = 0.5 * np.sqrt((-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2))
        inter = a1 + a2 - tri
    return 1.0 - inter / (np.pi * (r1**2 + r2**2) - inter)


def test_methods_listed():
    assert set(GT_METHODS) == {"A", "B", "C", "D"}


@pytest.mark.parametrize("r2,d", [(1.0, 0.0), (2.0, 0.0), (1.0, 0.7), (1.5, 1.2), (0.8, 1.9), (1.0, 2.5)])
def test_overlap_of_disks_is_exact(r2, d):
    err = region_overlap_error([[0.0, 0.0]], _circle(1.0), [[d, 0.0]], _circle(r2))
    assert err[0] == pytest.approx(_lens_error(1.0, r2, d), abs=2e-3)


def test_overlap_matches_polygons_near_the_threshold():
    rng = np.random.default_rng(0)
    k = 2000
    ang = rng.uniform(0, np.pi, (2, k))
    ax = rng.uniform(2, 10, (2, k, 2))
    A = []
    for i in range(2):
        c, s = np.cos(ang[i]), np.sin(ang[i])
        R = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
        A.append(R * ax[i][:, None, :])
    c1 = rng.uniform(0, 50, (k, 2))
    c2 = c1 + rng.normal(0, 3, (k, 2))
    ours = region_overlap_error(c1, A[0], c2, A[1])
    ref = ellipse_overlap_error(c1, A[0], c2, A[1])
    assert np.abs(ours - ref).max() < 5e-3
    band = np.abs(ref - 0.5) < 0.2
    assert band.sum() > 100
    assert np.abs(ours - ref)[band].max() < 2e-3


def test_overlap_rejection_keeps_every_value_at_or_below_the_threshold():
    # Labelling skips the integration where a lower bound of the error exceeds reject_above; the errors at or
    # below the threshold are the exact computation's, bit for bit, and every skipped pair is truly above it.
    rng = np.random.default_rng(1)
    k = 3000
    A1 = _circle(1.0) * rng.uniform(2, 10, k)[:, None, None]
    A2 = A1 * rng.uniform(0.4, 2.5, k)[:, None, None] * np.array([1.0, 0.7])[None, None, :]
    c1 = rng.uniform(0, 50, (k, 2))
    c2 = c1 + rng.normal(0, 6, (k, 2))
    exact = region_overlap_error(c1, A1, c2, A2)
    fast = region_overlap_error(c1, A1, c2, A2, reject_above=0.51)
    keep = exact <= 0.51
    np.testing.assert_array_equal(fast[keep], exact[keep])
    skipped = fast != exact
    assert skipped.sum() > 300 and (fast[skipped] == 1.0).all() and (exact[skipped] > 0.51).all()


def test_overlap_empty_and_non_finite():
    assert region_overlap_error(np.empty((0, 2)), np.empty((0, 2, 2)), np.empty((0, 2)), np.empty((0, 2, 2))).shape == (0,)
    err = region_overlap_error([[0.0, 0.0]], np.full((1, 2, 2), np.nan), [[0.0, 0.0]], _circle(1))
    assert err[0] == 1.0


def test_homography_ellipses_exact_image():
    H = np.array([[0.9, 0.1, 30.0], [-0.05, 1.1, 10.0], [1e-4, 5e-5, 1.0]])
    c = np.array([[100.0, 50.0], [300.0, 400.0]])
    A = np.array([[[8.0, 2.0], [-1.0, 5.0]], [[3.0, 0.0], [0.0, 12.0]]])
    q, B = homography_ellipses(H, c, A)
    t = np.linspace(0, 2 * np.pi, 13)
    pts = c[:, None] + np.einsum("kij,tj->kti", A, np.stack([np.cos(t), np.sin(t)], 1))
    h = np.concatenate([pts, np.ones(pts.shape[:2] + (1,))], 2) @ H.T
    x = h[..., :2] / h[..., 2:]
    u = np.einsum("kij,ktj->kti", np.linalg.inv(B), x - q[:, None])
    np.testing.assert_allclose(np.linalg.norm(u, axis=2), 1.0, atol=1e-9)


def test_homography_ellipse_crossing_the_vanishing_line_is_unbounded():
    H = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.01, 0, 1.0]])  # vanishing line x = -100
    q, B = homography_ellipses(H, [[-100.0, 0.0]], _circle(10))
    assert np.isnan(q).all() and np.isnan(B).all()


def _planar_case():
    # H: scale 2 and a translation; a keypoint of radius 5 at (10, 10) maps to radius 10 at (30, 25).
    H = np.array([[2.0, 0, 10.0], [0, 2.0, 5.0], [0, 0, 1.0]])
    k1 = np.array([[10.0, 10.0]])
    s1 = _circle(5.0)
    return H, k1, s1


@pytest.mark.parametrize("r2,expected", [(10.0, 0.0), (10 * np.sqrt(0.6), 0.4), (10 * np.sqrt(0.4), 0.6)])
def test_b_planar_concentric_known_overlap(r2, expected):
    H, k1, s1 = _planar_case()
    k2 = np.array([[30.0, 25.0]])
    err = region_errors(k1, k2, [[0, 0]], HomographyGT(H=H), s1, _circle(r2))
    assert err.overlap[0] == pytest.approx(expected, abs=2e-3)
    lab = label_matches(k1, k2, [[0, 0]], HomographyGT(H=H), method="B", shapes1=s1, shapes2=_circle(r2))
    assert lab[0] == (expected <= OVERLAP_MAX)


@pytest.mark.parametrize("d", [0.0, 5.0, 12.0, 25.0, 45.0])
def test_b_planar_shifted_disks(d):
    H, k1, s1 = _planar_case()
    k2 = np.array([[30.0 + d, 25.0]])
    err = region_errors(k1, k2, [[0, 0]], HomographyGT(H=H), s1, _circle(10.0))
    # Doubled shapes: both regions are disks of radius 20 in image 2.
    assert err.overlap[0] == pytest.approx(_lens_error(20.0, 20.0, d), abs=2e-3)
    assert err.centre[0] == pytest.approx(d)


def test_c_rejects_large_patches_far_apart():
    """The reason for method C (Sec. 5.1): large patches overlap well although the centres are far apart."""
    H = np.eye(3)
    k1, k2 = np.array([[100.0, 100.0]]), np.array([[140.0, 100.0]])
    s = _circle(100.0)
    gt = HomographyGT(H=H)
    assert label_matches(k1, k2, [[0, 0]], gt, method="B", shapes1=s, shapes2=s)[0]
    assert not label_matches(k1, k2, [[0, 0]], gt, method="C", shapes1=s, shapes2=s)[0]


# Non-planar: the hand points are related by x' = L x + t (so the piecewise-affine map is L everywhere) and
# F is the horizontal-stereo one (y2 = y1), which that affine map respects.
L = np.array([[1.5, 0.0], [0.0, 1.0]])
T = np.array([20.0, 0.0])
F_STEREO = np.array([[0.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


def _nonplanar_gt():
    hand1 = np.array([[0.0, 0.0], [200.0, 0.0], [0.0, 200.0], [200.0, 200.0], [90.0, 120.0]])
    return EpipolarGT(F=F_STEREO, pts1=hand1, pts2=hand1 @ L.T + T)


@pytest.mark.parametrize(
    "shape2,expected",
    [
        (L @ _circle(4.0)[0], 0.0),  # the true image of the region
        (np.eye(2) * 4.0, 1.0 - 8.0 / 12.0),  # a radius-8 disk inside the 12 x 8 ellipse (doubled)
        (np.eye(2) * 2.5, 1.0 - 25.0 / 96.0),
    ],
)
def test_b_nonplanar_known_local_affine(shape2, expected):
    k1 = np.array([[50.0, 50.0]])
    k2 = k1 @ L.T + T
    gt = _nonplanar_gt()
    err = region_errors(k1, k2, [[0, 0]], gt, _circle(4.0), shape2[None])
    assert err.overlap[0] == pytest.approx(expected, abs=2e-3)
    np.testing.assert_allclose(err.centres2[0], k2[0], atol=1e-9)
    np.testing.assert_allclose(err.shapes2[0], 2 * L @ _circle(4.0)[0], atol=1e-9)
    assert label_matches(k1, k2, [[0, 0]], gt, method="C", shapes1=_circle(4.0), shapes2=shape2[None])[0] == (
        expected <= OVERLAP_MAX
    )


def test_b_nonplanar_centre_moved_onto_epipolar_line():
    gt = _nonplanar_gt()
    k1 = np.array([[50.0, 50.0]])
    k2 = np.array([[95.0, 53.0]])  # 3 px off its epipolar line y = 50
    err = region_errors(k1, k2, [[0, 0]], gt, _circle(4.0), _circle(4.0))
    np.testing.assert_allclose(err.centres2[0], [95.0, 50.0])
    assert err.centre[0] == pytest.approx(3.0)


def test_b_flow_jacobian_known_affine():
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    flow = np.stack([0.5 * xx + 20.0, np.zeros_like(yy)], axis=2)  # x' = 1.5 x + 20, y' = y
    k1 = np.array([[50.0, 50.0]])
    k2 = k1 @ L.T + T
    err = region_errors(k1, k2, [[0, 0]], FlowGT(flow12=flow), _circle(4.0), np.eye(2)[None] * 4.0)
    assert err.overlap[0] == pytest.approx(1.0 - 8.0 / 12.0, abs=2e-3)
    np.testing.assert_allclose(err.shapes2[0], 2 * L @ _circle(4.0)[0], atol=1e-9)
    # Unknown flow at the keypoint: no overlap, no centre.
    flow[40:60, 40:60] = np.nan
    err = region_errors(k1, k2, [[0, 0]], FlowGT(flow12=flow), _circle(4.0), _circle(4.0))
    assert err.overlap[0] == 1.0 and err.centre[0] == np.inf


def _random_case(kind, rng, n=300):
    k1 = rng.uniform(0, 150, (n, 2))
    s1 = _circle(1.0) * rng.uniform(2, 60, n)[:, None, None]
    if kind == "planar":
        H = np.array([[1.1, 0.05, 5.0], [0.0, 0.9, 3.0], [1e-4, 0, 1.0]])
        h = np.c_[k1, np.ones(n)] @ H.T
        k2, gt = h[:, :2] / h[:, 2:], HomographyGT(H=H)
    elif kind == "nonplanar":
        k2, gt = k1 @ L.T + T, _nonplanar_gt()
    else:
        yy, xx = np.mgrid[0:160, 0:160].astype(float)
        gt = FlowGT(flow12=np.stack([0.5 * xx + 20.0, np.zeros_like(yy)], axis=2))
        k2 = k1 @ L.T + T
    k2 = k2 + rng.normal(0, 25, (n, 2))
    s2 = s1 * rng.uniform(0.5, 2.0, n)[:, None, None]
    m = np.c_[rng.integers(0, n, 3 * n), rng.integers(0, n, 3 * n)]
    m[: 2 * n, 1] = m[: 2 * n, 0]
    return k1, k2, s1, s2, m, gt


@pytest.mark.parametrize("kind", ["planar", "nonplanar", "flow"])
def test_c_is_b_and_centre_constraint(kind):
    k1, k2, s1, s2, m, gt = _random_case(kind, np.random.default_rng(3))
    b = label_matches(k1, k2, m, gt, method="B", shapes1=s1, shapes2=s2)
    c = label_matches(k1, k2, m, gt, method="C", shapes1=s1, shapes2=s2)
    err = region_errors(k1, k2, m, gt, s1, s2)
    np.testing.assert_array_equal(b, err.overlap <= OVERLAP_MAX)
    np.testing.assert_array_equal(c, b & (err.centre <= CENTRE_THRESHOLD_PX))
    assert 0 < c.sum() < b.sum() < len(m)  # the case exercises both constraints


def test_c_is_b_and_centre_constraint_flow_both_directions():
    # Flow pairs with flow21 and unknown (NaN) displacements: the fused labelling pass against region_errors.
    k1, k2, s1, s2, m, gt = _random_case("flow", np.random.default_rng(4))
    flow12 = gt.flow12.copy()
    flow12[40:80, 40:80] = np.nan
    yy, xx = np.mgrid[0:200, 0:260].astype(float)
    flow21 = np.stack([-0.3 * xx - 15.0, np.zeros_like(yy)], axis=2)
    flow21[:60, :60] = np.nan
    gt = FlowGT(flow12=flow12, flow21=flow21)
    b = label_matches(k1, k2, m, gt, method="B", shapes1=s1, shapes2=s2)
    c = label_matches(k1, k2, m, gt, method="C", shapes1=s1, shapes2=s2)
    err = region_errors(k1, k2, m, gt, s1, s2)
    np.testing.assert_array_equal(b, err.overlap <= OVERLAP_MAX)
    np.testing.assert_array_equal(c, b & (err.centre <= CENTRE_THRESHOLD_PX))
    assert 0 < c.sum() < b.sum() < len(m)


@pytest.mark.parametrize("gt", [HomographyGT(H=np.eye(3)), _nonplanar_gt(), FlowGT(flow12=np.zeros((10, 10, 2)))])
@pytest.mark.parametrize("method", ["B", "C"])
def test_empty_inputs(gt, method):
    lab = label_matches(np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2), np.int64), gt, method=method,
                        shapes1=np.empty((0, 2, 2)), shapes2=np.empty((0, 2, 2)))
    assert lab.shape == (0,) and lab.dtype == bool
    k = np.array([[1.0, 1.0]])
    lab = label_matches(k, k, np.empty((0, 2), np.int64), gt, method=method, shapes1=_circle(2), shapes2=_circle(2))
    assert lab.shape == (0,)


def test_radii_accepted_as_shapes():
    H, k1, _ = _planar_case()
    lab = label_matches(k1, [[30.0, 25.0]], [[0, 0]], HomographyGT(H=H), method="B", shapes1=[5.0], shapes2=[10.0])
    assert lab[0]


def test_bad_shapes_name_the_argument():
    k = np.array([[1.0, 1.0], [2.0, 2.0]])
    gt = HomographyGT(H=np.eye(3))
    with pytest.raises(ValueError, match="shapes1"):
        label_matches(k, k, [[0, 0]], gt, method="B")
    with pytest.raises(ValueError, match="shapes2"):
        label_matches(k, k, [[0, 0]], gt, method="C", shapes1=np.ones((2, 2, 2)), shapes2=np.ones((3, 2, 2)))
    with pytest.raises(ValueError, match="shapes1"):
        label_matches(k, k, [[0, 0]], gt, method="C", shapes1=np.ones((2, 3)), shapes2=np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match="method"):
        label_matches(k, k, [[0, 0]], gt, method="E")


@pytest.mark.parametrize("pair_id", ["planar/poster/1-3", "nonplanar/cat"])
def test_engine_labels_with_method_c(pair_id):
    """``evaluate_pair(gt_method="C")`` labels the candidates through ``label_matches`` with the shapes."""
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig
    from ctxmatch_lib.pipeline import evaluate_pair, pair_features

    pair = {p.pair_id: p for p in load_dataset("embedded")}[pair_id]
    f1, f2 = pair_features(pair, FeatureConfig(max_keypoints=300))
    ev = evaluate_pair(pair, filters=[], models=["none"], gt_method="C", precomputed_features=(f1, f2))
    row = ev.rows[0]
    assert row["gt_method"] == "C" and row["n_candidates"] > 0
    stage = next(iter(ev.stages.values()))
    expected = label_matches(f1.kpts, f2.kpts, stage.matches, pair.gt, method="C", shapes1=f1.shapes,
                             shapes2=f2.shapes)
    np.testing.assert_array_equal(stage.labels, expected)
    assert 0 < row["n_gt"] <= expected.sum()
