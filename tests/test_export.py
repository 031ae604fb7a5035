"""hloc HDF5 and COLMAP database exports, each read back (with our readers, with hloc's reading rules and,
when installed, with pycolmap)."""

import sqlite3

import numpy as np
import pytest

from ctxmatch_lib.io.export import colmap_pair_id, names_to_pair, read_colmap, read_hloc, write_colmap, write_hloc


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    k1 = rng.uniform(0, 640, (50, 2))
    k2 = rng.uniform(0, 480, (40, 2))
    m = np.c_[rng.permutation(50)[:30], rng.integers(0, 40, 30)]  # one match per image-1 keypoint
    s = rng.uniform(0, 1, 30)
    return k1, k2, m.astype(np.int64), s


def _sorted(m, s=None):
    order = np.lexsort((m[:, 1], m[:, 0]))
    return m[order] if s is None else (m[order], s[order])


def test_hloc_round_trip(tmp_path, pair):
    h5py = pytest.importorskip("h5py", reason="h5py not installed (pip install 'ctxmatch[export]')")
    k1, k2, m, s = pair
    feats, matches = tmp_path / "features.h5", tmp_path / "matches.h5"
    assert write_hloc(feats, matches, "db/a.jpg", "b.jpg", k1, k2, m, s, image_size1=(640, 480),
                      image_size2=(500, 480)) == 30
    r1, r2, rm, rs = read_hloc(feats, matches, "db/a.jpg", "b.jpg")
    np.testing.assert_array_equal(rm, _sorted(m))
    np.testing.assert_array_equal(r1, k1.astype(np.float32))
    np.testing.assert_array_equal(r2, k2.astype(np.float32))
    np.testing.assert_allclose(rs, _sorted(m, s)[1], atol=1e-3)  # float16 confidences
    # The layout hloc reads: groups per image name, "name0/name1" per pair, matches0 int16 with -1.
    with h5py.File(feats, "r") as fd:
        assert fd["db/a.jpg"]["keypoints"].dtype == np.float32 and fd["b.jpg"]["image_size"][()].tolist() == [500, 480]
    with h5py.File(matches, "r") as fd:
        key = names_to_pair("db/a.jpg", "b.jpg")
        assert key == "db-a.jpg/b.jpg"
        m0 = fd[key]["matches0"][()]
        sc0 = fd[key]["matching_scores0"][()]
    assert m0.dtype == np.int16 and m0.shape == (50,) and sc0.dtype == np.float16
    idx = np.flatnonzero(m0 != -1)  # hloc.utils.io.get_matches
    np.testing.assert_array_equal(np.stack([idx, m0[idx]], -1), _sorted(m))
    # Read in the other order: columns swapped.
    _, _, rev, _ = read_hloc(feats, matches, "b.jpg", "db/a.jpg")
    np.testing.assert_array_equal(_sorted(rev[:, ::-1].copy()), _sorted(m))


def test_hloc_many_to_many_and_conflicts(tmp_path, pair):
    pytest.importorskip("h5py", reason="h5py not installed (pip install 'ctxmatch[export]')")
    k1, k2, m, s = pair
    mm = np.r_[m, [[m[0, 0], (m[0, 1] + 1) % 40]]]  # image-1 keypoint m[0, 0] matched twice
    ss = np.r_[s, s[0] / 2]  # the new one is better
    feats, matches = tmp_path / "f.h5", tmp_path / "m.h5"
    with pytest.raises(ValueError, match="duplicates='best'"):
        write_hloc(feats, matches, "a", "b", k1, k2, mm, ss)
    assert write_hloc(feats, matches, "a", "b", k1, k2, mm, ss, duplicates="best") == 30
    _, _, rm, _ = read_hloc(feats, matches, "a", "b")
    expected = np.r_[m[1:], mm[-1:]]
    np.testing.assert_array_equal(rm, _sorted(expected))
    with pytest.raises(ValueError, match="other keypoints"):
        write_hloc(feats, matches, "a", "c", k1 + 1, k2, m, s)
    # Empty matches: every keypoint unmatched.
    write_hloc(feats, matches, "a", "d", k1, k2, np.empty((0, 2), np.int64))
    assert read_hloc(feats, matches, "a", "d")[2].shape == (0, 2)


def test_colmap_round_trip(tmp_path, pair):
    k1, k2, m, _ = pair
    many = np.r_[m, [[m[0, 0], (m[0, 1] + 1) % 40]]]  # COLMAP takes many-to-many as it is
    db = tmp_path / "database.db"
    # name2 first into the database, so that its id is smaller: the stored columns are swapped.
    id_b, id_c = write_colmap(db, "b.jpg", "c.jpg", k2, k1, np.empty((0, 2), int), image_size1=(500, 480),
                              image_size2=(640, 480))
    id_a, id_b2 = write_colmap(db, "a.jpg", "b.jpg", k1, k2, many, image_size1=(640, 480), image_size2=(500, 480))
    assert id_b2 == id_b < id_a
    r1, r2, rm = read_colmap(db, "a.jpg", "b.jpg")
    np.testing.assert_array_equal(rm, many)
    np.testing.assert_array_equal(r1, (k1 + 0.5).astype(np.float32).astype(np.float64) - 0.5)
    np.testing.assert_array_equal(read_colmap(db, "b.jpg", "a.jpg")[2], many[:, ::-1])
    # The raw rows, as the schema documents them.
    con = sqlite3.connect(db)
    rows, cols, data = con.execute("SELECT rows, cols, data FROM matches WHERE pair_id = ?",
                                   (colmap_pair_id(id_a, id_b),)).fetchone()
    assert (rows, cols) == (len(many), 2)
    np.testing.assert_array_equal(np.frombuffer(data, np.uint32).reshape(-1, 2), many[:, ::-1])
    r, c, kp = con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?", (id_a,)).fetchone()
    np.testing.assert_array_equal(np.frombuffer(kp, np.float32).reshape(r, c), (k1 + 0.5).astype(np.float32))
    model, w, h, params = con.execute("SELECT model, width, height, params FROM cameras c JOIN images i "
                                      "ON c.camera_id = i.camera_id WHERE i.name = 'a.jpg'").fetchone()
    con.close()
    assert (model, w, h) == (2, 640, 480)
    np.testing.assert_array_equal(np.frombuffer(params, np.float64), [768.0, 320.0, 240.0, 0.0])
    with pytest.raises(ValueError, match="other keypoints"):
        write_colmap(db, "a.jpg", "d.jpg", k1 * 2, k2, m, image_size2=(10, 10))
    with pytest.raises(ValueError, match="image_size"):
        write_colmap(db, "a.jpg", "e.jpg", k1, k2, m)


def test_colmap_database_opens_in_pycolmap(tmp_path, pair):
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap not installed: COLMAP's own reader not checked")
    k1, k2, m, _ = pair
    db = tmp_path / "database.db"
    write_colmap(db, "b.jpg", "a.jpg", k2, k1, m[:, ::-1], image_size1=(500, 480), image_size2=(640, 480))
    with pycolmap.Database.open(str(db)) as d:
        ids = {im.name: im.image_id for im in d.read_all_images()}
        np.testing.assert_array_equal(d.read_keypoints(ids["a.jpg"])[:, :2], (k1 + 0.5).astype(np.float32))
        np.testing.assert_array_equal(d.read_matches(ids["a.jpg"], ids["b.jpg"]).astype(np.int64), m)
        cam = d.read_camera(d.read_image(ids["a.jpg"]).camera_id)
        assert (cam.width, cam.height) == (640, 480)


def test_cli_exports(tmp_path):
    pytest.importorskip("h5py", reason="h5py not installed (pip install 'ctxmatch[export]')")
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.match import load_result

    from test_match_cli import _write_pair

    a, b = _write_pair(tmp_path / "imgs")
    out = tmp_path / "m.npz"
    assert main(["match", str(a), str(b), "--out", str(out), "--max-keypoints", "300", "--no-cache",
                 "--export-h5", str(tmp_path / "hloc"), "--export-colmap", str(tmp_path / "db.db")]) == 0
    d = load_result(out)
    np.testing.assert_array_equal(read_colmap(tmp_path / "db.db", "a.png", "b.png")[2], d["matches"])
    _, _, hm, _ = read_hloc(tmp_path / "hloc" / "features.h5", tmp_path / "hloc" / "matches.h5", "a.png", "b.png")
    # hloc keeps the best-scored match of each image-1 keypoint: a subset with every image-1 keypoint present.
    assert set(map(tuple, hm.tolist())) <= set(map(tuple, d["matches"].tolist()))
    assert set(hm[:, 0].tolist()) == set(d["matches"][:, 0].tolist())


# ---------------------------------------------------------------- bad output paths
@pytest.mark.parametrize("where, reason", [
    ("file/db.db", "is a file, not a folder"),        # the corpus' case: a regular file in the path
    ("file/sub/db.db", "is a file, not a folder"),
    ("folder", "is a folder, not a file"),
    ("file", "is not an SQLite database"),            # an existing file of another kind: left untouched
])
def test_write_colmap_bad_database_path_names_the_argument(tmp_path, pair, where, reason):
    k1, k2, m, _ = pair
    (tmp_path / "file").write_text("a regular file")
    (tmp_path / "folder").mkdir()
    with pytest.raises(ValueError, match=f"^database_path: .*{reason}"):
        write_colmap(tmp_path / where, "a.jpg", "b.jpg", k1, k2, m, image_size1=(640, 480),
                     image_size2=(640, 480))
    assert (tmp_path / "file").read_text() == "a regular file"


def test_write_colmap_read_only_database_names_the_argument(tmp_path, pair, monkeypatch):
    import os

    import ctxmatch_lib.cache as paths

    k1, k2, m, _ = pair
    db = tmp_path / "db.db"
    write_colmap(db, "a.jpg", "b.jpg", k1, k2, m, image_size1=(640, 480), image_size2=(640, 480))
    # Permissions as a non-root user would see them (tests may run as root, who may write anything).
    monkeypatch.setattr(paths.os, "access", lambda p, mode: os.fspath(p) != os.fspath(db))
    with pytest.raises(ValueError, match="^database_path: .*db.db is not writable"):
        write_colmap(db, "a.jpg", "c.jpg", k1, k2, m, image_size1=(640, 480), image_size2=(640, 480))
    monkeypatch.undo()
    assert read_colmap(db, "a.jpg", "b.jpg")[2].shape == m.shape


def test_write_colmap_empty_file_is_a_new_database(tmp_path, pair):
    # SQLite treats an empty file as a new database: touch-then-write keeps working.
    k1, k2, m, _ = pair
    db = tmp_path / "db.db"
    db.touch()
    write_colmap(db, "a.jpg", "b.jpg", k1, k2, m, image_size1=(640, 480), image_size2=(640, 480))
    assert len(read_colmap(db, "a.jpg", "b.jpg")[2]) == len(m)


def test_write_hloc_bad_paths_name_the_argument(tmp_path, pair):
    pytest.importorskip("h5py", reason="h5py not installed (pip install 'ctxmatch[export]')")
    k1, k2, m, s = pair
    (tmp_path / "file").write_text("a regular file")
    with pytest.raises(ValueError, match="^features_path: .*is a file, not a folder"):
        write_hloc(tmp_path / "file" / "f.h5", tmp_path / "m.h5", "a", "b", k1, k2, m, s)
    with pytest.raises(ValueError, match="^matches_path: .*is not an HDF5 file"):
        write_hloc(tmp_path / "f.h5", tmp_path / "file", "a", "b", k1, k2, m, s)


def test_readers_name_a_missing_or_foreign_file(tmp_path, pair):
    (tmp_path / "file").write_text("a regular file")
    with pytest.raises(FileNotFoundError, match="^database_path: file not found"):
        read_colmap(tmp_path / "none.db", "a.jpg", "b.jpg")
    with pytest.raises(ValueError, match="^database_path: .* is not a COLMAP database"):
        read_colmap(tmp_path / "file", "a.jpg", "b.jpg")
    pytest.importorskip("h5py", reason="h5py not installed (pip install 'ctxmatch[export]')")
    with pytest.raises(FileNotFoundError, match="^features_path: file not found"):
        read_hloc(tmp_path / "none.h5", tmp_path / "m.h5", "a", "b")
    k1, k2, m, s = pair
    write_hloc(tmp_path / "f.h5", tmp_path / "m.h5", "a", "b", k1, k2, m, s)
    with pytest.raises(KeyError, match="image 'c' not in"):
        read_hloc(tmp_path / "f.h5", tmp_path / "m.h5", "a", "c")
