"""Where ctxmatch keeps its caches and where it looks for real data."""

from __future__ import annotations

import functools
import json
import os
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["CACHE_MARKER", "CACHE_SUBFOLDERS", "atomic_path", "build_info", "cache_dir", "cache_root",
           "check_writable", "data_root", "is_marked_cache", "mark_cache", "repo_root", "write_parquet_atomic"]

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
    """The cache folder: ``$CTXMATCH_CACHE`` if set, else the user's cache directory,
    ``$XDG_CACHE_HOME/ctxmatch`` (``~/.cache/ctxmatch`` when ``XDG_CACHE_HOME`` is unset).

    Never the checkout unless ``CTXMATCH_CACHE`` says so. ``sub`` names a sub-folder (created on demand):
    ``features`` (extracted keypoints and descriptors), ``sweep`` (the evaluation cache of ``ctxmatch
    eval``, ``ctxmatch sweep`` and the report notebooks: result parts and intermediates), ``weights`` (what
    ``ctxmatch train`` writes without ``--output``). The folder gets the cache's marker (:func:`mark_cache`)
    when it is created, or when it holds nothing but the cache's own sub-folders.
    """
    base = cache_root()
    base.mkdir(parents=True, exist_ok=True)
    if str(base) not in _CHECKED:
        mark_cache(base)
        _CHECKED.add(str(base))
    path = base / sub if sub else base
    path.mkdir(parents=True, exist_ok=True)
    return path


def is_marked_cache(folder) -> bool:
    """Whether ``folder`` holds the marker of a ctxmatch cache (:data:`CACHE_MARKER`, a regular file, not a
    link, that ctxmatch wrote)."""
    marker = Path(folder) / CACHE_MARKER
    try:
        if not marker.is_file() or marker.is_symlink():
            return False
        head = marker.read_text(encoding="utf-8", errors="replace")[:1000]
    except OSError:
        return False
    return head.startswith(_CACHEDIR_SIGNATURE) and "ctxmatch" in head


def mark_cache(folder) -> bool:
    """Write the cache's marker into ``folder`` when the folder is clearly the cache's; return whether it is
    marked.

    A folder is the cache's when it is empty (the cache has just created it) or holds nothing but the
    sub-folders the package creates there (:data:`CACHE_SUBFOLDERS`, real folders, not links): a cache made
    before the marker existed. A folder holding anything else is left unmarked, and ``ctxmatch cache clear``
    refuses to delete in it.
    """
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
    """The real-data root from ``$CTXMATCH_DATA`` (its README describes the layout), or ``None``.

    With ``required=True`` a missing root raises ``FileNotFoundError`` explaining how to set it.
    """
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
    """Check, before any work and without creating anything, that ``path`` can be written.

    A file (``folder=False``) must not be a folder, and either be a writable file or be creatable: its
    nearest existing ancestor must be a writable folder (not a file). A folder (``folder=True``) must be a
    writable folder or be creatable the same way. Commands call this on every output path first, so a bad
    path fails at once instead of after the computation.

    Parameters
    ----------
    path : str or Path
        The output path.
    name : str
        The argument or flag it came from (``"--out"``, ``"database_path"``): every message starts with it.
    folder : bool
        Whether ``path`` is an output folder rather than a file.

    Returns
    -------
    Path
        ``path`` with ``~`` expanded.

    Raises
    ------
    ValueError
        Naming ``name`` and the reason: a folder where a file is wanted (or the reverse), a file in the way of
        a folder to create, or no write permission.

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

    Readers never see a half-written file, and an interrupted write leaves nothing behind. The temporary
    name is hidden and ends in ``.tmp``, so globs for the real suffix never pick it up; writers that infer
    the format from the suffix must be told it. The file gets the mode a plain ``open(path, "w")`` would
    give (``0o666`` less the umask), not the ``0o600`` of a temporary file.
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
    """Write ``df`` to ``path`` (Parquet) atomically; ``metadata`` (dataset, feature preset, blob setup, ...)
    goes, as JSON, under the ``ctxmatch`` key of the schema metadata, and :func:`build_info` (version, git
    commit, date) under ``ctxmatch_provenance``."""
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
