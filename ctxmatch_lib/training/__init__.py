"""Training sets of blob candidates built with the engine's per-pair steps (:mod:`.blobsets`), above the
learned filters, which never build candidates: :func:`blob_training_sets` and
:func:`train_on_blob_candidates` (needs torch)."""

from __future__ import annotations

from . import blobsets
from .blobsets import BlobSet, build_sets, describe, scene_count

__all__ = ["BLOB_SCENES", "BLOB_VAL_FRACTION", "BLOB_MIN_CANDIDATES", "BlobSet", "blobsets", "blob_training_sets",
           "train_on_blob_candidates"]

#: Blob training sets: generated scenes, the held-out fraction, the smallest set used.
BLOB_SCENES = 48
BLOB_VAL_FRACTION = 0.1
BLOB_MIN_CANDIDATES = 100


def blob_training_sets(n_scenes: int = BLOB_SCENES, seed: int = 0, *, min_candidates: int = BLOB_MIN_CANDIDATES,
                       val_fraction: float = BLOB_VAL_FRACTION, cache_dir=None, progress: bool = False):
    """``(train, validation, description)`` blob sets of :func:`.blobsets.build_sets`: the ``blob_sets``
    argument of :func:`~ctxmatch_lib.filters.learned.train_learned_filter`. The last ``val_fraction`` of the
    scenes (at least one when ``n_scenes > 1``) are held out; sets under ``min_candidates`` rows or without
    an inlier are dropped."""
    if not 0 <= val_fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction!r}")
    sets = build_sets(n_scenes, seed, cache_dir=cache_dir, progress=progress)
    n_val = max(1, int(round(val_fraction * n_scenes))) if n_scenes > 1 and val_fraction > 0 else 0
    cut = (n_scenes - n_val) * scene_count()
    ok = [len(s.x1) >= min_candidates and s.is_inlier.any() for s in sets]
    train_sets = [s for i, s in enumerate(sets) if ok[i] and (i < cut or not n_val)]
    val_sets = [s for i, s in enumerate(sets) if ok[i] and i >= cut and n_val]
    return train_sets, val_sets, {"n_scenes": int(n_scenes), "blobsets": describe()}


def train_on_blob_candidates(arch: str, *, n_scenes: int = BLOB_SCENES, seed: int = 0, cache_dir=None, **kwargs):
    """Train OANet or ACNe on :func:`blob_training_sets`: :func:`~ctxmatch_lib.filters.learned.train_learned_filter`
    with ``data="blob"``, the same ``seed`` and ``kwargs`` (``steps``, ``init``, ``output``, ...). Needs torch."""
    from ..filters.learned import require_torch, train_learned_filter

    require_torch()
    sets = blob_training_sets(n_scenes, seed, cache_dir=cache_dir, progress=kwargs.get("progress", True))
    return train_learned_filter(arch, data="blob", blob_sets=sets, seed=seed, **kwargs)
