"""Learned match filters: OANet (Zhang et al., ICCV 2019) and ACNe (Sun et al., CVPR 2020), with weights trained here.

Compared with DTM in Sec. 5, Tables 1-3, Fig. 9. The shipped, smaller networks are **trained here**
(:func:`train_learned_filter`, :mod:`.data`); ``weights=`` loads the authors' checkpoints. Inference is
numpy (:mod:`.npnets`); torch is needed only to train, to read ``.pt``/``.pth`` and for ``backend="torch"``.
"""

from __future__ import annotations

import importlib.util

from .filters import (TORCH_HINT, acne_filter, learned_logits, load_learned_model, load_numpy_model_cached,
                      oanet_filter, require_torch, shipped_weights)

__all__ = ["oanet_filter", "acne_filter", "learned_logits", "load_learned_model", "load_numpy_model_cached",
           "shipped_weights", "train_learned_filter", "torch_available", "LEARNED_FILTERS", "TORCH_HINT"]

#: Registry names of the learned filters (numpy inference: always available).
LEARNED_FILTERS = ("oanet", "acne")


def torch_available() -> bool:
    """Whether torch can be imported (without importing it): training and the torch backend need it."""
    try:
        return importlib.util.find_spec("torch") is not None
    except ValueError:  # sys.modules["torch"] is None: import blocked
        return False


def train_learned_filter(arch: str, *, steps: int | None = None, batch_size: int = 8, n_candidates=(500, 1500),
                         lr: float = 1e-3, seed: int = 0, config: dict | None = None, output=None,
                         max_images: int | None = None, num_threads: int = 1, progress: bool = True,
                         validate: bool = True, data: str = "generated", balanced: bool = False, init=None,
                         blob_sets=None):
    """Train OANet or ACNe here (see :mod:`.training` for the loss, the optimiser and the data).

    Parameters
    ----------
    arch : {"oanet", "acne"}
    steps, batch_size : int, optional, and int, default 8
        Optimisation steps (default: the shipped weights', :data:`~.training.TRAINED_HERE_STEPS`); sets per step.
    n_candidates : int or (int, int), default (500, 1500)
        K, or the range it is drawn from per step (``data="blob"``: its high end caps K).
    lr, seed : float, int, default 1e-3 and 0
        Initial learning rate (the authors'); seed of data and initialisation (same seed, same weights).
    config, output, init : dict, path, path, optional
        Network shape overrides (:data:`~.training.TRAINED_HERE_CONFIGS`); where to save; weights to start from.
    max_images, num_threads, progress : int, int, bool, default None, 1, True
        Only the first embedded images as keypoint sources; torch threads; a tqdm progress bar.
    validate, balanced : bool, default True and False
        Precision and recall of ``logit > 0`` at the end; the OANet / CNe authors' balanced loss.
    data, blob_sets : {"generated", "blob"}, (list, list, dict)
        Sets of :mod:`.data`, or ``blob_sets`` (:func:`ctxmatch_lib.training.blob_training_sets`).

    Returns
    -------
    TrainResult
        ``.net`` (eval mode), ``.losses``, ``.validation``, ``.seconds``, ``.path``; ``ImportError`` without torch.
    """
    require_torch()
    from .training import train

    return train(arch, steps=steps, batch_size=batch_size, n_candidates=n_candidates, lr=lr, seed=seed,
                 config=config, output=output, max_images=max_images, num_threads=num_threads,
                 progress=progress, validate=validate, data=data, balanced=balanced, init=init,
                 blob_sets=blob_sets)
