"""Optional dependencies: import one, or say which extra of ``pyproject.toml`` installs it."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["install_hint", "require"]


def install_hint(module: str, extra: str, purpose: str) -> str:
    """The message of a missing optional dependency: what needs it and the ``pip`` command that installs it.

    Parameters
    ----------
    module : str
        The module to import; its top-level package is the one named.
    extra : str
        The extra of ``[project.optional-dependencies]`` that installs it.
    purpose : str
        What needs it, as the subject of the sentence.

    Examples
    --------
    >>> install_hint("h5py", "export", "the hloc export")
    "the hloc export needs h5py: pip install 'ctxmatch[export]'"
    """
    return f"{purpose} needs {module.split('.')[0]}: pip install 'ctxmatch[{extra}]'"


def require(module: str, extra: str, purpose: str, *, alternative: str | None = None) -> ModuleType:
    """Import and return ``module``; if it cannot be imported, raise an ``ImportError`` naming the extra.

    Parameters
    ----------
    module, extra, purpose : str
        As in :func:`install_hint`; ``module`` may be a submodule (``"kornia.feature"``).
    alternative : str, optional
        Another way to the same end, appended to the message (``"...; or <alternative>"``).

    Returns
    -------
    module
        The imported module.

    Raises
    ------
    ImportError
        The :func:`install_hint` message and the import's own error, chained from that error.

    Examples
    --------
    >>> require("json", "none", "the example").__name__
    'json'
    >>> require("no_such_module", "export", "the example")
    Traceback (most recent call last):
    ...
    ImportError: the example needs no_such_module: pip install 'ctxmatch[export]' (No module named 'no_such_module')
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        message = install_hint(module, extra, purpose) + (f"; or {alternative}" if alternative else "")
        raise ImportError(f"{message} ({exc})", name=module.split(".")[0]) from exc
