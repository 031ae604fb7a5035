"""OpenCV and kornia interop: exact round trips, the explicit LAF scale convention, the cv2-list errors of the
public API, and a cross-check of our AdaLAM against kornia's on an embedded pair."""

import cv2
import numpy as np
import pytest

from ctxmatch_lib import BLOB_PRESETS, FILTERS, blob_matching
from ctxmatch_lib.features import FeatureConfig, extract_features
from ctxmatch_lib.io.interop import (
    from_cv2_keypoints,
    from_cv2_matches,
    from_kornia_lafs,
    match_blob,
    to_cv2_keypoints,
    to_cv2_matches,
    to_kornia_lafs,
)


def _kp_tuple(k):
    return (k.pt[0], k.pt[1], k.size, k.angle, k.response)


@pytest.fixture(scope="module")
def sift_kps():
    from skimage.data import camera

    kps = cv2.SIFT_create(300).detect(camera()[::2, ::2], None)
    assert len(kps) > 100
    return list(kps) + [cv2.KeyPoint(3.25, 4.5, 7.0, -1.0, 0.125)]  # one without orientation


def test_cv2_keypoints_round_trip_exact(sift_kps):
    kpts, shapes, angles, resp = from_cv2_keypoints(sift_kps)
    n = len(sift_kps)
    assert kpts.shape == (n, 2) and shapes.shape == (n, 2, 2) and angles.shape == resp.shape == (n,)
    assert np.isnan(angles[-1]) and not np.isnan(angles[:-1]).any()
    assert np.all(np.abs(angles[:-1]) <= np.pi)
    back = to_cv2_keypoints(kpts, shapes, angles=angles, responses=resp)
    assert [_kp_tuple(k) for k in back] == [_kp_tuple(k) for k in sift_kps]
    # From the shapes alone: position, size and orientation are exact too (OpenCV stores float32).
    alone = to_cv2_keypoints(kpts, shapes)
    assert [_kp_tuple(k)[:4] for k in alone[:-1]] == [_kp_tuple(k)[:4] for k in sift_kps[:-1]]
    assert alone[-1].angle == 0.0  # the shape of an unoriented keypoint points along x
    # And our side: ctxmatch arrays -> cv2 -> ctxmatch arrays.
    k2, s2, a2, _ = from_cv2_keypoints(to_cv2_keypoints(kpts, shapes, angles=angles))
    np.testing.assert_array_equal(k2, kpts)
    np.testing.assert_allclose(s2, shapes, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.isnan(a2), np.isnan(angles))


def test_cv2_keypoints_match_the_feature_extractor():
    """The shapes of from_cv2_keypoints are those of extract_features (3 sigma, same orientation)."""
    from skimage.data import camera

    f = extract_features(camera()[::2, ::2], FeatureConfig(max_keypoints=120), cache_dir=False)
    kpts, shapes, angles, _ = from_cv2_keypoints(to_cv2_keypoints(f.kpts, f.shapes, responses=f.responses))
    np.testing.assert_allclose(kpts, f.kpts, atol=1e-4)
    np.testing.assert_allclose(shapes, f.shapes, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.cos(angles - f.angles), 1.0, atol=1e-9)


def test_cv2_keypoints_empty_and_bad_input():
    kpts, shapes, angles, resp = from_cv2_keypoints([])
    assert kpts.shape == (0, 2) and shapes.shape == (0, 2, 2) and angles.shape == resp.shape == (0,)
    assert to_cv2_keypoints(np.empty((0, 2))) == []
    plain = to_cv2_keypoints([[1.0, 2.0]])
    assert (plain[0].pt, plain[0].size, plain[0].angle) == ((1.0, 2.0), 1.0, -1.0)
    with pytest.raises(ValueError, match="shapes must have shape"):
        to_cv2_keypoints([[1.0, 2.0]], np.eye(2)[None].repeat(2, 0))
    with pytest.raises(ValueError, match="cv2.KeyPoint"):
        from_cv2_keypoints([(1.0, 2.0)])


def test_cv2_matches_round_trip_exact():
    rng = np.random.default_rng(0)
    m = rng.integers(0, 500, (40, 2))
    s = rng.uniform(0, 1, 40).astype(np.float32).astype(np.float64)  # DMatch.distance is float32
    dm = to_cv2_matches(m, s)
    assert all(isinstance(d, cv2.DMatch) for d in dm)
    back, back_s = from_cv2_matches(dm, return_scores=True)
    assert back.dtype == np.int64 and back.shape == (40, 2)
    np.testing.assert_array_equal(back, m)
    np.testing.assert_array_equal(back_s, s)
    np.testing.assert_array_equal(from_cv2_matches(dm), m)
    assert from_cv2_matches([]).shape == (0, 2) and to_cv2_matches(np.empty((0, 2), int)) == []
    # knnMatch gives lists of lists: flattened.
    d1 = rng.uniform(0, 1, (5, 8)).astype(np.float32)
    knn = cv2.BFMatcher().knnMatch(d1, d1, k=2)
    assert from_cv2_matches(knn).shape == (10, 2)


def test_api_names_the_argument_for_cv2_lists(sift_kps):
    kps = sift_kps[:5]
    with pytest.raises(ValueError, match=r"kpts1 .*cv2\.KeyPoint.*interop\.from_cv2_keypoints"):
        FILTERS["dtm"](kps, np.zeros((5, 2)), [[0, 0]], None, image_size1=(64, 64), image_size2=(64, 64))
    with pytest.raises(ValueError, match=r"kpts2 .*cv2\.KeyPoint"):
        blob_matching(np.eye(5), np.eye(5), kpts1=np.zeros((5, 2)), kpts2=kps)
    with pytest.raises(ValueError, match=r"matches .*cv2\.DMatch.*from_cv2_matches"):
        FILTERS["gms"](np.zeros((5, 2)), np.zeros((5, 2)), to_cv2_matches([[0, 1]]), None,
                       image_size1=(64, 64), image_size2=(64, 64))
    # With the interop functions, the same input works end to end.
    kpts, shapes, _, _ = from_cv2_keypoints(kps)
    out = blob_matching(np.eye(5), np.eye(5), kpts1=kpts, kpts2=kpts, shapes1=shapes, shapes2=shapes)
    assert out.matches.shape[1] == 2


# ------------------------------------------------------------------------------------------------ kornia

try:
    import kornia
    import torch
except ImportError:  # the optional 'kornia' extra
    kornia = torch = None

needs_kornia = pytest.mark.skipif(kornia is None, reason="torch/kornia not installed (pip install 'ctxmatch[kornia]')")


@needs_kornia
def test_kornia_lafs_round_trip_exact(sift_kps):
    kpts, shapes, _, _ = from_cv2_keypoints(sift_kps)
    for mr in (3.0, 6.0, 12.0):
        lafs = to_kornia_lafs(kpts, shapes, mr_size=mr)
        assert lafs.shape == (1, len(kpts), 2, 3) and lafs.dtype == torch.float64
        k2, s2 = from_kornia_lafs(lafs, mr_size=mr)
        np.testing.assert_array_equal(k2, kpts)
        np.testing.assert_allclose(s2, shapes, rtol=1e-15, atol=1e-13)
    np.testing.assert_array_equal(to_kornia_lafs(kpts, shapes, mr_size=3.0)[0, :, :, :2].numpy(), shapes)
    k0, s0 = from_kornia_lafs(to_kornia_lafs(np.empty((0, 2)), np.empty((0, 2, 2)), mr_size=6.0), mr_size=6.0)
    assert k0.shape == (0, 2) and s0.shape == (0, 2, 2)


@needs_kornia
def test_kornia_scale_convention_is_explicit(sift_kps):
    """kornia_moons' laf_from_opencv_SIFT_kpts (scale 6 * size, angle -angle through kornia) is mr_size=12."""
    import kornia.feature as KF

    kps = sift_kps[:-1]
    xy = torch.tensor([k.pt for k in kps], dtype=torch.float64).view(1, -1, 2)
    scale = torch.tensor([6.0 * k.size for k in kps], dtype=torch.float64).view(1, -1, 1, 1)
    ori = torch.tensor([-k.angle for k in kps], dtype=torch.float64).view(1, -1, 1)
    moons = KF.laf_from_center_scale_ori(xy, scale, ori)
    kpts, shapes, _, _ = from_cv2_keypoints(kps)
    np.testing.assert_allclose(to_kornia_lafs(kpts, shapes, mr_size=12.0).numpy(), moons.numpy(), rtol=1e-6, atol=1e-4)
    _, s12 = from_kornia_lafs(moons, mr_size=12.0)
    np.testing.assert_allclose(s12, shapes, rtol=1e-6, atol=1e-5)
    # Read with the wrong convention the patches are 4x too large: hence no default.
    _, s3 = from_kornia_lafs(moons, mr_size=3.0)
    np.testing.assert_allclose(np.abs(np.linalg.det(s3)) / np.abs(np.linalg.det(shapes)), 16.0, rtol=1e-5)
    with pytest.raises(TypeError):
        from_kornia_lafs(moons)  # mr_size is required
    with pytest.raises(ValueError, match="B = 2"):
        from_kornia_lafs(moons.repeat(2, 1, 1, 1), mr_size=12.0)


@needs_kornia
def test_match_blob_is_blob_matching_kornia_style(sift_kps):
    from skimage.data import camera

    img = camera()[::2, ::2]
    f1 = extract_features(img, FeatureConfig(max_keypoints=120), cache_dir=False)
    f2 = extract_features(np.ascontiguousarray(img[7:, 5:]), FeatureConfig(max_keypoints=120), cache_dir=False)
    lafs1 = to_kornia_lafs(f1.kpts, f1.shapes, mr_size=6.0, dtype=torch.float32)
    lafs2 = to_kornia_lafs(f2.kpts, f2.shapes, mr_size=6.0, dtype=torch.float32)
    d1, d2 = torch.from_numpy(f1.desc), torch.from_numpy(f2.desc)
    for name in ("paper-best", "paper-best-overlap"):
        dists, idxs = match_blob(d1, d2, lafs1, lafs2, mr_size=6.0, blob=name)
        ref = blob_matching(f1.desc, f2.desc, kpts1=lafs1[0, :, :, 2].double().numpy(),
                            kpts2=lafs2[0, :, :, 2].double().numpy(), shapes1=f1.shapes, shapes2=f2.shapes,
                            **BLOB_PRESETS[name].kwargs())
        assert dists.shape == (len(ref.matches), 1) and idxs.dtype == torch.long
        np.testing.assert_array_equal(idxs.numpy(), ref.matches)
        np.testing.assert_allclose(dists[:, 0].numpy(), ref.scores, rtol=1e-5, atol=1e-6)
    # Same interface as kornia's own matchers.
    sd, si = kornia.feature.match_smnn(d1, d2, 0.95)
    assert sd.shape[1] == 1 and si.shape[1] == 2
    with pytest.raises(ValueError, match="mr_size is required"):
        match_blob(d1, d2, lafs1, lafs2, blob="paper-best-overlap")
    with pytest.raises(ValueError, match="lafs1 and lafs2 are required"):
        match_blob(d1, d2)
    dists, idxs = match_blob(d1, d2, blob="baseline")  # no FGINN: descriptors are enough
    assert len(idxs) == len(set(idxs[:, 0].tolist())) > 0


@needs_kornia
def test_adalam_agrees_with_kornia(tmp_path):
    """Our AdaLAM (FILTERS["adalam"]) and kornia's AdalamFilter on the same nearest-neighbour candidates of an
    embedded pair (the astronaut photo and its warp by a planted homography)."""
    import kornia.feature as KF
    from kornia.feature.adalam import AdalamFilter

    from test_match_cli import H12, _write_pair

    a, b = _write_pair(tmp_path)
    cfg = FeatureConfig(max_keypoints=2000)
    f1, f2 = extract_features(a, cfg, cache_dir=False), extract_features(b, cfg, cache_dir=False)
    D = np.linalg.norm(f1.desc[:, None].astype(np.float64) - f2.desc[None].astype(np.float64), axis=2)
    nn2 = np.argsort(D, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(D))
    ratio = D[rows, nn2[:, 0]] / D[rows, nn2[:, 1]]
    cand = np.c_[rows, nn2[:, 0]]
    ours = FILTERS["adalam"](f1.kpts, f2.kpts, cand, ratio, image_size1=(256, 256), image_size2=(240, 220),
                             shapes1=f1.shapes, shapes2=f2.shapes)
    lafs1 = to_kornia_lafs(f1.kpts, f1.shapes, mr_size=6.0, dtype=torch.float32)
    lafs2 = to_kornia_lafs(f2.kpts, f2.shapes, mr_size=6.0, dtype=torch.float32)
    # kornia's seeds test the squared-distance ratio against 0.8**2, ours the ratio against 0.8; no MNN forcing.
    theirs = AdalamFilter().filter_matches(
        torch.from_numpy(f1.kpts).float(), torch.from_numpy(f2.kpts).float(), torch.from_numpy(nn2[:, 0]),
        torch.from_numpy(ratio**2).float(), None, (256, 256), (220, 240),
        KF.get_laf_orientation(lafs1).reshape(-1), KF.get_laf_orientation(lafs2).reshape(-1),
        KF.get_laf_scale(lafs1).reshape(-1), KF.get_laf_scale(lafs2).reshape(-1))
    s_ours = set(map(tuple, cand[ours].tolist()))
    s_theirs = set(map(tuple, theirs.numpy().tolist()))

    def precision(s):
        m = np.array(sorted(s))
        p = np.c_[f1.kpts[m[:, 0]], np.ones(len(m))] @ H12.T
        return np.mean(np.linalg.norm(p[:, :2] / p[:, 2:] - f2.kpts[m[:, 1]], axis=1) < 5)

    jaccard = len(s_ours & s_theirs) / len(s_ours | s_theirs)
    print(f"AdaLAM on {len(cand)} NN candidates (precision {precision(set(map(tuple, cand.tolist()))):.3f}): "
          f"ours {len(s_ours)} kept (precision {precision(s_ours):.3f}), kornia {len(s_theirs)} "
          f"(precision {precision(s_theirs):.3f}), common {len(s_ours & s_theirs)}, Jaccard {jaccard:.3f}")
    assert len(s_ours) > 100 and len(s_theirs) > 100
    assert jaccard > 0.9
    assert precision(s_ours) > 0.95 and precision(s_theirs) > 0.95
