"""The user's cache folder: what each part of it takes, and clearing a part or what is older than an age.

The cache (:func:`ctxmatch_lib._paths.cache_root`: ``$CTXMATCH_CACHE``, else ``$XDG_CACHE_HOME/ctxmatch`` or
``~/.cache/ctxmatch``) is split into parts by folder (:data:`CACHE_PARTS`). ``ctxmatch cache`` prints
:func:`cache_usage`; ``ctxmatch cache clear`` runs :func:`clear_cache`.

Clearing never reaches outside the cache folder: links are never followed (a link inside the cache is removed
as a link, its target untouched), folders on another file system (mount points) are skipped, and a folder
that does not hold the cache's marker (:data:`ctxmatch_lib._paths.CACHE_MARKER`) is refused. It is safe while
another process writes to the cache: every cache file is written under a temporary name and renamed into
place, and temporary files younger than :data:`IN_PROGRESS_GRACE` seconds are kept; a file removed while a
run reads the cache is a miss, recomputed.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

from ._paths import CACHE_MARKER, CACHE_SUBFOLDERS, cache_root, is_marked_cache, mark_cache

__all__ = ["CACHE_PARTS", "IN_PROGRESS_GRACE", "CacheUsage", "ClearResult", "PartUsage", "cache_usage",
           "clear_cache", "parse_age"]

#: The parts of the cache: name -> (folders relative to the cache folder, what they hold). ``other`` is
#: everything in no other part's folder.
CACHE_PARTS: dict[str, tuple[tuple[str, ...], str]] = {
    "datasets": (("datasets", "data"), "the generated embedded dataset, downloads"),
    "features": (("features",), "keypoints and descriptors"),
    "evaluations": (("sweep/results",), "result rows of eval, sweep and the notebooks"),
    "sweeps": (("sweep/candidates", "sweep/overlap", "sweep/filters"),
               "the engine's candidate sets, overlap tables and filter masks"),
    "numba": (("numba",), "compiled kernels"),
    "weights": (("weights",), "what ctxmatch train writes without --output"),
    "other": ((), "training sets, the benchmarks' caches, anything else"),
}

#: Seconds during which a temporary file (a hidden name, or a name with ``.tmp``) counts as being written by
#: a running process: it is kept even by ``clear --all``.
IN_PROGRESS_GRACE = 3600.0

_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}
_AGE = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([smhdw])\s*$")
# Part folders, longest first, so that sweep/results wins over a shorter prefix.
_ROOTS = sorted(((p, name) for name, (paths, _) in CACHE_PARTS.items() for p in paths), key=lambda t: -len(t[0]))
# Folders above part folders (``sweep``): walked for every part, never removed.
_ANCESTORS = {"/".join(p.split("/")[:i]) for p, _ in _ROOTS for i in range(1, p.count("/") + 1)}
# Open folders by descriptor and act relative to it where the platform allows (no link can be swapped in
# between a check and an action); elsewhere by path, after the same checks.
_BY_FD = {os.open, os.stat, os.unlink, os.rmdir} <= os.supports_dir_fd and os.scandir in os.supports_fd


@dataclass(frozen=True)
class PartUsage:
    """Bytes (apparent size) and files of one part of the cache; ``folders`` relative to the cache folder."""

    name: str
    bytes: int
    files: int
    folders: tuple[str, ...]
    description: str


@dataclass(frozen=True)
class CacheUsage:
    """What :func:`cache_usage` found: the cache folder, whether :func:`clear_cache` may delete in it (it holds
    the cache's marker, or nothing but the cache's own sub-folders), and each part."""

    root: Path
    exists: bool
    clearable: bool
    parts: tuple[PartUsage, ...]

    @property
    def bytes(self) -> int:
        return sum(p.bytes for p in self.parts)

    @property
    def files(self) -> int:
        return sum(p.files for p in self.parts)


@dataclass(frozen=True)
class ClearResult:
    """What :func:`clear_cache` removed (or would remove, ``dry_run``) per selected part.

    ``kept_in_progress`` counts temporary files kept because a running process may still be writing them;
    ``skipped`` lists folders left alone because they are on another file system (relative paths).
    """

    root: Path
    dry_run: bool
    older_than: float | None
    removed: tuple[PartUsage, ...]
    kept_in_progress: int
    skipped: tuple[str, ...]

    @property
    def bytes(self) -> int:
        return sum(p.bytes for p in self.removed)

    @property
    def files(self) -> int:
        return sum(p.files for p in self.removed)


def parse_age(age) -> float:
    """An age in seconds from ``"30s"``, ``"30m"``, ``"12h"``, ``"7d"``, ``"2w"``, a number of seconds or a
    ``timedelta``.

    Raises
    ------
    ValueError
        Naming ``older_than`` when the age is not one of these or is negative.

    Examples
    --------
    >>> parse_age("7d"), parse_age("12h"), parse_age("1.5m")
    (604800.0, 43200.0, 90.0)
    """
    if isinstance(age, timedelta):
        seconds = age.total_seconds()
    elif isinstance(age, (int, float)) and not isinstance(age, bool):
        seconds = float(age)
    elif isinstance(age, str) and (m := _AGE.match(age.lower())):
        seconds = float(m.group(1)) * _UNITS[m.group(2)]
    else:
        raise ValueError("older_than must be a number followed by s, m, h, d or w (seconds, minutes, hours, "
                         f"days, weeks), e.g. 7d, 12h, 30m; got {age!r}")
    if not seconds >= 0:
        raise ValueError(f"older_than must not be negative, got {age!r}")
    return seconds


def part_of(rel: str) -> str:
    """The part a path relative to the cache folder belongs to (``"other"`` when in no part's folder)."""
    for root, name in _ROOTS:
        if rel == root or rel.startswith(root + "/"):
            return name
    return "other"


def _in_progress(name: str) -> bool:
    # atomic_path writes ".<name>.<random>.tmp", numba "<name>.tmp.<uuid>", the embedded dataset a hidden
    # temporary folder.
    return name.startswith(".") or ".tmp" in name


class _Walker:
    """One pass over the cache: tally every part, and remove what is selected and old enough."""

    def __init__(self, selected: set[str], cutoff: float | None, dry_run: bool):
        self.selected, self.cutoff, self.dry_run = selected, cutoff, dry_run
        self.grace_cutoff = time.time() - IN_PROGRESS_GRACE
        self.seen = {name: [0, 0] for name in CACHE_PARTS}
        self.removed = {name: [0, 0] for name in CACHE_PARTS}
        self.kept_in_progress = 0
        self.skipped: list[str] = []
        self.dev = None

    def _old_enough(self, mtime: float, in_progress: bool) -> bool:
        limit = self.cutoff
        if in_progress:
            limit = self.grace_cutoff if limit is None else min(limit, self.grace_cutoff)
        return limit is None or mtime < limit

    def _needed(self, rel: str) -> bool:
        return not self.selected or rel in _ANCESTORS or part_of(rel) in self.selected

    def folder(self, handle, rel: str, in_progress: bool) -> bool:
        """Walk one open folder; return whether it is empty afterwards (as if removed, in a dry run)."""
        empty = True
        with os.scandir(handle) as it:
            entries = list(it)
        for entry in entries:
            sub = f"{rel}/{entry.name}" if rel else entry.name
            if not rel and (entry.name == CACHE_MARKER or entry.name.startswith(f".{CACHE_MARKER}.")):
                empty = False
                continue
            try:
                st = entry.stat(follow_symlinks=False)
                is_dir = entry.is_dir(follow_symlinks=False)
            except FileNotFoundError:  # removed meanwhile by another process
                continue
            busy = in_progress or _in_progress(entry.name)
            if is_dir:
                empty &= self._subfolder(handle, entry.name, sub, st, busy)
            else:
                empty &= self._file(handle, entry.name, sub, st, busy)
        return empty

    def _file(self, handle, name: str, rel: str, st: os.stat_result, busy: bool) -> bool:
        part = part_of(rel)
        self.seen[part][0] += st.st_size
        self.seen[part][1] += 1
        if part not in self.selected:
            return False
        if not self._old_enough(st.st_mtime, busy):
            if busy:
                self.kept_in_progress += 1
            return False
        if not self.dry_run:
            try:
                path, dir_fd = _at(name, handle)
                os.unlink(path, dir_fd=dir_fd)  # a link is removed as a link, its target untouched
            except FileNotFoundError:
                return True
            except OSError:
                return False
        self.removed[part][0] += st.st_size
        self.removed[part][1] += 1
        return True

    def _subfolder(self, handle, name: str, rel: str, st: os.stat_result, busy: bool) -> bool:
        if not self._needed(rel):
            return False
        if st.st_dev != self.dev:
            self.skipped.append(rel)
            return False
        try:
            child = _open_folder(name, handle, st)
        except OSError:  # removed or replaced meanwhile: leave it
            return False
        try:
            empty = self.folder(child, rel, busy)
        finally:
            if _BY_FD:
                os.close(child)
        keep = rel in _ANCESTORS or any(rel == root for root, _ in _ROOTS) or part_of(rel) not in self.selected
        if not empty or keep:
            return False
        if not self.dry_run:
            try:
                path, dir_fd = _at(name, handle)
                os.rmdir(path, dir_fd=dir_fd)
            except FileNotFoundError:
                pass
            except OSError:  # a writer has just put a file in it
                return False
        return True


def _at(name: str, handle) -> tuple:
    """``(path, dir_fd)`` arguments of an ``os`` call on ``name`` inside the open folder ``handle``."""
    if _BY_FD:
        return name, handle
    return os.path.join(handle, name), None


def _open_folder(name: str, handle, st: os.stat_result):
    """Open the sub-folder ``name`` of ``handle`` without following a link, and check it is the folder that
    was listed (``st``)."""
    if _BY_FD:
        fd = os.open(name, os.O_RDONLY | os.O_DIRECTORY | getattr(os, "O_NOFOLLOW", 0), dir_fd=handle)
        now = os.fstat(fd)
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            os.close(fd)
            raise OSError(f"{name} changed while the cache was read")
        return fd
    path = os.path.join(handle, name)
    now = os.lstat(path)
    if os.path.islink(path) or (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
        raise OSError(f"{path} changed while the cache was read")
    return path


def _walk(root: Path, selected: set[str], cutoff: float | None, dry_run: bool) -> _Walker:
    walker = _Walker(selected, cutoff, dry_run)
    handle = os.open(root, os.O_RDONLY | os.O_DIRECTORY) if _BY_FD else str(root)
    try:
        walker.dev = (os.fstat(handle) if _BY_FD else os.stat(handle)).st_dev
        walker.folder(handle, "", False)
    finally:
        if _BY_FD:
            os.close(handle)
    return walker


def _parts(tally: dict, names: Iterable[str]) -> tuple[PartUsage, ...]:
    return tuple(PartUsage(n, tally[n][0], tally[n][1], CACHE_PARTS[n][0], CACHE_PARTS[n][1]) for n in names)


def cache_usage(root=None) -> CacheUsage:
    """The size of each part of the cache (:data:`CACHE_PARTS`), reading only: nothing is created or removed.

    Parameters
    ----------
    root : str or Path, optional
        The cache folder; default :func:`ctxmatch_lib._paths.cache_root` (``$CTXMATCH_CACHE``, else the user's
        cache directory).

    Returns
    -------
    CacheUsage
        Per part, the apparent size in bytes and the number of files (links count as files, never
        followed); a missing folder gives zeros with ``exists=False``.

    Examples
    --------
    >>> import tempfile
    >>> usage = cache_usage(Path(tempfile.mkdtemp()) / "none")
    >>> usage.exists, usage.bytes, [p.name for p in usage.parts][:3]
    (False, 0, ['datasets', 'features', 'evaluations'])
    """
    root = Path(root).expanduser() if root is not None else cache_root()
    if not root.is_dir():
        return CacheUsage(root, False, False, _parts({n: (0, 0) for n in CACHE_PARTS}, CACHE_PARTS))
    walker = _walk(root, set(), None, True)
    return CacheUsage(root, True, is_marked_cache(root) or _only_ours(root), _parts(walker.seen, CACHE_PARTS))


def _only_ours(root: Path) -> bool:
    """Whether ``root`` holds nothing but the cache's own sub-folders (:func:`mark_cache` would mark it)."""
    try:
        with os.scandir(root) as it:
            return all(e.name in CACHE_SUBFOLDERS and e.is_dir(follow_symlinks=False) for e in it)
    except OSError:
        return False


def clear_cache(parts, *, older_than=None, dry_run: bool = False, root=None) -> ClearResult:
    """Remove parts of the cache, or only their files older than an age.

    Parameters
    ----------
    parts : iterable of str, or "all"
        Names of :data:`CACHE_PARTS`, or ``"all"`` for every part (the whole cache but its marker).
    older_than : str, float, timedelta or None
        Remove only files last modified longer ago than this (``"7d"``, ``"12h"``, ``"30m"``, seconds; see
        :func:`parse_age`); ``None``: every file of the parts. Folders left empty go too, but the parts' own
        folders stay.
    dry_run : bool
        Count what would be removed, remove nothing.
    root : str or Path, optional
        The cache folder; default :func:`ctxmatch_lib._paths.cache_root`.

    Returns
    -------
    ClearResult
        Bytes and files removed per selected part (would be removed, in a dry run).

    Raises
    ------
    ValueError
        An unknown part or a bad ``older_than`` (named); a cache folder that is not a folder, or that holds
        no marker and is not clearly the cache's (see :func:`ctxmatch_lib._paths.mark_cache`): nothing is
        removed then.

    Examples
    --------
    >>> import tempfile
    >>> root = Path(tempfile.mkdtemp())
    >>> _ = (root / "features").mkdir(), (root / "features" / "f.npz").write_bytes(b"x" * 10)
    >>> result = clear_cache(["features"], root=root)
    >>> result.bytes, result.files, sorted(p.name for p in root.iterdir())
    (10, 1, ['CACHEDIR.TAG', 'features'])
    """
    if isinstance(parts, str):
        parts = list(CACHE_PARTS) if parts == "all" else [parts]
    selected = list(dict.fromkeys(parts))
    unknown = [p for p in selected if p not in CACHE_PARTS]
    if unknown or not selected:
        raise ValueError(f"parts must name parts of the cache ({', '.join(CACHE_PARTS)}) or be 'all', "
                         f"got {', '.join(map(repr, unknown)) or 'none'}")
    age = None if older_than is None else parse_age(older_than)
    cutoff = None if age is None else time.time() - age
    root = Path(root).expanduser() if root is not None else cache_root()
    if not os.path.lexists(root):
        return ClearResult(root, dry_run, age, _parts({n: (0, 0) for n in CACHE_PARTS}, selected), 0, ())
    if not root.is_dir():
        raise ValueError(f"the cache folder {root} is not a folder")
    if not mark_cache(root):
        raise ValueError(_refusal(root))
    walker = _walk(root, set(selected), cutoff, dry_run)
    return ClearResult(root, dry_run, age, _parts(walker.removed, selected), walker.kept_in_progress,
                       tuple(walker.skipped))


def _refusal(root: Path) -> str:
    try:
        foreign = sorted(e.name for e in os.scandir(root) if e.name != CACHE_MARKER)[:3]
    except OSError:
        foreign = []
    listed = f" (it holds {', '.join(map(repr, foreign))}, ...)" if foreign else ""
    return (f"{root} is not a ctxmatch cache folder: it holds no {CACHE_MARKER} written by ctxmatch and more "
            f"than the cache's own sub-folders{listed}; nothing was removed. Check CTXMATCH_CACHE; if this "
            "folder is the cache, delete it by hand (the cache recreates it, marked, on its next use)")
