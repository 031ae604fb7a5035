"""Exports for structure-from-motion pipelines: hloc's HDF5 files and a COLMAP database.

- hloc (:func:`write_hloc`, :func:`read_hloc`, needs ``h5py``: the ``export`` extra): ``keypoints`` per image,
  ``matches0`` (int16, one match per image-0 keypoint) and ``matching_scores0`` (``1 - score``) per pair.
- COLMAP (:func:`write_colmap`, :func:`read_colmap`): its documented SQLite schema through ``sqlite3``; one
  ``SIMPLE_RADIAL`` camera per image (focal 1.2 max(w, h), COLMAP's guess without EXIF), keypoints +0.5 px
  (corner origin), many-to-many matches kept.

Formats and commands: docs/interop.md.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .._numerics.docstrings import shared_doc
from .._numerics.extras import require
from .._numerics.validation import as_image_size, as_matches, as_points, as_scores

__all__ = ["names_to_pair", "write_hloc", "read_hloc", "write_colmap", "read_colmap", "colmap_pair_id",
           "check_export_paths", "export_results"]

#: COLMAP's bound on image ids, the base of its pair ids.
COLMAP_MAX_IMAGE_ID = 2147483647
#: COLMAP camera model id of SIMPLE_RADIAL (f, cx, cy, k).
_SIMPLE_RADIAL = 2


def _h5py():
    return require("h5py", "export", "writing or reading hloc's HDF5 files (write_hloc, read_hloc, --export-h5)")


def names_to_pair(name0: str, name1: str, separator: str = "/") -> str:
    """hloc's pair key: ``"name0/name1"`` with ``/`` inside each name replaced by ``-``.

    Parameters
    ----------
    name0, name1 : str
    separator : str, default "/"
        ``"_"`` in hloc's older files.

    Examples
    --------
    >>> names_to_pair("db/a.jpg", "q/b.jpg")
    'db-a.jpg/q-b.jpg'
    """
    return separator.join((name0.replace("/", "-"), name1.replace("/", "-")))


def _check_pair(kpts1, kpts2, matches, scores):
    k1 = as_points(kpts1, "kpts1")
    k2 = as_points(kpts2, "kpts2")
    m = as_matches(matches, len(k1), len(k2))
    s = as_scores(scores, len(m))
    return k1, k2, m, s


_SQLITE_MAGIC = b"SQLite format 3\x00"


def _check_colmap_path(path, name: str) -> Path:
    """A COLMAP database path that can be written: a new file, an empty one or an SQLite database."""
    from ..cache import check_writable

    path = check_writable(path, name)
    if path.is_file() and path.stat().st_size:
        with open(path, "rb") as fh:
            head = fh.read(len(_SQLITE_MAGIC))
        if head != _SQLITE_MAGIC:
            raise ValueError(f"{name}: {path} exists and is not an SQLite database (COLMAP's format); "
                             "give a new file name or a COLMAP database")
    return path


def _check_h5_path(path, name: str) -> Path:
    """An hloc HDF5 path that can be written: a new file or an HDF5 file."""
    from ..cache import check_writable

    path = check_writable(path, name)
    if path.is_file() and path.stat().st_size:
        h5py = _h5py()
        if not h5py.is_hdf5(str(path)):
            raise ValueError(f"{name}: {path} exists and is not an HDF5 file (hloc's format)")
    return path


def check_export_paths(h5_dir=None, colmap_db=None, *, h5_name: str = "h5_dir",
                       colmap_name: str = "colmap_db") -> None:
    """Check the targets of :func:`export_results` before any work; nothing is created.

    Parameters
    ----------
    h5_dir : str or Path, optional
        A creatable folder; its ``features.h5`` / ``matches.h5``, where present, must be HDF5.
    colmap_db : str or Path, optional
        A new or empty file, or an SQLite database.
    h5_name, colmap_name : str
        The names the ``ValueError`` messages start with.
    """
    if h5_dir is not None:
        from ..cache import check_writable

        folder = check_writable(h5_dir, h5_name, folder=True)
        for file in ("features.h5", "matches.h5"):
            _check_h5_path(folder / file, h5_name)
    if colmap_db is not None:
        _check_colmap_path(colmap_db, colmap_name)


def _reduce_one_per_row(m: np.ndarray, s: np.ndarray):
    """The best-scored match of each image-0 keypoint (ties: the first given)."""
    order = np.lexsort((np.arange(len(m)), s, m[:, 0]))
    first = np.r_[True, m[order[1:], 0] != m[order[:-1], 0]] if len(m) else np.zeros(0, bool)
    pick = np.sort(order[first])
    return m[pick], s[pick]


# -------------------------------------------------------------------------------------------------- hloc
def _write_h5_features(fd, name: str, kpts: np.ndarray, image_size) -> None:
    kp = np.asarray(kpts, np.float32)
    if name in fd and "keypoints" in fd[name]:
        old = fd[name]["keypoints"][()]
        if old.shape != kp.shape or not np.array_equal(old, kp):
            raise ValueError(f"image {name!r} is already in the features file with other keypoints "
                             f"({len(old)} vs {len(kp)}); matches index into them, so they cannot change")
        return
    grp = fd.require_group(name)
    grp.create_dataset("keypoints", data=kp)
    if image_size is not None:
        grp.create_dataset("image_size", data=np.asarray(image_size, np.int64))


@shared_doc
def write_hloc(features_path, matches_path, name1: str, name2: str, kpts1, kpts2, matches, scores=None, *,
               image_size1=None, image_size2=None, duplicates: str = "error") -> int:
    """Add one pair to hloc's ``features.h5`` and ``matches.h5``; return the number of matches written.

    Parameters
    ----------
    features_path, matches_path : str or Path
        An image already present must have the same keypoints.
    name1, name2 : str
        Image names, relative to the image folder.
    %(kpts)s
    %(matches)s
    scores : array_like of shape (K,), optional
        Lower is better, stored as ``1 - score``; default 0.
    image_size1, image_size2 : (int, int), optional
    duplicates : {"error", "best"}
        For an image-1 keypoint with several matches: raise ``ValueError``, or keep the best-scored one.
    """
    h5py = _h5py()

    k1, k2, m, s = _check_pair(kpts1, kpts2, matches, scores)
    if duplicates not in ("error", "best"):
        raise ValueError(f"duplicates must be 'error' or 'best', got {duplicates!r}")
    if len(k1) > np.iinfo(np.int16).max or len(k2) > np.iinfo(np.int16).max:
        raise ValueError(f"hloc stores matches0 as int16: at most {np.iinfo(np.int16).max} keypoints per image, "
                         f"got {len(k1)} and {len(k2)}")
    if len(np.unique(m[:, 0])) != len(m):
        if duplicates == "error":
            raise ValueError("matches has several matches for one image-1 keypoint, which hloc's matches0 cannot "
                             "hold; pass duplicates='best' to keep the best-scored one of each")
        m, s = _reduce_one_per_row(m, s)
    size1 = None if image_size1 is None else as_image_size(image_size1, "image_size1")
    size2 = None if image_size2 is None else as_image_size(image_size2, "image_size2")
    _check_h5_path(features_path, "features_path")
    _check_h5_path(matches_path, "matches_path")
    matches0 = np.full(len(k1), -1, np.int16)
    matches0[m[:, 0]] = m[:, 1]
    scores0 = np.zeros(len(k1), np.float16)
    scores0[m[:, 0]] = 1.0 - s
    Path(features_path).parent.mkdir(parents=True, exist_ok=True)
    Path(matches_path).parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(str(features_path), "a", libver="latest") as fd:
        _write_h5_features(fd, name1, k1, size1)
        _write_h5_features(fd, name2, k2, size2)
    pair = names_to_pair(name1, name2)
    with h5py.File(str(matches_path), "a", libver="latest") as fd:
        if pair in fd:
            del fd[pair]
        grp = fd.create_group(pair)
        grp.create_dataset("matches0", data=matches0)
        grp.create_dataset("matching_scores0", data=scores0)
    return len(m)


def read_hloc(features_path, matches_path, name1: str, name2: str):
    """``(kpts1, kpts2, matches, scores)`` of one pair, read as hloc's ``get_keypoints`` / ``get_matches`` do.

    Matches are sorted by image-1 row; scores are ``1 - matching_scores0`` (float16 precision).

    Parameters
    ----------
    features_path, matches_path : str or Path
    name1, name2 : str
        A pair stored in either order.
    """
    h5py = _h5py()

    for arg, path in (("features_path", features_path), ("matches_path", matches_path)):
        if not Path(path).is_file():
            raise FileNotFoundError(f"{arg}: file not found: {path}")
    with h5py.File(str(features_path), "r") as fd:
        for name in (name1, name2):
            if name not in fd:
                raise KeyError(f"image {name!r} not in {features_path}")
        k1 = fd[name1]["keypoints"][()].astype(np.float64)
        k2 = fd[name2]["keypoints"][()].astype(np.float64)
    with h5py.File(str(matches_path), "r") as fd:
        for a, b, rev in ((name1, name2, False), (name2, name1, True)):
            key = names_to_pair(a, b)
            if key in fd:
                m0 = fd[key]["matches0"][()].astype(np.int64)
                sc = fd[key]["matching_scores0"][()].astype(np.float64)
                break
        else:
            raise KeyError(f"pair ({name1!r}, {name2!r}) not in {matches_path}")
    idx = np.flatnonzero(m0 != -1)
    m = np.stack([idx, m0[idx]], -1).astype(np.int64).reshape(-1, 2)
    s = 1.0 - sc[idx]
    if rev:
        m = m[:, ::-1]
        order = np.lexsort((m[:, 1], m[:, 0]))
        m, s = np.ascontiguousarray(m[order]), s[order]
    return k1, k2, m, s


# ------------------------------------------------------------------------------------------------ COLMAP
def colmap_pair_id(image_id1: int, image_id2: int) -> int:
    """COLMAP's symmetric ``pair_id``: ``2147483647 * min(ids) + max(ids)`` (COLMAP's ``doc/database.rst``).

    Parameters
    ----------
    image_id1, image_id2 : int

    Examples
    --------
    >>> colmap_pair_id(1, 2) == colmap_pair_id(2, 1) == 2147483647 + 2
    True
    """
    a, b = sorted((int(image_id1), int(image_id2)))
    return COLMAP_MAX_IMAGE_ID * a + b


_COLMAP_SCHEMA = """
CREATE TABLE IF NOT EXISTS cameras
   (camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, model INTEGER NOT NULL, width INTEGER NOT NULL,
    height INTEGER NOT NULL, params BLOB, prior_focal_length INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS images
   (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, name TEXT NOT NULL UNIQUE,
    camera_id INTEGER NOT NULL,
    CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),
    FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX IF NOT EXISTS index_name ON images(name);
CREATE TABLE IF NOT EXISTS keypoints
   (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL, data BLOB,
    FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS descriptors
   (image_id INTEGER PRIMARY KEY NOT NULL, type INTEGER NOT NULL DEFAULT 0, rows INTEGER NOT NULL,
    cols INTEGER NOT NULL, data BLOB,
    FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS matches
   (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL, data BLOB);
CREATE TABLE IF NOT EXISTS two_view_geometries
   (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL, data BLOB,
    config INTEGER NOT NULL, F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB, camera1 BLOB, camera2 BLOB);
"""


def _colmap_image(con: sqlite3.Connection, name: str, kpts: np.ndarray, image_size) -> int:
    row = con.execute("SELECT image_id FROM images WHERE name = ?", (name,)).fetchone()
    data = np.ascontiguousarray(kpts + 0.5, np.float32)  # COLMAP: (0, 0) is the corner of the top-left pixel
    if row is not None:
        image_id = int(row[0])
        kp = con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?", (image_id,)).fetchone()
        if kp is not None:
            old = np.frombuffer(kp[2], np.float32).reshape(kp[0], kp[1])[:, :2] if kp[0] else np.empty((0, 2), np.float32)
            if old.shape != data.shape or not np.array_equal(old, data):
                raise ValueError(f"image {name!r} is already in the database with other keypoints "
                                 f"({len(old)} vs {len(data)}); matches index into them, so they cannot change")
            return image_id
    else:
        if image_size is None:
            raise ValueError(f"image_size of {name!r} is required to add it to the COLMAP database (its camera)")
        w, h = as_image_size(image_size, "image_size")
        f = 1.2 * max(w, h)
        params = np.array([f, w / 2.0, h / 2.0, 0.0], np.float64)
        cur = con.execute("INSERT INTO cameras (model, width, height, params, prior_focal_length) VALUES (?, ?, ?, ?, ?)",
                          (_SIMPLE_RADIAL, w, h, params.tobytes(), 0))
        cur = con.execute("INSERT INTO images (name, camera_id) VALUES (?, ?)", (name, cur.lastrowid))
        image_id = int(cur.lastrowid)
    con.execute("INSERT OR REPLACE INTO keypoints (image_id, rows, cols, data) VALUES (?, ?, ?, ?)",
                (image_id, data.shape[0], 2, data.tobytes()))
    return image_id


@shared_doc
def write_colmap(database_path, name1: str, name2: str, kpts1, kpts2, matches, *, image_size1=None,
                 image_size2=None) -> tuple[int, int]:
    """Add one pair to a COLMAP database (created when absent); return the two image ids.

    Parameters
    ----------
    database_path : str or Path
        A COLMAP database (known images keep their ids and must have the same keypoints) or a new file.
    name1, name2 : str
        Image names, relative to COLMAP's image folder.
    %(kpts)s
    %(matches)s
    image_size1, image_size2 : (int, int), optional
        Required for an image not yet in the database (its camera).
    """
    k1, k2, m, _ = _check_pair(kpts1, kpts2, matches, None)
    if name1 == name2:
        raise ValueError(f"name1 and name2 must differ, got {name1!r} twice")
    path = _check_colmap_path(database_path, "database_path")
    path.parent.mkdir(parents=True, exist_ok=True)
    con = sqlite3.connect(str(path))
    try:
        with con:
            con.executescript(_COLMAP_SCHEMA)
            id1 = _colmap_image(con, name1, k1, image_size1)
            id2 = _colmap_image(con, name2, k2, image_size2)
            mm = m if id1 < id2 else m[:, ::-1]
            data = np.ascontiguousarray(mm, np.uint32)
            con.execute("INSERT OR REPLACE INTO matches (pair_id, rows, cols, data) VALUES (?, ?, ?, ?)",
                        (colmap_pair_id(id1, id2), data.shape[0], 2, data.tobytes()))
    except sqlite3.DatabaseError as exc:  # locked, read-only or corrupt past its header; nothing was committed
        raise ValueError(f"database_path: cannot write the COLMAP database {path}: {exc}") from exc
    finally:
        con.close()
    return id1, id2


def read_colmap(database_path, name1: str, name2: str):
    """``(kpts1, kpts2, matches)`` of one pair of a COLMAP database, keypoints back in the pixel-centre origin.

    Parameters
    ----------
    database_path : str or Path
    name1, name2 : str
    """
    if not Path(database_path).is_file():
        raise FileNotFoundError(f"database_path: file not found: {database_path}")
    con = sqlite3.connect(f"file:{Path(database_path)}?mode=ro", uri=True)
    try:
        con.execute("SELECT 1 FROM images LIMIT 1")
    except sqlite3.DatabaseError as exc:
        con.close()
        raise ValueError(f"database_path: {database_path} is not a COLMAP database: {exc}") from None
    try:
        ids, kps = [], []
        for name in (name1, name2):
            row = con.execute("SELECT image_id FROM images WHERE name = ?", (name,)).fetchone()
            if row is None:
                raise KeyError(f"image {name!r} not in {database_path}")
            ids.append(int(row[0]))
            r, c, data = con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?", (row[0],)).fetchone()
            kp = np.frombuffer(data, np.float32).reshape(r, c)[:, :2] if r else np.empty((0, 2), np.float32)
            kps.append(kp.astype(np.float64) - 0.5)
        row = con.execute("SELECT rows, cols, data FROM matches WHERE pair_id = ?", (colmap_pair_id(*ids),)).fetchone()
    finally:
        con.close()
    if row is None or not row[0]:
        m = np.empty((0, 2), np.int64)
    else:
        m = np.frombuffer(row[2], np.uint32).reshape(row[0], row[1]).astype(np.int64)
    if ids[0] > ids[1]:
        m = np.ascontiguousarray(m[:, ::-1])
    return kps[0], kps[1], m


# ---------------------------------------------------------------------------------------- from the CLI
def export_results(results: Mapping, *, h5_dir=None, colmap_db=None, duplicates: str = "best") -> list[str]:
    """Export :func:`ctxmatch_lib.match.save_result` files to hloc and/or COLMAP; one summary line each.

    Parameters
    ----------
    results : mapping of (str, str) -> path
        Image names ``(name1, name2)`` -> the pair's ``.npz``.
    h5_dir : str or Path, optional
        Folder for hloc's ``features.h5`` and ``matches.h5``.
    colmap_db : str or Path, optional
    duplicates : {"best", "error"}
        As in :func:`write_hloc`.
    """
    from ..match import load_result

    check_export_paths(h5_dir, colmap_db)
    lines = []
    n_in = n_h5 = 0
    for (name1, name2), path in results.items():
        d = load_result(path)
        k = len(d["matches"])
        n_in += k
        if h5_dir is not None:
            n_h5 += write_hloc(Path(h5_dir) / "features.h5", Path(h5_dir) / "matches.h5", name1, name2,
                               d["kpts1"], d["kpts2"], d["matches"], d["scores"], image_size1=d["image_size1"],
                               image_size2=d["image_size2"], duplicates=duplicates)
        if colmap_db is not None:
            write_colmap(colmap_db, name1, name2, d["kpts1"], d["kpts2"], d["matches"],
                         image_size1=d["image_size1"], image_size2=d["image_size2"])
    if h5_dir is not None:
        note = "" if n_h5 == n_in else (f" (hloc's matches0 holds one match per image-1 keypoint: the best-scored "
                                        f"one kept, {n_in - n_h5} dropped)")
        lines.append(f"hloc: {len(results)} pairs, {n_h5} of {n_in} matches -> {Path(h5_dir) / 'features.h5'}, "
                     f"{Path(h5_dir) / 'matches.h5'}{note}")
    if colmap_db is not None:
        lines.append(f"COLMAP: {len(results)} pairs, {n_in} matches -> {colmap_db}")
    return lines
