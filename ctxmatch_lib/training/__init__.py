"""Training sets built from the project's own pipeline, above the evaluation engine.

The learned filters sit under the engine and never build candidates; this package builds their training sets
with the engine's per-pair steps (:mod:`.blobsets`) and hands them over: :func:`blob_training_sets` (training
and held-out validation sets) and :func:`train_on_blob_candidates` (those sets, then
:func:`ctxmatch_lib.filters.learned.train_learned_filter` with ``data="blob"``; needs torch). Nothing here
reads ``CTXMATCH_DATA``.
"""

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
    """Training and validation blob sets of ``n_scenes`` generated scenes (:func:`.blobsets.build_sets`).

    The last ``val_fraction`` of the scenes (at least one when ``n_scenes > 1``) are held out; sets with fewer
    than ``min_candidates`` rows or no inlier are left out. ``n_scenes``, ``seed``, ``cache_dir``,
    ``progress``: as in :func:`.blobsets.build_sets`.

    Returns
    -------
    (list of BlobSet, list of BlobSet, dict)
        Training sets, validation sets, description: the ``blob_sets`` argument of
        :func:`~ctxmatch_lib.filters.learned.train_learned_filter`.
    """
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
    """Train OANet or ACNe on blob candidate sets: :func:`blob_training_sets` of ``seed``, then
    :func:`~ctxmatch_lib.filters.learned.train_learned_filter` with ``data="blob"`` and the same ``seed``.

    ``kwargs`` are those of :func:`~ctxmatch_lib.filters.learned.train_learned_filter` (``steps``, ``init``,
    ``balanced``, ``output``, ...). Needs torch.
    """
    from ..filters.learned import require_torch, train_learned_filter

    require_torch()
    sets = blob_training_sets(n_scenes, seed, cache_dir=cache_dir, progress=kwargs.get("progress", True))
    return train_learned_filter(arch, data="blob", blob_sets=sets, seed=seed, **kwargs)
