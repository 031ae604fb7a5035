"""Download the public real datasets into the data-root layout (:func:`download_dataset`,
``ctxmatch data download``): archives (:class:`Source`) and the Strecha files (:class:`FileSet`) are checked
against pinned SHA-256 hashes and unpacked path-traversal safe, atomically. An unpinned archive needs
``sha256=`` or ``allow_unpinned=True`` (its hash is then reported).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlparse
from urllib.request import url2pathname


__all__ = ["Source", "FileSet", "SOURCES", "DOWNLOAD_GROUPS", "STRECHA_BASE_URL", "download_dataset",
           "download_names"]


@dataclass(frozen=True)
class Source:
    """One archive: where to get it, its SHA-256 (``None``: not pinned) and where it unpacks to."""

    url: str
    sha256: str | None
    dest: str  # relative to the data root
    strip_single_top: bool = True  # an archive whose entries share one top folder is unpacked without it


@dataclass(frozen=True)
class FileSet:
    """Plain files under one base URL: ``files`` is ``((relative path, sha256), ...)``, written under ``dest``."""

    base_url: str
    files: tuple[tuple[str, str], ...]
    dest: str  # relative to the data root


#: The Strecha scenes' pinned source: repository, commit, folder; their file list (SHA-256, size, path) is
#: ``data/strecha_files.txt``, hashed from the repository's blobs at that commit.
STRECHA_REPOSITORY = "openMVG/SfM_quality_evaluation"
STRECHA_COMMIT = "348a981ef51112e9848acfb20004f4ed6fbc6ce3"
STRECHA_PREFIX = "Benchmarking_Camera_Calibration_2008"
STRECHA_FILES = "\n".join(line for line in (Path(__file__).with_name("data") / "strecha_files.txt").read_text().splitlines()
                          if line and not line.startswith("#"))
#: Raw files of openMVG/SfM_quality_evaluation at the pinned commit; a mirror replaces it (``url=``).
STRECHA_BASE_URL = (f"https://raw.githubusercontent.com/{STRECHA_REPOSITORY}/{STRECHA_COMMIT}/{STRECHA_PREFIX}")


def _strecha_sets() -> dict[str, FileSet]:
    by_scene: dict[str, list[tuple[str, str]]] = {}
    for line in STRECHA_FILES.splitlines():
        digest, _size, path = line.split()
        scene, rel = path.split("/", 1)
        by_scene.setdefault(scene, []).append((rel, digest))
    return {f"strecha-{scene}": FileSet(f"{STRECHA_BASE_URL}/{scene}", tuple(files), f"calibrated/strecha/{scene}")
            for scene, files in by_scene.items()}


_STRECHA = _strecha_sets()

_OXFORD = "https://www.robots.ox.ac.uk/~vgg/research/affine/det_eval_files/{}.tar.gz"
_OXFORD_SHA256 = {
    # Published SHA-256 of the Oxford archives (two independent public benchmark scripts agree on graf).
    "graf": "999871b945ee968a00a0d5f9af957d1382fb9dae1511cdee9553366817b53b5b",
    "boat": "6e5721f37fbf9c3e974fd05935a42c1670f3e71aa3e5b218807ea046a068c603",
}

_OXFORD_SEQUENCES = ("graf", "boat", "bark", "bikes", "leuven", "trees", "ubc", "wall")

SOURCES: dict[str, tuple[Source, ...] | FileSet] = {
    "hpatches": (
        Source("http://icvl.ee.ic.ac.uk/vbalnt/hpatches/hpatches-sequences-release.tar.gz", None,
               "planar/hpatches"),
    ),
    **{
        f"oxford-{seq}": (Source(_OXFORD.format(seq), _OXFORD_SHA256.get(seq), f"planar/oxford/{seq}"),)
        for seq in _OXFORD_SEQUENCES
    },
    "homogr": (
        Source("http://cmp.felk.cvut.cz/data/geometry2view/Lebeda-2012-homogr.tar.gz", None, "planar/homogr"),
    ),
    "kusvod2": (
        Source("http://cmp.felk.cvut.cz/data/geometry2view/Lebeda-2012-kusvod2.tar.gz", None,
               "nonplanar/kusvod2"),
    ),
    **_STRECHA,
}
_OXFORD_ALL = tuple(f"oxford-{seq}" for seq in _OXFORD_SEQUENCES)
_STRECHA_ALL = tuple(_STRECHA)
DOWNLOAD_GROUPS = {"oxford": _OXFORD_ALL, "planar": ("hpatches", *_OXFORD_ALL, "homogr"),
                   "nonplanar": ("kusvod2",), "strecha": _STRECHA_ALL, "calibrated": _STRECHA_ALL,
                   "all": ("hpatches", *_OXFORD_ALL, "homogr", "kusvod2", *_STRECHA_ALL)}


def download_names() -> list[str]:
    """Names accepted by :func:`download_dataset`."""
    return [*SOURCES, *DOWNLOAD_GROUPS]


def _file_downloader(url: str, output_file, pooch_obj=None, check_only: bool = False):
    """pooch downloader for ``file://`` URLs (pooch itself only speaks http(s), ftp, sftp and doi)."""
    src = Path(url2pathname(unquote(urlparse(url).path)))
    if check_only:
        return src.is_file()
    if not src.is_file():
        raise FileNotFoundError(f"archive not found: {src} (from {url})")
    if hasattr(output_file, "write"):
        with open(src, "rb") as f:
            shutil.copyfileobj(f, output_file)
    else:
        shutil.copyfile(src, output_file)
    return None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _safe_extract(archive: Path, out: Path) -> None:
    out = out.resolve()

    def check(name: str):
        target = (out / name).resolve()
        if target != out and out not in target.parents:
            raise ValueError(f"archive {archive} has an entry outside the target folder: {name!r}")

    if zipfile.is_zipfile(archive):
        with zipfile.ZipFile(archive) as z:
            for name in z.namelist():
                check(name)
            z.extractall(out)
        return
    try:
        tar = tarfile.open(archive)
    except tarfile.TarError as exc:
        raise ValueError(f"{archive} is neither a tar nor a zip archive: {exc}") from None
    with tar:
        members = []
        for m in tar.getmembers():
            check(m.name)
            if m.issym() or m.islnk() or m.isdev():
                continue  # datasets are plain files; links and devices are never needed
            members.append(m)
        tar.extractall(out, members=members)


def _strip_top(folder: Path) -> Path:
    entries = [p for p in folder.iterdir() if not p.name.startswith(".") and p.name != "__MACOSX"]
    if len(entries) == 1 and entries[0].is_dir():
        return entries[0]
    return folder


def _data_root(root) -> Path:
    if root is None:
        from ..cache import cache_dir, data_root

        root = data_root() or cache_dir("data")
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    return root


def _download_files(name: str, fs: FileSet, root: Path, *, force: bool, progress: bool, log) -> Path:
    """Fetch every file of ``fs`` (each checked against its SHA-256) into ``root / fs.dest``, atomically."""
    import pooch

    dest = root / fs.dest
    if dest.is_dir() and any(dest.iterdir()) and not force:
        log(f"{name}: {dest} already present (use --force to replace)")
        return dest
    downloader = _file_downloader if fs.base_url.startswith("file:") else None
    log(f"{name}: fetching {len(fs.files)} files from {fs.base_url}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        for rel, digest in fs.files:
            target = (tmp / rel).resolve()
            if tmp.resolve() not in target.parents:
                raise ValueError(f"{name}: file {rel!r} lies outside the dataset folder")
            try:
                pooch.retrieve(f"{fs.base_url}/{rel}", known_hash=f"sha256:{digest}", fname=target.name,
                               path=target.parent, downloader=downloader, progressbar=progress)
            except ValueError as exc:  # pooch's hash mismatch: name the file
                raise ValueError(f"{name}: {rel}: {exc}") from None
        if dest.exists():
            shutil.rmtree(dest)
        os.replace(tmp, dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    log(f"{name}: written into {dest}")
    return dest


def download_dataset(name: str, *, root=None, url: str | None = None, sha256: str | None = None,
                     allow_unpinned: bool = False, force: bool = False, progress: bool = False,
                     log=print) -> list[Path]:
    """Download and unpack a public dataset under the data root.

    Parameters
    ----------
    name : str
        One of :func:`download_names`.
    root : str or Path, optional
        Default ``$CTXMATCH_DATA`` when set, else ``cache_dir("data")``.
    url, sha256 : str, optional
        A single archive's URL (``http(s)``, ``ftp``, ``file``) and hash; for Strecha, ``url`` is a mirror of
        ``Benchmarking_Camera_Calibration_2008`` and the pinned per-file hashes apply.
    allow_unpinned : bool
        Accept an archive with no pinned hash.
    force : bool
        Replace an existing dataset folder.
    progress : bool
    log : callable
        Receives one line per step.

    Returns
    -------
    list of Path
        The dataset folders written or already present.
    """
    import pooch

    if name in DOWNLOAD_GROUPS:
        members = DOWNLOAD_GROUPS[name]
        file_sets = all(isinstance(SOURCES[sub], FileSet) for sub in members)
        if sha256 or (url and not file_sets):
            raise ValueError(f"url and sha256 apply to a single dataset, not to the group {name!r}")
        return [p for sub in members
                for p in download_dataset(sub, root=root, allow_unpinned=allow_unpinned, force=force,
                                          progress=progress, log=log,
                                          url=url and f"{url.rstrip('/')}/{Path(SOURCES[sub].dest).name}")]
    if name not in SOURCES:
        raise ValueError(f"name must be one of {download_names()}, got {name!r}")
    sources = SOURCES[name]
    if isinstance(sources, FileSet):
        if sha256:
            raise ValueError(f"{name!r} is checked file by file against pinned hashes; sha256 does not apply")
        fs = FileSet(url.rstrip("/"), sources.files, sources.dest) if url else sources
        return [_download_files(name, fs, _data_root(root), force=force, progress=progress, log=log)]
    if url or sha256:
        if len(sources) != 1:
            raise ValueError(f"{name!r} has {len(sources)} archives; url/sha256 overrides need a single one")
        sources = (Source(url or sources[0].url, sha256 or None, sources[0].dest, sources[0].strip_single_top),)
    if sha256 is not None and (len(sha256) != 64 or any(c not in "0123456789abcdefABCDEF" for c in sha256)):
        raise ValueError(f"sha256 must be 64 hexadecimal digits, got {sha256!r}")
    root = _data_root(root)
    archives = root / ".downloads"
    written = []
    for src in sources:
        dest = root / src.dest
        if dest.is_dir() and any(dest.iterdir()) and not force:
            log(f"{name}: {dest} already present (use --force to replace)")
            written.append(dest)
            continue
        if src.sha256 is None and not allow_unpinned:
            raise ValueError(
                f"{name}: no pinned SHA-256 for {src.url}; pass sha256= (--sha256) or allow_unpinned=True "
                "(--allow-unpinned) to accept it and print its hash"
            )
        fname = Path(urlparse(src.url).path).name or f"{name}.archive"
        downloader = _file_downloader if src.url.startswith("file:") else None
        log(f"{name}: fetching {src.url}")
        path = Path(pooch.retrieve(
            src.url, known_hash=f"sha256:{src.sha256.lower()}" if src.sha256 else None, fname=fname,
            path=archives, downloader=downloader, progressbar=progress,
        ))
        digest = _sha256(path)
        if src.sha256 is None:
            log(f"{name}: UNPINNED archive {fname} has sha256 {digest}")
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
        try:
            _safe_extract(path, tmp)
            top = _strip_top(tmp) if src.strip_single_top else tmp
            if dest.exists():
                shutil.rmtree(dest)
            os.replace(top, dest)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
        log(f"{name}: unpacked into {dest}")
        written.append(dest)
    return written
