"""Training sets built from the project's own pipeline, above the evaluation engine.

The learned filters (:mod:`ctxmatch_lib.filters.learned`) sit under the engine: their training loop takes
its sets as arguments and never builds candidates. This package builds them with the engine's per-pair steps
(:mod:`.blobsets`: blob candidates of SIFT / HarrisZ features on warped and layered scenes of scikit-image's
photos, labelled by the known warp) and hands them to the training loop:

* :func:`blob_training_sets`: the sets of ``n_scenes`` generated scenes, split into training and held-out
  validation scenes;
* :func:`train_on_blob_candidates`: those sets, then
  :func:`ctxmatch_lib.filters.learned.train_learned_filter` with ``data="blob"`` (needs torch).

Nothing here reads ``CTXMATCH_DATA`` (the evaluation data). Keypoints are (x, y) pixels, origin at the centre
of the top-left pixel.
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
    than ``min_candidates`` rows or no inlier are left out of both.

    Parameters
    ----------
    n_scenes : int, default :data:`BLOB_SCENES`
        Generated image pairs; each gives :func:`.blobsets.scene_count` sets.
    seed : int, default 0
        Scene ``i`` draws from ``np.random.SeedSequence([seed, i])``.
    min_candidates : int, default :data:`BLOB_MIN_CANDIDATES`
    val_fraction : float, default :data:`BLOB_VAL_FRACTION`
    cache_dir : str or Path, optional
        Where the sets are cached (default: the user's cache, ``learned-sets``).
    progress : bool, default False
        A progress bar while scenes are computed.

    Returns
    -------
    (list of BlobSet, list of BlobSet, dict)
        The training sets, the validation sets and the generator's description (``n_scenes`` and
        :func:`.blobsets.describe`), the ``blob_sets`` argument of
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
