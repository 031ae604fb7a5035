"""Spatial match filters behind one registry.

Every filter has the same signature::

    FILTERS[name](kpts1, kpts2, matches, scores, *, image_size1, image_size2,
                  shapes1=None, shapes2=None, **params) -> keep  # (K,) bool

``kpts*`` are ``(N, 2)`` (x, y) pixels, origin at the centre of the top-left pixel; ``matches`` ``(K, 2)``
indices (many-to-many allowed); ``scores`` ``(K,)``, lower is better; ``matches[keep]`` are kept. NNR
thresholds (``th``, ``glpm``, ``adalam``) are read on the scores' scale (:func:`nnr_scores`). Filters are
imported on first use. A filter from outside the library enters by :func:`register_filter`, by its import
path (``FILTERS["mypkg.mymodule:myfilter"]``, :func:`load_filter`) or through the ``ctxmatch.filters``
entry-point group of an installed package. Guides: ``docs/filters.md``, ``docs/own-filter.md``.

Every spatial filter drops the one outlier of a translated grid and keeps the rest (MOP+MiHo excepted: on a
noise-free translation no inlier pair votes for its pre-rotation, as in the authors' code):

>>> import numpy as np
>>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
>>> y = g + (7.0, -3.0)
>>> y[0] = (300.0, 200.0)  # one outlier
>>> m, shapes = np.c_[np.arange(64), np.arange(64)], np.tile(3.0 * np.eye(2), (64, 1, 1))  # scale 3, upright
>>> def kept(name):
...     keep = FILTERS[name](g, y, m, image_size1=(400, 300), image_size2=(400, 300), shapes1=shapes, shapes2=shapes)
...     return bool(keep[0]), int(keep[1:].sum())
>>> names = ("lpm", "glpm", "vfc", "llt", "adalam", "rfm_scan", "pgm", "scv", "bm", "pfm", "lmr", "mop")
>>> [name for name in names if kept(name) != (False, 63)]
[]
"""

from __future__ import annotations

import functools
import importlib
import inspect
import os
import sys
from collections.abc import Callable, Iterator, Mapping
from importlib.metadata import entry_points

from .._numerics.scores import nnr_scores

__all__ = ["FILTERS", "register_filter", "load_filter", "nnr_scores", "ENTRY_POINT_GROUP", "NOT_IN_ALL"]

#: The entry-point group through which an installed package registers filters (``name = "module:function"``).
ENTRY_POINT_GROUP = "ctxmatch.filters"

# name -> "module:function[:stages]"; ``dtm1`` (DTM1) and ``dtm2`` (DTM1 + DTM2, as ``dtm``) as in Tables 1-3.
_BUILTIN: dict[str, str] = {
    "dtm": "ctxmatch_lib.dtm:dtm_filter",
    "dtm1": "ctxmatch_lib.dtm:dtm_filter:1",
    "dtm2": "ctxmatch_lib.dtm:dtm_filter:2",
    "th": "ctxmatch_lib.filters.th:th_filter",
    "gms": "ctxmatch_lib.filters.gms:gms_filter",
    "lpm": "ctxmatch_lib.filters.lpm:lpm_filter",
    "glpm": "ctxmatch_lib.filters.lpm:glpm_filter",
    "vfc": "ctxmatch_lib.filters.vfc:vfc_filter",
    "llt": "ctxmatch_lib.filters.llt:llt_filter",
    "adalam": "ctxmatch_lib.filters.adalam:adalam_filter",
    "rfm_scan": "ctxmatch_lib.filters.rfm_scan:rfm_scan_filter",
    "pgm": "ctxmatch_lib.filters.pgm:pgm_filter",
    "scv": "ctxmatch_lib.filters.scv:scv_filter",
    "bm": "ctxmatch_lib.filters.bm:bm_filter",
    "pfm": "ctxmatch_lib.filters.pfm:pfm_filter",
    "lmr": "ctxmatch_lib.filters.lmr:lmr_filter",
    # The paper author's successor (arXiv 2411.09484, fb82/MiHo): not in the paper's benchmark.
    "mop": "ctxmatch_lib.filters.mop:mop_filter",
    "mop_miho": "ctxmatch_lib.filters.mop:mop_miho_filter",
    # Learned filters (numpy inference; default weights trained here, not the authors'; torch only to train).
    "oanet": "ctxmatch_lib.filters.learned.filters:oanet_filter",
    "acne": "ctxmatch_lib.filters.learned.filters:acne_filter",
}


#: Registered filters that ``"all"`` leaves out (named, they run like any other): MOP and MOP+MiHo, not in the
#: paper's benchmark, take seconds a pair, so the benchmark runs them where it names them.
NOT_IN_ALL = frozenset({"mop", "mop_miho"})


class _Registry(Mapping):
    """Read-only mapping name -> filter function that imports built-in filters on first access. Import paths
    resolve too (:func:`load_filter`) but are not listed: ``"all"`` means the registered filters."""

    def __init__(self) -> None:
        self._loaded: dict[str, Callable] = {}
        self._by_path: dict[str, Callable] = {}

    def __getitem__(self, name: str) -> Callable:
        if name in self._loaded:
            return self._loaded[name]
        if name in self._by_path:
            return self._by_path[name]
        if name in _BUILTIN:
            module, func, *stages = _BUILTIN[name].split(":")
            f = getattr(importlib.import_module(module), func)
            self._loaded[name] = functools.partial(f, stages=int(stages[0])) if stages else f
        elif name in _entry_points():
            self._loaded[name] = load_filter(_entry_points()[name], name=name)
        elif ":" in name:
            self._by_path[name] = load_filter(name)
            return self._by_path[name]
        else:
            raise KeyError(f"unknown filter {name!r}; known filters: {', '.join(self)} (or 'module:function')")
        return self._loaded[name]

    def __contains__(self, name) -> bool:
        try:
            self[name]
        except (KeyError, ValueError):
            return False
        return True

    def __iter__(self) -> Iterator[str]:
        yield from _BUILTIN
        yield from (k for k in _entry_points() if k not in _BUILTIN)
        yield from (k for k in self._loaded if k not in _BUILTIN and k not in _entry_points())

    def __len__(self) -> int:
        return sum(1 for _ in self)


FILTERS = _Registry()


def register_filter(name: str, func: Callable | None = None):
    """Register ``func`` under ``name`` (usable as a decorator: ``@register_filter("mine")``).

    Parameters
    ----------
    name : str
        The registry key (``FILTERS[name]``, ``--filters name``).
    func : callable, optional
        A filter with the common signature (module docstring); omitted, a decorator is returned.
    """

    def _add(f: Callable) -> Callable:
        FILTERS._loaded[name] = f
        return f

    return _add if func is None else _add(func)


_SIGNATURE = "(kpts1, kpts2, matches, scores, *, image_size1, image_size2, shapes1=None, shapes2=None, **params)"


@functools.cache
def _entry_points() -> dict[str, str]:
    """name -> ``"module:function"`` of the filters that installed packages register (:data:`ENTRY_POINT_GROUP`)."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def load_filter(path: str, *, name: str | None = None) -> Callable:
    """The filter function at the import path ``"package.module:function"``, checked against the common
    signature (module docstring). A module that is not importable otherwise is looked for in the current
    folder, as a script's own module would be.

    Parameters
    ----------
    path : str
        ``module:attribute``, the attribute possibly dotted (``module:Class.method``).
    name : str, optional
        The registry name the errors give (default: ``path``).

    Raises
    ------
    ValueError
        Naming the path, when the module does not import, the attribute is missing or not callable, or the
        function cannot take a filter's arguments.

    Examples
    --------
    >>> load_filter("ctxmatch_lib.filters.th:th_filter").__name__
    'th_filter'
    """
    label = f"filter {name or path!r}" + (f" ({path})" if name and name != path else "")
    module_name, sep, attr = path.partition(":")
    if not (sep and module_name and attr):
        raise ValueError(f"{label}: an import path is 'module:function', got {path!r}")
    try:
        obj = _import(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except ImportError as exc:
        raise ValueError(f"{label}: cannot import {module_name!r}: {exc}") from None
    except AttributeError:
        raise ValueError(f"{label}: module {module_name!r} has no attribute {attr!r}") from None
    if not callable(obj):
        raise ValueError(f"{label}: {attr!r} is a {type(obj).__name__}, not a function")
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # a callable without a signature (a C function) is taken as it is
        return obj
    try:
        signature.bind(None, None, None, None, image_size1=None, image_size2=None, shapes1=None, shapes2=None)
    except TypeError as exc:
        raise ValueError(f"{label}: a filter takes {_SIGNATURE}; {attr}{signature} does not ({exc})") from None
    return obj


def _import(module_name: str):
    """``importlib.import_module``, then once more with the current folder on ``sys.path`` when the module is
    not found elsewhere."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        here = os.getcwd()
        if exc.name != module_name.split(".")[0] or here in sys.path or "" in sys.path:
            raise
        sys.path.append(here)
        return importlib.import_module(module_name)
