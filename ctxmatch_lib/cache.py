"""The user's cache folder (:func:`cache_root`), atomic writes (:func:`atomic_path`), the real-data root
(:func:`data_root`), output-path checks (:func:`check_writable`) and the parts of the cache
(:data:`CACHE_PARTS`) that ``ctxmatch cache`` shows (:func:`cache_usage`) and clears (:func:`clear_cache`):
never outside the marked cache folder, and safe while another process writes (see docs/setup.md).
"""

from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import tempfile
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path

__all__ = ["CACHE_MARKER", "CACHE_SUBFOLDERS", "atomic_path", "build_info", "cache_dir", "cache_root",
           "check_writable", "data_root", "is_marked_cache", "mark_cache", "repo_root", "write_parquet_atomic",
           "CACHE_PARTS", "IN_PROGRESS_GRACE", "CacheUsage", "ClearResult", "PartUsage", "cache_usage",
           "clear_cache", "parse_age"]

#: The file that marks a folder as ctxmatch's cache, written when the cache creates its folder; in the Cache
#: Directory Tagging format (https://bford.info/cachedir/), so backup tools skip the folder too.
CACHE_MARKER = "CACHEDIR.TAG"
_CACHEDIR_SIGNATURE = "Signature: 8a477f597d28d172789f06886806bc55"
_MARKER_TEXT = (f"{_CACHEDIR_SIGNATURE}\n# This file is a cache directory tag created by ctxmatch.\n"
                "# Everything in this folder can be recomputed; `ctxmatch cache` shows and clears it.\n")

#: The sub-folders the package creates in its cache (the library, the command line and the benchmarks).
CACHE_SUBFOLDERS = ("ablation", "data", "datasets", "features", "learned-eval", "learned-sets", "numba", "sweep",
                    "weights")

# Folders already marked or found foreign in this process: cache_dir checks each once.
_CHECKED: set[str] = set()


def repo_root() -> Path | None:
    """The checkout this package runs from (editable install), or ``None`` for a plain install."""
    root = Path(__file__).resolve().parents[1]
    return root if (root / "pyproject.toml").exists() else None


def cache_root() -> Path:
    """Where the cache folder is, without creating it: ``$CTXMATCH_CACHE`` if set, else
    ``$XDG_CACHE_HOME/ctxmatch`` (``~/.cache/ctxmatch`` when ``XDG_CACHE_HOME`` is unset)."""
    env = os.environ.get("CTXMATCH_CACHE")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    # The XDG spec: a relative XDG_CACHE_HOME is invalid and ignored.
    root = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return root / "ctxmatch"


def cache_dir(sub: str | None = None) -> Path:
    """The cache folder, created and marked, or its sub-folder ``sub`` (created on demand)."""
    base = cache_root()
    base.mkdir(parents=True, exist_ok=True)
    if str(base) not in _CHECKED:
        mark_cache(base)
        _CHECKED.add(str(base))
    path = base / sub if sub else base
    path.mkdir(parents=True, exist_ok=True)
    return path


def is_marked_cache(folder) -> bool:
    """Whether ``folder`` holds ctxmatch's :data:`CACHE_MARKER` (a regular file, not a link)."""
    marker = Path(folder) / CACHE_MARKER
    try:
        if not marker.is_file() or marker.is_symlink():
            return False
        head = marker.read_text(encoding="utf-8", errors="replace")[:1000]
    except OSError:
        return False
    return head.startswith(_CACHEDIR_SIGNATURE) and "ctxmatch" in head


def mark_cache(folder) -> bool:
    """Mark ``folder`` when it is empty or holds only :data:`CACHE_SUBFOLDERS`; return whether it is marked."""
    folder = Path(folder)
    if is_marked_cache(folder):
        return True
    try:
        with os.scandir(folder) as it:
            # A concurrent process may be writing the marker (atomic_path's hidden temporary file).
            ours = all((e.name in CACHE_SUBFOLDERS and e.is_dir(follow_symlinks=False))
                       or (e.name.startswith(f".{CACHE_MARKER}.") and e.name.endswith(".tmp")) for e in it)
    except OSError:
        return False
    if not ours:
        return False
    try:
        with atomic_path(folder / CACHE_MARKER) as tmp:
            tmp.write_text(_MARKER_TEXT, encoding="utf-8")
    except OSError:  # a read-only cache still serves what it holds
        return False
    return True


def data_root(required: bool = False) -> Path | None:
    """The real-data root from ``$CTXMATCH_DATA`` (its README describes the layout), or ``None``; with
    ``required=True`` a missing root raises ``FileNotFoundError`` explaining how to set it."""
    env = os.environ.get("CTXMATCH_DATA")
    if env and Path(env).is_dir():
        return Path(env)
    if required:
        raise FileNotFoundError(
            "real data not found: set CTXMATCH_DATA to the folder holding planar/ and nonplanar/ "
            f"(currently {env!r})"
        )
    return None


def check_writable(path, name: str, *, folder: bool = False) -> Path:
    """``path`` with ``~`` expanded, checked without creating anything to be writable or creatable.

    Parameters
    ----------
    path : str or Path
    name : str
        The argument or flag it came from (``"--out"``); every ``ValueError`` message starts with it.
    folder : bool
        Whether ``path`` is an output folder rather than a file.

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> (d / "file").write_text("")
    0
    >>> check_writable(d / "out" / "x.npz", "--out") == d / "out" / "x.npz"
    True
    >>> check_writable(d / "file" / "x.npz", "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: --out: cannot create .../file/x.npz: .../file is a file, not a folder
    """
    kind = "folder" if folder else "file"
    if str(path) == "":  # before Path(), which reads "" as "."
        raise ValueError(f"{name}: the output {kind} name is empty")
    path = Path(path).expanduser()
    if os.path.lexists(path):
        if folder and not path.is_dir():
            raise ValueError(f"{name}: {path} exists and is not a folder")
        if not folder and path.is_dir():
            raise ValueError(f"{name}: {path} is a folder, not a file")
        if not os.access(path, os.W_OK | (os.X_OK if folder else 0)):
            raise ValueError(f"{name}: {path} is not writable")
        if not folder and not os.access(path.parent, os.W_OK | os.X_OK):
            # Files are written beside their target and renamed into place (atomic_path).
            raise ValueError(f"{name}: cannot write {path}: its folder {path.parent} is not writable")
        return path
    ancestor = path.parent
    while not os.path.lexists(ancestor) and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{name}: cannot create {path}: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(f"{name}: cannot create {path}: {ancestor} is not writable")
    return path


def _umask() -> int:
    """The process umask (read without changing it where /proc allows, else set and restored at once)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` in one ``os.replace``.

    The name is hidden and ends in ``.tmp`` (writers that infer the format from the suffix must be told it);
    the file gets ``open(path, "w")``'s mode, not ``0o600``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_parquet_atomic(df, path, metadata: dict | None = None) -> Path:
    """Write ``df`` to ``path`` (Parquet) atomically, ``metadata`` and :func:`build_info` as JSON in the schema
    metadata (keys ``ctxmatch``, ``ctxmatch_provenance``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(df, preserve_index=False)
    meta = dict(table.schema.metadata or {})
    meta[b"ctxmatch_provenance"] = json.dumps(build_info(), sort_keys=True).encode()
    if metadata is not None:
        meta[b"ctxmatch"] = json.dumps(metadata, sort_keys=True, default=str).encode()
    table = table.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return Path(path)


@functools.lru_cache(maxsize=1)
def _git_commit() -> str:
    """Commit of the checkout (``-dirty`` when tracked files outside ``figures/`` differ from it), else ``""``."""
    root = repo_root()
    if root is None or not (root / ".git").exists():
        return ""
    try:
        run = functools.partial(subprocess.run, cwd=root, capture_output=True, text=True, timeout=10)
        head = run(["git", "rev-parse", "--short=12", "HEAD"]).stdout.strip()
        dirty = run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)figures"]).stdout
    except (OSError, subprocess.SubprocessError):
        return ""
    return f"{head}-dirty" if head and dirty.strip() else head


def build_info() -> dict:
    """Provenance of anything ctxmatch writes: ``version`` (of ``ctxmatch_lib``), ``git_commit`` (of the
    checkout, ``""`` for a plain install) and ``date`` (UTC, ISO 8601, to the second)."""
    from datetime import datetime, timezone

    from . import __version__

    return {"version": __version__, "git_commit": _git_commit(),
            "date": datetime.now(timezone.utc).replace(microsecond=0).isoformat()}


# ----------------------------------------------------------------------------- usage and clearing

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
    """What :func:`cache_usage` found; ``clearable``: whether :func:`clear_cache` may delete in ``root``."""

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
    """What :func:`clear_cache` removed (or would), per part; ``skipped``: folders on another file system."""

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
    """An age in seconds from ``"30s"``, ``"30m"``, ``"12h"``, ``"7d"``, ``"2w"``, seconds or a ``timedelta``.

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
    """Open the sub-folder ``name`` without following a link; check it is the one listed (``st``)."""
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
    """Apparent bytes and files of each part of the cache (:data:`CACHE_PARTS`) under ``root`` (default
    :func:`cache_root`), read only; links count as files, never followed.

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
    """Remove parts of the cache, or their files older than an age; ``ValueError``, removing nothing, for a
    folder that is not clearly the cache's (:func:`mark_cache`).

    Parameters
    ----------
    parts : iterable of str, or "all"
        Names of :data:`CACHE_PARTS`.
    older_than : str, float, timedelta or None
        Remove only files not modified for that long (:func:`parse_age`); empty folders go too.
    dry_run : bool
        Count what would be removed, remove nothing.
    root : str or Path, optional
        Default :func:`cache_root`.

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
