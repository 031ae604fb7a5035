"""Datasets: the embedded default (deterministic, exact ground truth), real loaders, custom format, download."""

from __future__ import annotations

import argparse
import hashlib
import io
import tarfile

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from ctxmatch_lib.datasets import (
    Dataset, EpipolarGT, FlowGT, HomographyGT, Pair, list_datasets, load_dataset, write_custom_dataset,
)
from ctxmatch_lib.datasets._io import fundamental_from_hand_points
from ctxmatch_lib.datasets.download import download_dataset
from ctxmatch_lib.features import load_image


# ------------------------------------------------------------------------------------------- helpers
def apply_h(H, pts):
    pts = np.asarray(pts, np.float64)
    q = pts @ H[:2, :2].T + H[:2, 2]
    return q / (pts @ H[2, :2] + H[2, 2])[:, None]


def epipolar_distance(F, p1, p2):
    """Symmetric point-to-line distance (the larger of the two), pixels."""
    x1 = np.c_[p1, np.ones(len(p1))]
    x2 = np.c_[p2, np.ones(len(p2))]
    l2, l1 = x1 @ F.T, x2 @ F
    num = np.abs(np.einsum("ij,ij->i", x2, l2))
    return np.maximum(num / np.hypot(l2[:, 0], l2[:, 1]), num / np.hypot(l1[:, 0], l1[:, 1]))


def homography_flow(H, w, h):
    yy, xx = np.mgrid[0:h, 0:w]
    pts = np.c_[xx.ravel(), yy.ravel()].astype(np.float64)
    q = apply_h(H, pts)
    flow = (q - pts).reshape(h, w, 2)
    inside = (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
    flow[~inside.reshape(h, w)] = np.nan
    return flow


def warp_ncc(img1, img2, flow, dx=0.0):
    """Correlation between image 1 and image 2 sampled where the flow sends each image-1 pixel."""
    h, w = img1.shape
    yy, xx = np.mgrid[0:h, 0:w]
    ok = np.isfinite(flow[..., 0])
    v = map_coordinates(img2.astype(np.float64), [yy[ok] + flow[..., 1][ok], xx[ok] + flow[..., 0][ok] + dx],
                        order=1, mode="nearest")
    return np.corrcoef(img1[ok].astype(np.float64), v)[0, 1]


def camera_pair(n, rng):
    """Exact correspondences of 3-D points seen by two cameras, and the true F (x2^T F x1 = 0)."""
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    a = 0.2
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([-1.0, 0.1, 0.2])
    X = np.c_[rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(5, 9, n)]
    x1 = X @ K.T
    x2 = (X @ R.T + t) @ K.T
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K)
    return x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:], Ki.T @ tx @ R @ Ki


# ------------------------------------------------------------------------------------------ embedded
@pytest.fixture(scope="module")
def embedded(tmp_path_factory):
    return load_dataset("embedded", root=tmp_path_factory.mktemp("embedded"))


def test_registered_names():
    assert list_datasets() == ["embedded", "embedded-planar", "embedded-nonplanar", "embedded-depth",
                               "embedded-calibrated", "hpatches", "oxford", "homogr", "kusvod2", "strecha", "strecha-half", "planar",
                               "nonplanar", "calibrated"]


def test_embedded_contents(embedded):
    assert isinstance(embedded, Dataset) and embedded.name == "embedded"
    assert len(embedded) == 20 and len(list(embedded)) == 20
    kinds = [p.kind for p in embedded]
    assert (kinds.count("planar"), kinds.count("nonplanar"), kinds.count("depth")) == (15, 4, 1)
    assert len({p.pair_id for p in embedded}) == 20
    for p in embedded:
        assert isinstance(p, Pair) and p.image1.is_file() and p.image2.is_file()
        img = load_image(p.image1)
        assert (img.shape[1], img.shape[0]) == p.image_size1
        expected = {"planar": HomographyGT, "nonplanar": FlowGT, "depth": FlowGT}[p.kind]
        assert isinstance(p.gt, expected)
    assert {p.image_size1 for p in embedded if p.kind != "depth"} == {(640, 480)}
    assert [p.image_size1 for p in embedded if p.kind == "depth"] == [(741, 500)]


def test_embedded_subsets(embedded):
    root = embedded.root.parent
    for name, kind, n in (("embedded-planar", "planar", 15), ("embedded-nonplanar", "nonplanar", 4),
                          ("embedded-depth", "depth", 1)):
        ds = load_dataset(name, root=root)
        assert ds.name == name and len(ds) == n and {p.kind for p in ds} == {kind}
    assert len(embedded.by_kind("planar")) == 15


@pytest.mark.slow
def test_embedded_is_deterministic(embedded, tmp_path):
    from ctxmatch_lib.datasets.embedded import generate_embedded

    again = generate_embedded(tmp_path / "again")
    files = sorted(p.relative_to(embedded.root) for p in embedded.root.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        if rel.suffix == ".npz":
            with np.load(embedded.root / rel) as a, np.load(again / rel) as b:
                for key in a.files:
                    np.testing.assert_array_equal(a[key], b[key])
        else:
            assert (embedded.root / rel).read_bytes() == (again / rel).read_bytes(), rel


def test_embedded_planar_ground_truth_is_exact(embedded):
    for p in embedded.by_kind("planar"):
        img1, img2 = load_image(p.image1), load_image(p.image2)
        flow = homography_flow(p.gt.H, *p.image_size1)
        exact = warp_ncc(img1, img2, flow)
        # The true map correlates best: better than one shifted by half a pixel either way.
        assert exact > 0.95, p.pair_id
        assert exact > max(warp_ncc(img1, img2, flow, dx) for dx in (-0.5, 0.5)), p.pair_id


def test_embedded_planar_sequences_grow_harder(embedded):
    for seq in ("poster", "lab", "hubble"):
        pairs = [p for p in embedded if p.pair_id.startswith(f"planar/{seq}/")]
        assert [p.pair_id.rsplit("-", 1)[1] for p in pairs] == ["2", "3", "4", "5", "6"]
        assert len({p.image1 for p in pairs}) == 1  # one reference image
        grid = np.mgrid[0:480:4, 0:640:4].reshape(2, -1)[::-1].T.astype(np.float64)
        overlap = []
        for p in pairs:
            q = apply_h(p.gt.H, grid)
            overlap.append(np.mean((q[:, 0] >= 0) & (q[:, 0] <= 639) & (q[:, 1] >= 0) & (q[:, 1] <= 479)))
        assert all(a > b for a, b in zip(overlap, overlap[1:])), (seq, overlap)


def test_embedded_nonplanar_flow_is_exact_with_occlusion(embedded):
    for p in embedded.by_kind("nonplanar"):
        img1, img2 = load_image(p.image1), load_image(p.image2)
        f12, f21 = p.gt.flow12, p.gt.flow21
        assert f12.shape == (480, 640, 2) and f21.shape == (480, 640, 2)
        exact = warp_ncc(img1, img2, f12)
        assert exact > 0.97, p.pair_id
        assert exact > max(warp_ncc(img1, img2, f12, dx) for dx in (-0.5, 0.5)), p.pair_id
        # Round trip 1 -> 2 -> 1 is the identity wherever both directions are known.
        yy, xx = np.mgrid[0:480, 0:640]
        ok = np.isfinite(f12[..., 0])
        x2, y2 = xx[ok] + f12[..., 0][ok], yy[ok] + f12[..., 1][ok]
        back = np.stack([map_coordinates(f21[..., c].astype(np.float64), [y2, x2], order=1, mode="nearest")
                         for c in (0, 1)], 1)
        good = np.isfinite(back).all(1)  # NaN wherever a neighbour of the landing point is unknown
        # Bilinear lookup of a per-layer projective flow: only its curvature and float32 storage remain,
        # except next to layer boundaries, where the lookup mixes the flows of two layers.
        err = np.hypot(x2[good] + back[good, 0] - xx[ok][good], y2[good] + back[good, 1] - yy[ok][good])
        assert good.mean() > 0.9 and np.median(err) < 1e-3 and np.mean(err < 0.02) > 0.97, p.pair_id
        # Occlusion: some image-1 points land inside image 2 yet are hidden (NaN), i.e. there are layers.
        h = np.isnan(f12[..., 0]).mean()
        assert 0.02 < h < 0.6, (p.pair_id, h)


def test_embedded_depth_pair_disparity_convention(embedded):
    (p,) = embedded.by_kind("depth")
    left, right = load_image(p.image1), load_image(p.image2)
    f12 = p.gt.flow12
    assert np.nanmax(f12[..., 0]) < 0 and np.all(f12[..., 1][np.isfinite(f12[..., 1])] == 0)
    ncc = warp_ncc(left, right, f12)
    assert ncc > 0.8
    assert ncc > warp_ncc(left, right, f12, 1.0) and ncc > warp_ncc(left, right, f12, -1.0)
    # The opposite sign (the literal reading of the skimage docstring) is far worse.
    assert warp_ncc(left, right, -f12) < ncc - 0.2
    assert warp_ncc(right, left, p.gt.flow21) > 0.8


def test_motorcycle_flow_inversion_on_a_toy_row():
    from ctxmatch_lib.datasets.embedded import motorcycle_flows

    disp = np.full((1, 10), np.nan)
    disp[0, 2:6] = 2.0  # background
    disp[0, 6:9] = 4.0  # a nearer surface: it hides the background where both land
    f12, f21 = motorcycle_flows(disp)
    np.testing.assert_array_equal(f12[0, 2:9, 0], -disp[0, 2:9])
    assert np.isnan(f12[0, :2, 0]).all()
    # Right pixels 0..3 see the background (left 2..5), 2..4 the near surface (left 6..8): it wins on 2, 3.
    np.testing.assert_array_equal(f21[0, :5, 0], [2, 2, 4, 4, 4])
    assert np.isnan(f21[0, 5:, 0]).all()


# ------------------------------------------------------------------------------------- custom format
def test_custom_round_trip(embedded, tmp_path):
    rng = np.random.default_rng(0)
    p1, p2, F = camera_pair(12, rng)
    epi = Pair("epi", embedded[0].image1, embedded[0].image2, (640, 480), (640, 480), "nonplanar",
               EpipolarGT(F / np.linalg.norm(F), p1, p2))
    pairs = [embedded[0], embedded[16], embedded[19], epi]
    write_custom_dataset(pairs, tmp_path / "custom")
    back = load_dataset(str(tmp_path / "custom"))
    assert back.name == "custom" and len(back) == 4
    for a, b in zip(pairs, back):
        assert (a.pair_id, a.kind, a.image_size1, a.image_size2) == (b.pair_id, b.kind, b.image_size1, b.image_size2)
        assert a.image1.resolve() == b.image1.resolve() and a.image2.resolve() == b.image2.resolve()
        assert type(a.gt) is type(b.gt)
    np.testing.assert_array_equal(back[0].gt.H, pairs[0].gt.H)
    np.testing.assert_array_equal(back[1].gt.flow12, pairs[1].gt.flow12)
    np.testing.assert_array_equal(back[2].gt.flow21, pairs[2].gt.flow21)
    np.testing.assert_array_equal(back[3].gt.F, epi.gt.F)
    np.testing.assert_array_equal(back[3].gt.pts1, p1)


def _write_image(path, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    cv2.imwrite(str(path), rng.integers(0, 255, (48, 64), dtype=np.uint8))


def test_custom_hand_written_folder(tmp_path):
    _write_image(tmp_path / "a.png")
    _write_image(tmp_path / "b.png", 1)
    H = np.array([[1.1, 0.05, 3.0], [-0.02, 0.95, -2.0], [1e-4, 0, 1.0]])
    np.savetxt(tmp_path / "H.txt", H)
    p1, p2, F_true = camera_pair(10, np.random.default_rng(1))
    np.savetxt(tmp_path / "pts.txt", np.c_[p1, p2])
    (tmp_path / "pairs.csv").write_text(
        "pair_id,image1,image2,kind,gt\n"
        "plane,a.png,b.png,planar,H.txt\n"
        "scene, a.png, b.png, nonplanar, pts.txt\n"
        "\n"
    )
    ds = load_dataset(tmp_path)
    assert [p.pair_id for p in ds] == ["plane", "scene"]
    assert ds[0].image_size1 == (64, 48)
    np.testing.assert_allclose(ds[0].gt.H, H)
    F = ds[1].gt.F
    assert np.linalg.matrix_rank(F, tol=1e-9 * np.abs(F).max()) == 2
    assert epipolar_distance(F, p1, p2).max() < 1e-6
    # pairs.csv itself is accepted too.
    assert len(load_dataset(tmp_path / "pairs.csv")) == 2


def test_custom_optional_F_column(tmp_path):
    _write_image(tmp_path / "a.png")
    p1, p2, F_true = camera_pair(9, np.random.default_rng(2))
    np.savetxt(tmp_path / "pts.txt", np.c_[p1, p2])
    np.savetxt(tmp_path / "F.txt", F_true)
    (tmp_path / "pairs.csv").write_text("pair_id,image1,image2,kind,gt,F\ns,a.png,a.png,nonplanar,pts.txt,F.txt\n")
    (p,) = load_dataset(tmp_path)
    np.testing.assert_allclose(p.gt.F, F_true / np.linalg.norm(F_true))


def _load_fails(root, pairs_csv, error, match):
    """``load_dataset(root)`` with ``pairs.csv`` holding ``pairs_csv`` raises ``error`` matching ``match``."""
    (root / "pairs.csv").write_text(pairs_csv)
    with pytest.raises(error, match=match):
        load_dataset(root)


def test_empty_pairs_csv_names_the_file(tmp_path):
    _load_fails(tmp_path, "pair_id,image1,image2,kind,gt\n", ValueError, r"pairs\.csv.*no pairs")
    _load_fails(tmp_path, "", ValueError, r"pairs\.csv.* empty")
    _load_fails(tmp_path, "pair_id,image1,image2\nx,a.png,b.png\n", ValueError, "kind, gt")


def test_missing_gt_file_names_the_file(tmp_path):
    _write_image(tmp_path / "a.png")
    _load_fails(tmp_path, "pair_id,image1,image2,kind,gt\np,a.png,a.png,planar,gone/H_1_2.txt\n",
                FileNotFoundError, "H_1_2.txt")
    _load_fails(tmp_path, "pair_id,image1,image2,kind,gt\np,a.png,a.png,nonplanar,pts.txt\n",
                FileNotFoundError, "pts.txt")


def test_corrupt_or_missing_image_names_the_file(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    _write_image(tmp_path / "a.png")
    np.savetxt(tmp_path / "H.txt", np.eye(3))
    _load_fails(tmp_path, "pair_id,image1,image2,kind,gt\np,a.png,bad.png,planar,H.txt\n",
                ValueError, "bad.png")
    _load_fails(tmp_path, "pair_id,image1,image2,kind,gt\np,a.png,nothere.png,planar,H.txt\n",
                FileNotFoundError, "nothere.png")


@pytest.mark.parametrize(
    "row, match",
    [("p,a.png,a.png,curved,H.txt", "kind"), ("p,a.png,a.png,planar,bad.txt", "bad.txt"),
     ("p,a.png,a.png,nonplanar,few.txt", "few.txt"), ("p,a.png,a.png,depth,H.txt", "depth"),
     (",a.png,a.png,planar,H.txt", "pair_id")],
)
def test_custom_bad_rows(tmp_path, row, match):
    _write_image(tmp_path / "a.png")
    np.savetxt(tmp_path / "H.txt", np.eye(3))
    (tmp_path / "bad.txt").write_text("1 2 3\n4 5 6\n")
    np.savetxt(tmp_path / "few.txt", np.ones((3, 4)))
    (tmp_path / "pairs.csv").write_text(f"pair_id,image1,image2,kind,gt\n{row}\n")
    with pytest.raises(ValueError, match=match):
        load_dataset(tmp_path)


def test_unknown_name():
    with pytest.raises(ValueError, match="name_or_path.*embedded"):
        load_dataset("no-such-dataset")


def test_real_loader_without_data(monkeypatch, tmp_path):
    monkeypatch.delenv("CTXMATCH_DATA", raising=False)
    with pytest.raises(FileNotFoundError, match="CTXMATCH_DATA"):
        load_dataset("hpatches")
    with pytest.raises(FileNotFoundError, match="kusvod2"):
        load_dataset("kusvod2", root=tmp_path)


# ---------------------------------------------------------------------------------- fundamental fit
@pytest.mark.parametrize("n", [7, 8, 12])
def test_fit_fundamental_exact(n):
    p1, p2, F_true = camera_pair(n, np.random.default_rng(n))
    F = fundamental_from_hand_points(p1, p2)
    assert epipolar_distance(F, p1, p2).max() < 1e-6
    # Also right on points it was not fitted to (for n = 7 the root choice must be the true one).
    q1, q2, _ = camera_pair(50, np.random.default_rng(100 + n))
    assert np.median(epipolar_distance(F, q1, q2)) < 1e-3


def test_fit_fundamental_noisy_and_bad_input():
    rng = np.random.default_rng(5)
    p1, p2, _ = camera_pair(14, rng)
    F = fundamental_from_hand_points(p1 + rng.normal(0, 0.5, p1.shape), p2 + rng.normal(0, 0.5, p2.shape))
    assert np.median(epipolar_distance(F, p1, p2)) < 1.5
    with pytest.raises(ValueError, match="at least 7"):
        fundamental_from_hand_points(p1[:6], p2[:6])
    with pytest.raises(ValueError, match="same length"):
        fundamental_from_hand_points(p1, p2[:9])


# ---------------------------------------------------------------------------------------- real data
@pytest.mark.realdata
@pytest.mark.parametrize("name, n", [("hpatches", 10), ("oxford", 5), ("homogr", 16), ("kusvod2", 24)])
def test_real_loader_counts(data_root, name, n):
    ds = load_dataset(name, root=data_root)
    assert len(ds) == n and ds.name == name
    for p in ds:
        assert p.image1.is_file() and p.image2.is_file() and p.dataset == name
        assert min(p.image_size1) > 100 and min(p.image_size2) > 100


@pytest.mark.realdata
def test_real_groups(data_root):
    assert len(load_dataset("planar", root=data_root)) == 31
    assert {p.kind for p in load_dataset("planar", root=data_root)} == {"planar"}
    assert len(load_dataset("nonplanar", root=data_root)) == 24
    # The default root is CTXMATCH_DATA, and a dataset folder itself is accepted as root.
    assert len(load_dataset("oxford")) == 5
    assert len(load_dataset("oxford", root=data_root / "planar" / "oxford")) == 5
    assert len(load_dataset("hpatches", root=data_root / "planar" / "hpatches")) == 10


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["hpatches", "oxford"])
def test_sequence_homographies_are_sane(data_root, name):
    for p in load_dataset(name, root=data_root):
        H = p.gt.H
        assert H.shape == (3, 3) and H[2, 2] == pytest.approx(1) and np.linalg.det(H) > 0
        w, h = p.image_size1
        centre = apply_h(H, [[(w - 1) / 2, (h - 1) / 2]])[0]
        w2, h2 = p.image_size2
        assert 0 <= centre[0] <= w2 - 1 and 0 <= centre[1] <= h2 - 1, p.pair_id
        assert p.pair_id.startswith(f"{name}/") and p.pair_id.endswith(("-2", "-3", "-4", "-5", "-6"))


@pytest.mark.realdata
def test_homogr_maps_the_hand_points(data_root):
    import scipy.io

    for p in load_dataset("homogr", root=data_root):
        err = np.linalg.norm(apply_h(p.gt.H, p.gt.pts1) - p.gt.pts2, axis=1)
        assert err.max() < 3, p.pair_id
        # The shipped model maps B to A: our H (A -> B) is its inverse.
        name = p.pair_id.split("/")[1]
        M = np.loadtxt(data_root / "planar" / "homogr" / f"{name}_model.txt")
        np.testing.assert_allclose(p.gt.H, np.linalg.inv(M) / np.linalg.inv(M)[2, 2], rtol=1e-9, atol=1e-12)
        mat = scipy.io.loadmat(data_root / "planar" / "homogr" / f"{name}_vpts.mat")
        assert len(p.gt.pts1) == mat["validation"]["pts"][0, 0].shape[1]


@pytest.mark.realdata
def test_kusvod2_epipolar_geometry(data_root):
    fitted = 0
    for p in load_dataset("kusvod2", root=data_root):
        F = p.gt.F
        s = np.linalg.svd(F, compute_uv=False)
        assert s[2] < 1e-9 * s[0], p.pair_id
        err = epipolar_distance(F, p.gt.pts1, p.gt.pts2)
        assert np.median(err) <= 3, (p.pair_id, np.median(err))
        name = p.pair_id.split("/")[1]
        txt = data_root / "nonplanar" / "kusvod2" / f"{name}_model.txt"
        M = np.loadtxt(txt) if txt.exists() else None
        if M is not None and np.any(M):
            # xA^T M xB = 0 in the file: ours (x2^T F x1 = 0, image 1 = A) is the transpose.
            np.testing.assert_allclose(F, M.T / np.linalg.norm(M), rtol=1e-9, atol=1e-15)
        else:
            fitted += 1
    assert fitted == 17


# ------------------------------------------------------------------------------------------ download
def _fake_oxford_archive(tmp_path, *, top=None):
    import cv2

    src = tmp_path / "src"
    src.mkdir()
    _write_image(src / "img1.png")
    _write_image(src / "img2.png", 1)
    np.savetxt(src / "H1to2p", np.eye(3))
    archive = tmp_path / "graf.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        for f in sorted(src.iterdir()):
            tar.add(f, arcname=f"{top}/{f.name}" if top else f.name)
    assert cv2 is not None
    return archive, hashlib.sha256(archive.read_bytes()).hexdigest()


@pytest.mark.parametrize("top", [None, "graf"])
def test_download_from_local_url(tmp_path, top):
    archive, sha = _fake_oxford_archive(tmp_path, top=top)
    root = tmp_path / "root"
    lines = []
    paths = download_dataset("oxford-graf", root=root, url=archive.as_uri(), sha256=sha, log=lines.append)
    assert paths == [root / "planar" / "oxford" / "graf"]
    ds = load_dataset("oxford", root=root)
    assert [p.pair_id for p in ds] == ["oxford/graf/1-2"]
    # A second call finds it and does nothing.
    download_dataset("oxford-graf", root=root, url=archive.as_uri(), sha256=sha, log=lines.append)
    assert "already present" in lines[-1]


def test_download_rejects_wrong_or_missing_hash(tmp_path):
    archive, sha = _fake_oxford_archive(tmp_path)
    root = tmp_path / "root"
    with pytest.raises(ValueError, match="hash"):
        download_dataset("oxford-graf", root=root, url=archive.as_uri(), sha256="0" * 64, log=lambda s: None)
    assert not (root / "planar" / "oxford" / "graf").exists()
    with pytest.raises(ValueError, match="no pinned SHA-256"):
        download_dataset("kusvod2", root=root, log=lambda s: None)
    with pytest.raises(ValueError, match="sha256"):
        download_dataset("oxford-graf", root=root, url=archive.as_uri(), sha256="xyz", log=lambda s: None)
    with pytest.raises(ValueError, match="name"):
        download_dataset("imagenet", root=root)
    # Unpinned but explicitly allowed: the hash is reported so that it can be pinned.
    lines = []
    download_dataset("kusvod2", root=root, url=archive.as_uri(), allow_unpinned=True, log=lines.append)
    assert any(sha in line for line in lines)


def test_download_refuses_path_traversal(tmp_path):
    archive = tmp_path / "evil.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        data = b"x"
        info = tarfile.TarInfo("../../escape.txt")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    sha = hashlib.sha256(archive.read_bytes()).hexdigest()
    with pytest.raises(ValueError, match="outside"):
        download_dataset("kusvod2", root=tmp_path / "root", url=archive.as_uri(), sha256=sha, log=lambda s: None)
    assert not (tmp_path / "escape.txt").exists()
    assert not (tmp_path / "root" / "nonplanar" / "kusvod2").exists()


def test_cli_data_download(tmp_path, capsys):
    from ctxmatch_lib.cli import data as cli_data

    archive, sha = _fake_oxford_archive(tmp_path)
    parser = argparse.ArgumentParser(prog="ctxmatch")
    cli_data.add_parser(parser.add_subparsers(dest="command", required=True))
    root = tmp_path / "root"
    args = parser.parse_args(["data", "download", "oxford-graf", "--root", str(root), "--url", archive.as_uri(),
                              "--sha256", sha])
    assert args.func(args) == 0
    assert (root / "planar" / "oxford" / "graf" / "H1to2p").is_file()
    args = parser.parse_args(["data", "download", "homogr", "--root", str(root)])
    assert args.func(args) == 1
    assert "no pinned SHA-256" in capsys.readouterr().err
    (tmp_path / "file").write_text("a regular file")
    for command in (["download", "oxford-graf"], ["embedded"]):
        args = parser.parse_args(["data", *command, "--root", str(tmp_path / "file" / "root")])
        assert args.func(args) == 2
        err = capsys.readouterr().err
        assert "--root: cannot create" in err and "is a file, not a folder" in err
    for flags, named in ((["--url", archive.as_uri(), "--sha256", "xyz"], "--sha256"),
                         (["--url", "archive.tar.gz", "--sha256", sha], "--url")):
        args = parser.parse_args(["data", "download", "oxford-graf", "--root", str(root), *flags])
        assert args.func(args) == 2 and f"{named} must" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parser.parse_args(["data", "download", "imagenet"])
