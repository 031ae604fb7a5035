"""Calibrated pairs: PoseGT, the Strecha loader and pair rule, the pairs-with-GT interchange, the download,
ground-truth labels, and bad input (each error names the file and line)."""

from __future__ import annotations

import functools
import hashlib
import http.server
import threading
from pathlib import Path

import numpy as np
import pytest

from ctxmatch_lib.datasets import (PAIR_KINDS, Dataset, PoseGT, load_dataset, pose_difficulty, read_custom_dataset,
                                   read_pairs_with_gt, write_custom_dataset, write_pairs_with_gt)
from ctxmatch_lib.datasets import download as dl
from ctxmatch_lib.datasets.strecha import (DIFFICULTY_BANDS, Camera, load_strecha_folder, read_strecha_camera,
                                           rotation_band, select_pairs)
from ctxmatch_lib.groundtruth import label_matches

K = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])


def _rot(axis, deg):
    import cv2

    return cv2.Rodrigues(np.radians(deg) * np.asarray(axis, float) / np.linalg.norm(axis))[0]


def _project(K_, X):
    x = X @ K_.T
    return x[:, :2] / x[:, 2:]


# ----------------------------------------------------------------------------------------------- PoseGT
def test_pose_gt_F_and_E_satisfy_the_epipolar_constraint():
    rng = np.random.default_rng(0)
    R, t = _rot([0.1, 1, 0.05], 12), np.array([1.0, 0.1, 0.2])
    K2 = K * [[1.1], [1.1], [1]]
    gt = PoseGT(K, K2, R, t)
    X1 = rng.uniform([-2, -2, 4], [2, 2, 8], (20, 3))
    X2 = X1 @ R.T + t
    x1, x2 = _project(K, X1), _project(K2, X2)
    h = np.ones((20, 1))
    assert np.abs(np.einsum("ij,jk,ik->i", np.c_[x2, h], gt.F, np.c_[x1, h])).max() < 1e-12
    assert np.abs(np.einsum("ij,jk,ik->i", X2 / X2[:, 2:], gt.E, X1 / X1[:, 2:])).max() < 1e-12
    assert np.linalg.norm(gt.F) == pytest.approx(1)
    assert "calibrated" in PAIR_KINDS


@pytest.mark.parametrize("field, value, match", [
    ("R", np.diag([1.0, 1, 2]), "R is not a rotation"),
    ("R", np.diag([1.0, 1, -1]), "reflection"),
    ("R", np.eye(2), r"R must be a \(3, 3\)"),
    ("K1", np.diag([0.0, 800, 1]), "K1 has a zero focal"),
    ("K2", np.array([[800.0, 0, 0], [0, 800, 0], [1, 0, 1]]), "K2 must be upper triangular"),
    ("t", np.zeros(3), "t is zero"),
    ("t", np.array([1.0, np.nan, 0]), "t contains NaN"),
    ("threshold_scale", 0.0, "threshold_scale must be a positive"),
])
def test_pose_gt_rejects_bad_fields(field, value, match):
    kwargs = dict(K1=K, K2=K, R=np.eye(3), t=np.array([1.0, 0, 0]))
    kwargs[field] = value
    with pytest.raises(ValueError, match=match):
        PoseGT(**kwargs)


def test_dataset_by_kind_accepts_calibrated():
    gt = PoseGT(K, K, np.eye(3), np.array([1.0, 0, 0]))
    from ctxmatch_lib.datasets import Pair

    p = Pair("a/b", Path("a.png"), Path("b.png"), (640, 480), (640, 480), "calibrated", gt)
    ds = Dataset("d", [p])
    assert len(ds.by_kind("calibrated")) == 1 and "calibrated=1" in repr(ds)


# ------------------------------------------------------------------------------------ labels (Sec. 5.1)
def test_calibrated_labels_use_the_larger_epipolar_distance_scaled():
    R, t = np.eye(3), np.array([1.0, 0, 0])  # pure x translation: epipolar lines are the image rows
    kp1 = np.array([[100.0, 100], [100, 100], [100, 100]])
    kp2 = np.array([[150.0, 110], [150, 130], [150, 146]])
    m = np.array([[0, 0], [1, 1], [2, 2]])
    assert label_matches(kp1, kp2, m, PoseGT(K, K, R, t)).tolist() == [True, False, False]
    gt3 = PoseGT(K, K, R, t, threshold_scale=3.0)
    assert label_matches(kp1, kp2, m, gt3).tolist() == [True, True, False]
    assert label_matches(kp1, kp2, m, gt3, method="A").tolist() == [True, True, False]
    assert label_matches(kp1, kp2, np.empty((0, 2), np.int64), gt3).shape == (0,)
    with pytest.raises(ValueError, match="PoseGT"):
        label_matches(kp1, kp2, m, gt3, method="B")


# ------------------------------------------------------------------------------- Strecha layout, pair rule
def _camera_text(K_, R_c2w, C, size=(64, 48)):
    rows = [*K_, [0, 0, 0], *R_c2w, C]
    return "\n".join(" ".join(f"{v:.9g}" for v in r) for r in rows) + f"\n{size[0]} {size[1]}\n"


def _ring_scene(folder: Path, angles_deg, radius=10.0, size=(64, 48)):
    """Cameras on a circle looking at the origin, a tiny image each: the Strecha layout."""
    import cv2

    (folder / "images").mkdir(parents=True)
    (folder / "gt_dense_cameras").mkdir()
    Ks = np.array([[60.0, 0, 31.5], [0, 60, 23.5], [0, 0, 1]])
    for k, a in enumerate(angles_deg):
        a = np.radians(a)
        C = radius * np.array([np.sin(a), 0, -np.cos(a)])
        z = -C / np.linalg.norm(C)
        x = np.cross([0, 1, 0], z)
        R_c2w = np.c_[x, np.cross(z, x), z]  # columns: camera axes in world coordinates
        name = f"{k:04d}.png"
        cv2.imwrite(str(folder / "images" / name), np.full((size[1], size[0]), 100 + k, np.uint8))
        (folder / "gt_dense_cameras" / f"{name}.camera").write_text(_camera_text(Ks, R_c2w, C, size))
    return folder


def test_strecha_camera_and_relative_pose(tmp_path):
    scene = _ring_scene(tmp_path / "ring", [0, 10, 27, 45, 80])
    pairs = load_strecha_folder(scene, dataset="ring", max_per_band=None)
    bands = {p.pair_id: p.gt.difficulty for p in pairs}
    # 0-1 10 deg, 0-2 27, 0-3 45, 1-2 17, 1-3 35, 2-3 18, 3-4 35, 2-4 53; 0-4 (80) and 1-4 (70) excluded
    assert bands == {"ring/ring/0-1": "easy", "ring/ring/0-2": "medium", "ring/ring/0-3": "hard",
                     "ring/ring/1-2": "medium", "ring/ring/1-3": "hard", "ring/ring/2-3": "medium",
                     "ring/ring/2-4": "hard", "ring/ring/3-4": "hard"}
    p = next(q for q in pairs if q.pair_id.endswith("0-3"))
    assert p.kind == "calibrated" and p.image_size1 == (64, 48) and pose_difficulty(p) == "hard"
    assert p.gt.threshold_scale == pytest.approx(64 / 1024)
    # the origin (the fixation point) projects to the principal point in both views; F agrees
    c1 = read_strecha_camera(scene / "gt_dense_cameras" / "0000.png.camera")
    X1 = c1.R.T @ (np.zeros(3) - c1.C)
    X2 = p.gt.R @ X1 + p.gt.t
    np.testing.assert_allclose(_project(p.gt.K2, X2[None])[0], [31.5, 23.5], atol=1e-6)
    assert np.degrees(np.arccos((np.trace(p.gt.R) - 1) / 2)) == pytest.approx(45, abs=1e-4)
    # a folder of scenes, and the cap per band
    _ring_scene(tmp_path / "ring2", [0, 5, 10, 20])
    both = load_dataset(tmp_path)
    assert {q.pair_id.split("/")[1] for q in both} == {"ring", "ring2"}
    capped = load_strecha_folder(scene, max_per_band=1)
    assert sorted(q.gt.difficulty for q in capped) == ["easy", "hard", "medium"]


def test_select_pairs_is_a_function_of_the_geometry_only():
    cams = []
    for a in (0, 20, 40):
        a = np.radians(a)
        C = 10 * np.array([np.sin(a), 0, -np.cos(a)])
        z = -C / 10
        x = np.cross([0, 1, 0], z)
        cams.append(Camera(K, np.c_[x, np.cross(z, x), z], C, (640, 480)))
    assert select_pairs(cams) == [(0, 1, "medium"), (0, 2, "hard"), (1, 2, "medium")]
    assert select_pairs(cams[:1]) == []
    # diverging axes (cameras back to back) never qualify
    back = Camera(K, cams[0].R @ np.diag([-1.0, 1, -1]), cams[0].C + [0.5, 0, 0], (640, 480))
    assert select_pairs([cams[0], back]) == []
    assert [rotation_band(a) for a in (0, 14.9, 15, 30, 60, 60.1)] == ["easy", "easy", "medium", "hard", "hard", ""]
    assert [b[0] for b in DIFFICULTY_BANDS] == ["easy", "medium", "hard"]


# ------------------------------------------------------------------------------ pairs-with-GT interchange
def _pose_line(name0, name1, R, t, K0=K, K1=K, rots=(0, 0)):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return " ".join([name0, name1, *map(str, rots), *(f"{v:.10g}" for v in (*K0.ravel(), *K1.ravel(), *T.ravel()))])


def _images(folder, *names, size=(640, 480)):
    import cv2

    for n in names:
        (folder / n).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(folder / n), np.zeros((size[1], size[0]), np.uint8))


def test_pairs_with_gt_read_write_round_trip(tmp_path):
    _images(tmp_path, "a.png", "b.png", "sub/c.png")
    R = _rot([0, 1, 0], 20)
    text = "# a comment\n\n" + "\n".join([
        _pose_line("a.png", "b.png", R, [1.0, 0, 0.1]),
        _pose_line("a.png", "sub/c.png", _rot([1, 0, 0], 5), [0, 0.2, 0.0], rots=(1, 3)),
    ]) + "\n"
    (tmp_path / "pairs_with_gt.txt").write_text(text)
    ds = load_dataset(tmp_path)
    assert len(ds) == 2 and all(p.kind == "calibrated" for p in ds)
    assert [pose_difficulty(p) for p in ds] == ["medium", "easy"]
    assert ds[1].gt.rotations == (1, 3) and ds[0].gt.threshold_scale == pytest.approx(640 / 1024)
    np.testing.assert_allclose(ds[0].gt.R, R, atol=1e-9)
    out = write_pairs_with_gt(ds, tmp_path / "copy.txt")
    again = read_pairs_with_gt(out, name=ds.name)
    assert [p.pair_id for p in again] == [p.pair_id for p in ds]
    for a, b in zip(ds, again):
        for f in ("K1", "K2", "R", "t"):
            np.testing.assert_allclose(getattr(a.gt, f), getattr(b.gt, f), rtol=0, atol=1e-14)
        assert a.gt.rotations == b.gt.rotations
    # the custom folder format carries calibrated pairs too
    write_custom_dataset(ds, tmp_path / "custom")
    custom = read_custom_dataset(tmp_path / "custom")
    np.testing.assert_array_equal(custom[1].gt.t, ds[1].gt.t)
    assert custom[1].kind == "calibrated" and custom[1].gt.rotations == (1, 3)


# ------------------------------------------------------------------------------------------- bad input
def _bad_pose_file(tmp_path, line):
    _images(tmp_path, "a.png", "b.png")
    good = _pose_line("a.png", "b.png", np.eye(3), [1.0, 0, 0])
    path = tmp_path / "pairs.txt"
    path.write_text(good + "\n" + line + "\n")
    return path


@pytest.mark.parametrize("mutate, match", [
    (lambda tok: tok[:-1], "line 2: expected 38 tokens"),
    (lambda tok: tok + ["1"], "line 2: expected 38 tokens"),
    (lambda tok: tok[:4] + ["0"] + tok[5:], "line 2: K0 has a zero focal"),
    (lambda tok: tok[:22] + ["2"] + tok[23:], "line 2: .*not a rotation"),
    (lambda tok: tok[:2] + ["5"] + tok[3:], "line 2: rot0 and rot1"),
    (lambda tok: tok[:5] + ["x"] + tok[6:], "line 2: not a number: 'x'"),
    (lambda tok: tok[:22] + ["0", "0", "0", "0", "0"] + tok[27:], "line 2: .*not a rotation"),
])
def test_pairs_with_gt_bad_lines_name_file_and_line(tmp_path, mutate, match):
    tokens = _pose_line("a.png", "b.png", np.eye(3), [1.0, 0, 0]).split()
    path = _bad_pose_file(tmp_path, " ".join(mutate(tokens)))
    with pytest.raises(ValueError, match=match) as info:
        read_pairs_with_gt(path)
    assert str(path) in str(info.value)


def test_pairs_with_gt_missing_image_or_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        read_pairs_with_gt(tmp_path / "nope.txt")
    path = _bad_pose_file(tmp_path, _pose_line("a.png", "missing.png", np.eye(3), [1.0, 0, 0]))
    with pytest.raises(FileNotFoundError, match=r"line 2: .*missing\.png"):
        read_pairs_with_gt(path)
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(ValueError, match="lists no pairs"):
        read_pairs_with_gt(tmp_path / "empty.txt")


@pytest.mark.parametrize("edit, exc, match", [
    (lambda ls: ls[:5], ValueError, "a .camera file has 9 lines"),
    (lambda ls: ["1 2"] + ls[1:], ValueError, "line 1: expected 3 numbers"),
    (lambda ls: ["0 0 31.5"] + ls[1:], ValueError, "lines 1-3: K has a zero focal"),
    (lambda ls: ls[:4] + ["2 0 0"] + ls[5:], ValueError, "lines 5-7: R is not a rotation"),
    (lambda ls: ls[:3] + ["0.1 0 0"] + ls[4:], ValueError, "line 4: non-zero distortion"),
    (lambda ls: ls[:7] + ["1 nan 2"] + ls[8:], ValueError, "line 8: NaN"),
    (lambda ls: ls[:8] + ["65 48"], ValueError, "line 9: size 65 48"),
    (lambda ls: ls[:8] + ["abc 48"], ValueError, "line 9: not a number"),
    (None, FileNotFoundError, r"camera file not found: .*0001\.png\.camera"),
])
def test_bad_camera_files_name_file_and_line(tmp_path, edit, exc, match):
    scene = _ring_scene(tmp_path / "s", [0, 10])
    cam = scene / "gt_dense_cameras" / "0001.png.camera"
    if edit is None:
        cam.unlink()
    else:
        cam.write_text("\n".join(edit(cam.read_text().splitlines())) + "\n")
    with pytest.raises(exc, match=match) as info:
        load_dataset(scene)
    assert "0001.png" in str(info.value)


# --------------------------------------------------------------------------------------------- download
def test_strecha_manifest_is_pinned():
    sets = {n: dl.SOURCES[n] for n in dl.DOWNLOAD_GROUPS["strecha"]}
    assert len(sets) == 6 and sum(len(s.files) for s in sets.values()) == 212
    assert all(len(h) == 64 for s in sets.values() for _, h in s.files)
    assert all("/348a981ef51112e9848acfb20004f4ed6fbc6ce3/" in s.base_url for s in sets.values())


@pytest.fixture
def mirror(tmp_path, monkeypatch):
    """A two-file Strecha scene served over http from a temporary folder, with a manifest of its hashes."""
    src = tmp_path / "mirror" / "tiny-P2"
    files = {"images/0000.jpg": b"\xff\xd8 not really a jpeg", "gt_dense_cameras/0000.jpg.camera": b"1 0 0\n"}
    for rel, data in files.items():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        (src / rel).write_bytes(data)
    manifest = tuple((rel, hashlib.sha256(data).hexdigest()) for rel, data in files.items())
    fs = dl.FileSet("http://unused.invalid/tiny-P2", manifest, "calibrated/strecha/tiny-P2")
    monkeypatch.setitem(dl.SOURCES, "strecha-tiny-P2", fs)
    monkeypatch.setitem(dl.DOWNLOAD_GROUPS, "strecha", ("strecha-tiny-P2",))
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path / "mirror"))
    handler.log_message = lambda *a, **k: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}", tmp_path / "mirror", files
    server.shutdown()


def test_strecha_download_from_a_local_mirror(mirror, tmp_path):
    base, folder, files = mirror
    root = tmp_path / "root"
    out = dl.download_dataset("strecha", root=root, url=base, log=lambda s: None)
    assert out == [root / "calibrated/strecha/tiny-P2"]
    for rel, data in files.items():
        assert (out[0] / rel).read_bytes() == data
    # already present: kept; file:// works too
    assert dl.download_dataset("strecha-tiny-P2", root=root, url=f"file://{folder}/tiny-P2", force=True,
                               log=lambda s: None) == out


def test_strecha_download_refuses_a_tampered_file(mirror, tmp_path):
    base, folder, _ = mirror
    (folder / "tiny-P2" / "images" / "0000.jpg").write_bytes(b"tampered")
    root = tmp_path / "root"
    with pytest.raises(ValueError, match=r"images/0000\.jpg"):
        dl.download_dataset("strecha", root=root, url=base, log=lambda s: None)
    assert not (root / "calibrated/strecha/tiny-P2").exists()  # nothing half-written
    with pytest.raises(ValueError, match="sha256 does not apply"):
        dl.download_dataset("strecha-tiny-P2", root=root, sha256="0" * 64)


def test_cli_data_strecha_from_a_mirror(mirror, tmp_path, capsys):
    from ctxmatch_lib.cli import main

    base, _, _ = mirror
    root = tmp_path / "cli-root"
    assert main(["data", "strecha", "--root", str(root), "--url", base]) == 0
    assert (root / "calibrated/strecha/tiny-P2/images/0000.jpg").is_file()
    assert main(["data", "strecha", "--url", "gopher://x"]) == 2


# ------------------------------------------------------------------------------------------- real data
@pytest.mark.realdata
def test_strecha_registered_dataset(data_root):
    ds = load_dataset("strecha", root=data_root)
    counts = {b: sum(pose_difficulty(p) == b for p in ds) for b, _, _ in DIFFICULTY_BANDS}
    assert len(ds) == 52 and counts == {"easy": 17, "medium": 18, "hard": 17}
    assert all(p.image_size1 == (3072, 2048) and p.gt.threshold_scale == 3.0 for p in ds)
    assert {p.pair_id.split("/")[1] for p in ds} == {"fountain-P11", "Herz-Jesus-P8", "castle-P19"}
    assert len(load_dataset("calibrated", root=data_root)) == 52
    folder = load_dataset(data_root / "calibrated" / "strecha" / "fountain-P11")
    assert [p.pair_id.split("/", 1)[1] for p in folder] == [
        p.pair_id.split("/", 1)[1] for p in ds if "/fountain-P11/" in p.pair_id]


def _sampson(F, p1, p2):
    h = np.ones((len(p1), 1))
    x1, x2 = np.c_[p1, h], np.c_[p2, h]
    Fx1, Ftx2 = x1 @ F.T, x2 @ F
    num = np.einsum("ij,ij->i", x2, Fx1)
    return np.abs(num) / np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)


@pytest.mark.slow
@pytest.mark.realdata
@pytest.mark.parametrize("pair_id", ["strecha/fountain-P11/3-4", "strecha/Herz-Jesus-P8/2-3",
                                     "strecha/castle-P19/4-5"])
def test_ground_truth_convention_on_sift_magsac_inliers(data_root, pair_id):
    """The GT F agrees with the images: MAGSAC inliers of SIFT ratio-test matches lie within 1 px of it."""
    import cv2

    from ctxmatch_lib.features import FeatureConfig, extract_features

    pair = next(p for p in load_dataset("strecha", root=data_root) if p.pair_id == pair_id)
    cfg = FeatureConfig(max_keypoints=8000)
    f1, f2 = extract_features(pair.image1, cfg), extract_features(pair.image2, cfg)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(f1.desc.astype(np.float32), f2.desc.astype(np.float32), k=2)
    m = np.array([(a.queryIdx, a.trainIdx) for a, b in knn if a.distance < 0.8 * b.distance])
    p1, p2 = f1.kpts[m[:, 0]], f2.kpts[m[:, 1]]
    _, mask = cv2.findFundamentalMat(p1, p2, cv2.USAC_MAGSAC, 1.0, 0.9999, 100000)
    inl = mask.ravel() > 0
    assert inl.sum() > 200
    assert np.median(_sampson(pair.gt.F, p1[inl], p2[inl])) < 1.0
    # and the labels (15 px x 3) accept nearly all of them
    assert label_matches(f1.kpts, f2.kpts, m[inl], pair.gt).mean() > 0.95
