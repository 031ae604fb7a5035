"""Features: SIFT frames, RootSIFT, upright option, keypoint cap and the atomic, config-keyed disk cache."""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy.spatial import cKDTree

from ctxmatch_lib import features as F
from ctxmatch_lib.features import FeatureConfig, Features, extract_features, load_image


@pytest.fixture(scope="module")
def gray():
    from skimage.data import camera

    return np.ascontiguousarray(camera()[60:316, 100:420])  # 256 x 320, textured


@pytest.fixture(scope="module")
def feats(gray):
    return extract_features(gray, cache_dir=False)


# ------------------------------------------------------------------------------------------- output
def test_shapes_dtypes_and_order(feats):
    n = len(feats)
    assert n > 100
    assert feats.kpts.shape == (n, 2) and feats.kpts.dtype == np.float64
    assert feats.shapes.shape == (n, 2, 2) and feats.shapes.dtype == np.float64
    assert feats.desc.shape == (n, 128) and feats.desc.dtype == np.float32
    for a in (feats.scales, feats.angles, feats.responses):
        assert a.shape == (n,)
    assert np.all(np.diff(feats.responses) <= 0), "strongest first"
    assert np.all((feats.angles > -np.pi - 1e-9) & (feats.angles <= np.pi + 1e-9))
    assert np.all(feats.scales > 0)


def test_rootsift_is_unit_norm_and_nonnegative(feats):
    assert np.allclose(np.linalg.norm(feats.desc, axis=1), 1, atol=1e-5)
    assert feats.desc.min() >= 0


def test_rootsift_is_sqrt_of_l1_normalised_sift(gray):
    sift = extract_features(gray, FeatureConfig(descriptor="sift", max_keypoints=50), cache_dir=False)
    root = extract_features(gray, FeatureConfig(max_keypoints=50), cache_dir=False)
    np.testing.assert_array_equal(sift.kpts, root.kpts)
    expected = np.sqrt(sift.desc / sift.desc.sum(1, keepdims=True))
    np.testing.assert_allclose(root.desc, expected, atol=1e-6)


def test_affine_shape_is_rotated_disc(feats):
    r = FeatureConfig().patch_radius * feats.scales
    c, s = np.cos(feats.angles), np.sin(feats.angles)
    np.testing.assert_allclose(feats.shapes[:, :, 0], np.c_[c, s] * r[:, None])  # first axis along the angle
    np.testing.assert_allclose(feats.shapes[:, :, 1], np.c_[-s, c] * r[:, None])


def test_pixel_centre_convention_by_mirror(gray, feats):
    # Mirroring maps x to W - 1 - x exactly when the origin is the centre of the top-left pixel.
    mirrored = extract_features(np.ascontiguousarray(gray[:, ::-1]), cache_dir=False)
    expected = np.c_[gray.shape[1] - 1 - feats.kpts[:, 0], feats.kpts[:, 1]]
    d, _ = cKDTree(mirrored.kpts).query(expected)
    assert np.mean(d < 0.05) > 0.75
    assert np.median(d) < 0.01  # a quarter-pixel upscaling bias would give 0.5


def test_angles_turn_with_the_image(gray, feats):
    # Rotating the image 90 deg clockwise on screen maps (x, y) to (H - 1 - y, x): +90 deg in the y-down frame.
    rot = extract_features(np.ascontiguousarray(np.rot90(gray, k=-1)), cache_dir=False)
    expected = np.c_[gray.shape[0] - 1 - feats.kpts[:, 1], feats.kpts[:, 0]]
    d, _ = cKDTree(rot.kpts).query(expected)
    errs = []
    for angle, pt, ok in zip(feats.angles, expected, d < 0.05):
        if ok:  # several orientations may share a location: compare with the closest one
            cand = rot.angles[np.linalg.norm(rot.kpts - pt, axis=1) < 0.05]
            errs.append(np.min(np.abs(np.angle(np.exp(1j * (cand - angle - np.pi / 2))))))
    assert len(errs) > 0.8 * len(feats)
    assert np.median(errs) < 1e-3


# ------------------------------------------------------------------------------------------ options
def test_keypoint_cap_keeps_the_strongest(gray, feats):
    capped = extract_features(gray, FeatureConfig(max_keypoints=40), cache_dir=False)
    assert len(capped) == 40
    np.testing.assert_array_equal(capped.responses, feats.responses[:40])
    np.testing.assert_array_equal(capped.kpts, feats.kpts[:40])
    everything = extract_features(gray, FeatureConfig(max_keypoints=0), cache_dir=False)
    assert len(everything) == len(feats)  # the default 8000 does not bind on this small image
    huge = extract_features(gray, FeatureConfig(max_keypoints=10**6), cache_dir=False)
    assert len(huge) == len(everything)


def test_one_pass_descriptors_equal_compute_on_the_kept_keypoints(gray):
    # Detected and described in one pass, the kept keypoints carry the descriptors that OpenCV's compute() gives
    # them on their own (its scale space starts at the lowest kept octave), whether the cap binds or not.
    import cv2

    from ctxmatch_lib._numerics.fixedmath import opencv_baseline
    from ctxmatch_lib.features.sift import _sift_detect

    for cap in (40, 0):
        config = FeatureConfig(descriptor="sift", max_keypoints=cap)
        with opencv_baseline():
            sift, (pts, size, ang, resp, octave) = _sift_detect(gray, config, merge=False)
            kps = [cv2.KeyPoint(float(x), float(y), float(s), float(a), float(r), int(o))
                   for (x, y), s, a, r, o in zip(pts, size, ang, resp, octave)]
            _, desc = sift.compute(gray, kps)
        got = extract_features(gray, config, cache_dir=False)
        np.testing.assert_array_equal(got.kpts, pts)
        want = desc.astype(np.float64)
        want /= np.maximum(np.linalg.norm(want, axis=1, keepdims=True), 1e-12)
        np.testing.assert_array_equal(got.desc, want.astype(np.float32))


def test_features_in_threads_equal_features_in_turn():
    # OpenCV keeps its IPP switch per thread: opencv_baseline must switch it off in every thread it covers.
    from concurrent.futures import ThreadPoolExecutor

    from skimage.data import astronaut, coffee

    images = [np.ascontiguousarray(astronaut()[..., 1]), np.ascontiguousarray(coffee()[..., 0])]
    in_turn = [extract_features(g, cache_dir=False) for g in images]
    with ThreadPoolExecutor(max_workers=2) as pool:
        side_by_side = list(pool.map(lambda g: extract_features(g, cache_dir=False), images))
    for a, b in zip(in_turn, side_by_side):
        for field in ("kpts", "shapes", "desc", "angles", "responses"):
            assert getattr(a, field).tobytes() == getattr(b, field).tobytes(), field


def test_upright(gray, feats):
    up = extract_features(gray, FeatureConfig(upright=True), cache_dir=False)
    assert np.all(up.angles == 0)
    # One keypoint per blob: the oriented duplicates of a location are merged.
    keys = np.c_[up.kpts, up.scales]
    assert len(np.unique(keys, axis=0)) == len(up)
    assert len(up) == len(np.unique(np.c_[feats.kpts, feats.scales], axis=0))
    np.testing.assert_allclose(up.shapes[:, 0, 1], 0, atol=1e-12)
    assert FeatureConfig(upright=True).key() != FeatureConfig().key()


def test_empty_and_tiny_images():
    for img in (np.zeros((120, 160), np.uint8), np.full((5, 5), 200, np.uint8), np.zeros((0, 0), np.uint8)):
        f = extract_features(img, cache_dir=False)
        assert len(f) == 0
        assert f.kpts.shape == (0, 2) and f.shapes.shape == (0, 2, 2) and f.desc.shape == (0, 128)


def test_array_inputs_agree(gray):
    rgb = np.repeat(gray[..., None], 3, axis=2)
    a = extract_features(gray, FeatureConfig(max_keypoints=30), cache_dir=False)
    b = extract_features(rgb, FeatureConfig(max_keypoints=30), cache_dir=False)
    c = extract_features(gray / 255.0, FeatureConfig(max_keypoints=30), cache_dir=False)
    for other in (b, c):
        np.testing.assert_array_equal(a.kpts, other.kpts)


@pytest.mark.parametrize(
    "kwargs, word",
    [({"detector": "harris"}, "detector"), ({"descriptor": "hardnet"}, "descriptor"),
     ({"max_keypoints": -1}, "max_keypoints"), ({"sigma": 0.0}, "sigma"), ({"n_octave_layers": 0}, "n_octave_layers")],
)
def test_bad_config_names_the_field(kwargs, word):
    with pytest.raises(ValueError, match=word):
        FeatureConfig(**kwargs)


def test_bad_inputs():
    with pytest.raises(ValueError, match="config"):
        extract_features(np.zeros((32, 32), np.uint8), {"max_keypoints": 5}, cache_dir=False)
    with pytest.raises(ValueError, match="image"):
        extract_features(np.zeros((4, 4, 4, 4)), cache_dir=False)


# ---------------------------------------------------------------------------------------- load_image
def test_load_image(tmp_path, gray):
    import cv2

    path = tmp_path / "g.png"
    cv2.imwrite(str(path), gray)
    np.testing.assert_array_equal(load_image(path), gray)
    rgb = load_image(path, gray=False)
    assert rgb.shape == gray.shape + (3,)


def test_load_image_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.png"
    with pytest.raises(FileNotFoundError, match="nope.png"):
        load_image(missing)
    corrupt = tmp_path / "broken.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    with pytest.raises(ValueError, match="broken.png"):
        load_image(corrupt)
    with pytest.raises(ValueError, match="broken.png"):
        extract_features(corrupt, cache_dir=False)
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    with pytest.raises(ValueError, match="empty.jpg"):
        load_image(empty)


# --------------------------------------------------------------------------------------------- cache
def _entries(cache):
    return sorted(p for p in cache.rglob("*") if p.is_file())


def test_cache_hit(tmp_path, gray, monkeypatch):
    cfg = FeatureConfig(max_keypoints=60)
    first = extract_features(gray, cfg, cache_dir=tmp_path)
    files = _entries(tmp_path)
    assert len(files) == 1 and files[0].suffix == ".npz"
    assert files[0] == F.feature_cache_path(gray, cfg, cache_dir=tmp_path)
    assert cfg.key() in str(files[0])

    def boom(*args, **kwargs):
        raise AssertionError("cache miss: features recomputed")

    monkeypatch.setattr(F.cache, "_extract", boom)  # where extract_features looks it up
    again = extract_features(gray, cfg, cache_dir=tmp_path)
    for name in ("kpts", "shapes", "desc", "scales", "angles", "responses"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
        assert getattr(first, name).dtype == getattr(again, name).dtype
    # Keyed by content, not by how the image was passed: a file with the same pixels hits too.
    import cv2

    path = tmp_path / "same.png"
    cv2.imwrite(str(path), gray)
    extract_features(path, cfg, cache_dir=tmp_path)


def test_cache_is_config_keyed(tmp_path, gray):
    a = extract_features(gray, FeatureConfig(max_keypoints=20), cache_dir=tmp_path)
    b = extract_features(gray, FeatureConfig(max_keypoints=30), cache_dir=tmp_path)
    c = extract_features(gray, FeatureConfig(max_keypoints=30, upright=True), cache_dir=tmp_path)
    assert (len(a), len(b), len(c)) == (20, 30, 30)
    assert len(_entries(tmp_path)) == 3
    keys = {FeatureConfig(max_keypoints=20).key(), FeatureConfig(max_keypoints=30).key(),
            FeatureConfig(max_keypoints=30, upright=True).key(), FeatureConfig(contrast_threshold=0.03).key(),
            FeatureConfig(patch_radius=2.0).key()}
    assert len(keys) == 5
    # Stable across calls and processes (no id() or hash randomisation inside).
    assert FeatureConfig().key() == FeatureConfig().key() == "sift-rootsift-k8000-v2-441d0e9b"
    assert all(ch.isalnum() or ch in "-_." for ch in FeatureConfig(upright=True).key())


def test_cache_write_is_atomic(tmp_path, gray, monkeypatch):
    cfg = FeatureConfig(max_keypoints=25)
    target = F.feature_cache_path(gray, cfg, cache_dir=tmp_path)

    def interrupted(f, **arrays):
        f.write(b"partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        extract_features(gray, cfg, cache_dir=tmp_path)
    assert not target.exists()
    assert _entries(tmp_path) == [], "no temporary file left behind"
    monkeypatch.undo()
    f = extract_features(gray, cfg, cache_dir=tmp_path)
    assert target.is_file() and len(f) == 25


def test_corrupt_cache_entry_is_recomputed(tmp_path, gray):
    cfg = FeatureConfig(max_keypoints=25)
    target = F.feature_cache_path(gray, cfg, cache_dir=tmp_path)
    target.parent.mkdir(parents=True)
    target.write_bytes(b"not an npz")
    f = extract_features(gray, cfg, cache_dir=tmp_path)
    assert len(f) == 25
    with np.load(target) as z:
        np.testing.assert_array_equal(z["kpts"], f.kpts)


def test_default_cache_location(tmp_path, gray, monkeypatch):
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path))
    extract_features(gray, FeatureConfig(max_keypoints=10))
    files = _entries(tmp_path / "features")
    assert len(files) == 1
    assert not any(name.endswith(".tmp") for name in os.listdir(files[0].parent))


def test_features_empty_constructor():
    f = Features.empty()
    assert len(f) == 0 and f.desc.dtype == np.float32
    assert f.image_size is None and Features.empty(image_size=(5, 7)).image_size == (5, 7)
    with pytest.raises(ValueError, match="image_size"):
        Features.empty(image_size=(640,))
    with pytest.raises(ValueError, match="image_size"):
        Features.empty(image_size=(640.5, 480))


@pytest.mark.parametrize("config", [
    FeatureConfig(max_keypoints=30),                                        # OpenCV SIFT path
    FeatureConfig(max_keypoints=30, upright=True),                          # SIFT, merged orientations
    FeatureConfig(descriptor="rootsgloh2", max_keypoints=30),               # patch path, SIFT detector
    FeatureConfig(detector="harrisz", max_keypoints=30),                    # patch path, HarrisZ
], ids=["sift", "upright", "sgloh2", "harrisz"])
def test_features_carry_the_image_size(gray, config, tmp_path):
    # (width, height) as Pair.image_size1, on every detector path, for empty results too, and from the cache.
    h, w = gray.shape
    assert extract_features(gray, config, cache_dir=False).image_size == (w, h)
    assert extract_features(np.zeros((40, 70), np.uint8), config, cache_dir=False).image_size == (70, 40)
    assert extract_features(np.zeros((5, 6), np.uint8), config, cache_dir=False).image_size == (6, 5)
    first = extract_features(gray, config, cache_dir=tmp_path)
    again = extract_features(gray, config, cache_dir=tmp_path)
    assert first.image_size == again.image_size == (w, h)


def test_cache_entries_without_the_image_size_are_ignored(tmp_path, gray):
    # An entry of the previous layout (no image_size) at the current path is a miss, recomputed and rewritten.
    cfg = FeatureConfig(max_keypoints=25)
    target = F.feature_cache_path(gray, cfg, cache_dir=tmp_path)
    target.parent.mkdir(parents=True)
    fake = Features.empty()
    np.savez(target, **{n: getattr(fake, n) for n in F.cache._FIELDS}, metric=np.array("l2"))
    f = extract_features(gray, cfg, cache_dir=tmp_path)
    assert len(f) == 25 and f.image_size == gray.shape[::-1]
    with np.load(target) as z:
        assert tuple(z["image_size"]) == gray.shape[::-1]
    # The layout version is in the entry's file name: older entries are not even opened.
    assert target.name.endswith(f".e{F.cache._ENTRY_FORMAT}.npz")


def test_cache_key_includes_the_opencv_version(gray, tmp_path, monkeypatch):
    import ctxmatch_lib.features as features
    from ctxmatch_lib.features import feature_cache_path

    cfg = FeatureConfig(max_keypoints=20)
    here = feature_cache_path(gray, cfg, cache_dir=tmp_path)
    extract_features(gray, cfg, cache_dir=tmp_path)
    import cv2

    assert here.is_file() and f"opencv-{cv2.__version__}" in here.parts
    # Another OpenCV is another entry: the stored features are not served to it.
    monkeypatch.setattr(features.cache, "_opencv_version", lambda: "0.0.0-other")
    other = feature_cache_path(gray, cfg, cache_dir=tmp_path)
    assert other != here and not other.exists()


def test_default_cache_is_the_users_cache_dir(tmp_path, monkeypatch):
    from ctxmatch_lib.cache import cache_dir

    monkeypatch.delenv("CTXMATCH_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir("features") == tmp_path / "xdg" / "ctxmatch" / "features"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "ctxmatch"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")  # invalid per the XDG spec: ignored
    assert cache_dir() == tmp_path / "home" / ".cache" / "ctxmatch"
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "mine"))
    assert cache_dir("sweep") == tmp_path / "mine" / "sweep" and (tmp_path / "mine" / "sweep").is_dir()
    # Never the checkout by surprise.
    from ctxmatch_lib.cache import repo_root

    monkeypatch.delenv("CTXMATCH_CACHE")
    if repo_root() is not None:
        assert repo_root() not in cache_dir().parents


def test_new_fields_keep_the_old_keys_and_validate():
    # The SIFT keys (and so their cache entries) do not change with the fields added for the other presets.
    assert FeatureConfig().key() == "sift-rootsift-k8000-v2-441d0e9b"
    assert FeatureConfig(orientation="none").key() != FeatureConfig().key()
    assert FeatureConfig(detector="harrisz").resolved_orientation() == "dominant"
    assert FeatureConfig(descriptor="rootsgloh2").resolved_orientation() == "none"
    assert FeatureConfig(upright=True).resolved_orientation() == "none"
    with pytest.raises(ValueError, match="orientation"):
        FeatureConfig(detector="harrisz", orientation="sift")
    with pytest.raises(ValueError, match="RootsGLOH2"):
        FeatureConfig(descriptor="rootsgloh2", orientation="dominant")
    with pytest.raises(ValueError, match="weights"):
        FeatureConfig(weights="x.pth")
    with pytest.raises(ValueError, match="detector"):
        FeatureConfig(detector="orb")


def test_cli_features_option(tmp_path, capsys):
    from ctxmatch_lib.cli import main

    assert main(["eval", "--features", "nope", "--out", str(tmp_path / "x.parquet")]) == 2
    assert "unknown feature preset" in capsys.readouterr().err
    assert main(["eval", "--features", "harrisz-rootsift", "--upright", "--out", str(tmp_path / "x.parquet")]) == 2
    assert main(["sweep", "--features", "sift-rootsift,nope", "--out", str(tmp_path / "y.parquet")]) == 2
    assert "harrisz-rootsgloh2" in capsys.readouterr().err  # the known presets are listed


@pytest.mark.parametrize("name", ["sift-rootsgloh2", "harrisz-rootsift"])
def test_handcrafted_patch_presets(gray, name):
    f = extract_features(gray, F.FEATURE_PRESETS[name], cache_dir=False)
    assert len(f) > 100 and f.shapes.shape == (len(f), 2, 2)
    assert np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-4)
    if name == "harrisz-rootsift":
        # Oriented by the dominant gradient: the first axis of each shape is turned by the angle.
        base = f.shapes @ np.stack([np.stack([np.cos(f.angles), np.sin(f.angles)], -1),
                                    np.stack([-np.sin(f.angles), np.cos(f.angles)], -1)], -2)
        assert np.allclose(base, np.swapaxes(base, 1, 2), atol=1e-9)  # HarrisZ shapes are symmetric


def test_readme_api_example_runs_on_any_image_size(tmp_path, monkeypatch):
    # The README's ten-line example once hard-coded (640, 480) and raised on other images: run it as written,
    # on the embedded pair it names (the 741 x 500 motorcycle stereo pair, not 640 x 480), and check its
    # matches against the pair's ground-truth disparity.
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme.split("## The Python API in ten lines", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "640, 480" not in code and "image_size" in code and "depth_motorcycle" in code
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    scope = {}
    exec(compile(code, "README.md", "exec"), scope)
    f1, f2 = scope["f1"], scope["f2"]
    assert f1.image_size == (741, 500) and f2.image_size == (741, 500)
    m = scope["matches"]
    assert m.ndim == 2 and m.shape[1] == 2 and len(m) > 20
    from ctxmatch_lib.datasets import load_dataset

    flow = load_dataset("embedded-depth")[0].gt.flow12  # left (x, y) -> right (x + u, y + v)
    p1, p2 = f1.kpts[m[:, 0]], f2.kpts[m[:, 1]]
    r, c = np.round(p1[:, 1]).astype(int), np.round(p1[:, 0]).astype(int)
    err = np.linalg.norm(p1 + flow[r, c] - p2, axis=1)
    known = np.isfinite(err)
    assert known.mean() > 0.8 and np.median(err[known]) < 1.5
    assert np.median(np.abs(p1[:, 1] - p2[:, 1])) < 1  # rectified: the matches keep their row
