"""Spatial match filters behind one registry.

Every filter has the same signature::

    FILTERS[name](kpts1, kpts2, matches, scores, *, image_size1, image_size2,
                  shapes1=None, shapes2=None, **params) -> keep  # (K,) bool

``kpts*`` are ``(N, 2)`` (x, y) pixels, origin at the centre of the top-left pixel; ``matches`` ``(K, 2)``
indices (many-to-many allowed); ``scores`` ``(K,)``, lower is better; ``matches[keep]`` are kept. NNR
thresholds (``th``, ``glpm``, ``adalam``) are read on the scores' scale (:func:`nnr_scores`). Filters are
imported on first use; :func:`register_filter` adds one. Guide: ``docs/filters.md``.

Every spatial filter drops the one outlier of a translated grid and keeps the rest:

>>> import numpy as np
>>> g = np.stack(np.meshgrid(np.arange(8) * 20.0, np.arange(8) * 20.0), -1).reshape(-1, 2)
>>> y = g + (7.0, -3.0)
>>> y[0] = (300.0, 200.0)  # one outlier
>>> m, shapes = np.c_[np.arange(64), np.arange(64)], np.tile(3.0 * np.eye(2), (64, 1, 1))  # scale 3, upright
>>> def kept(name):
...     keep = FILTERS[name](g, y, m, image_size1=(400, 300), image_size2=(400, 300), shapes1=shapes, shapes2=shapes)
...     return bool(keep[0]), int(keep[1:].sum())
>>> names = ("lpm", "glpm", "vfc", "llt", "adalam", "rfm_scan", "pgm", "scv", "bm", "pfm", "lmr")
>>> [name for name in names if kept(name) != (False, 63)]
[]
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Iterator, Mapping

from .._numerics.scores import nnr_scores

__all__ = ["FILTERS", "register_filter", "nnr_scores"]

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
    # Learned filters (numpy inference; default weights trained here, not the authors'; torch only to train).
    "oanet": "ctxmatch_lib.filters.learned.filters:oanet_filter",
    "acne": "ctxmatch_lib.filters.learned.filters:acne_filter",
}


class _Registry(Mapping):
    """Read-only mapping name -> filter function that imports built-in filters on first access."""

    def __init__(self) -> None:
        self._loaded: dict[str, Callable] = {}

    def __getitem__(self, name: str) -> Callable:
        if name in self._loaded:
            return self._loaded[name]
        if name not in _BUILTIN:
            raise KeyError(f"unknown filter {name!r}; known filters: {', '.join(self)}")
        module, func, *stages = _BUILTIN[name].split(":")
        f = getattr(importlib.import_module(module), func)
        self._loaded[name] = functools.partial(f, stages=int(stages[0])) if stages else f
        return self._loaded[name]

    def __iter__(self) -> Iterator[str]:
        yield from _BUILTIN
        yield from (k for k in self._loaded if k not in _BUILTIN)

    def __len__(self) -> int:
        return len(set(_BUILTIN) | set(self._loaded))


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
