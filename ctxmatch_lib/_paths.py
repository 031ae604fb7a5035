"""Where ctxmatch keeps its caches and where it looks for real data."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir", "data_root", "repo_root"]


def repo_root() -> Path | None:
    """The checkout this package runs from (editable install), or ``None`` for a plain install."""
    root = Path(__file__).resolve().parents[1]
    return root if (root / "pyproject.toml").exists() else None


def cache_dir(sub: str | None = None) -> Path:
    """The cache folder: ``$CTXMATCH_CACHE``, else ``data/cache`` of the checkout, else ``~/.cache/ctxmatch``.

    ``sub`` names a sub-folder (created on demand).
    """
    env = os.environ.get("CTXMATCH_CACHE")
    if env:
        base = Path(env)
    elif repo_root() is not None:
        base = repo_root() / "data" / "cache"
    else:
        base = Path.home() / ".cache" / "ctxmatch"
    path = base / sub if sub else base
    path.mkdir(parents=True, exist_ok=True)
    return path


def data_root(required: bool = False) -> Path | None:
    """The real-data root from ``$CTXMATCH_DATA`` (see ``../shared/data/README.md``), or ``None``.

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
