"""Learned match filters: OANet (Zhang et al., ICCV 2019) and ACNe (Sun et al., CVPR 2020), with weights trained here.

The paper compares DTM with OANet and ACNe (Sec. 5, Tables 1-3, Fig. 9). The authors' weights cannot be
obtained here, so the shipped weights (``weights/{oanet,acne}_trained_here.npz``, smaller networks) are
**trained here** by :func:`train_learned_filter` on generated correspondences (:mod:`.data`); the authors'
checkpoints load with ``weights=``. The filters run in numpy (:mod:`.npnets`); torch is needed only to
train, to read ``.pt``/``.pth`` checkpoints and for ``backend="torch"`` (``ImportError`` with the install
hint otherwise).

Main functions: :func:`oanet_filter`, :func:`acne_filter` (registry ``"oanet"``, ``"acne"``),
:func:`learned_logits`, :func:`train_learned_filter`, :func:`shipped_weights`.
"""

from __future__ import annotations

import importlib.util

from .filters import (TORCH_HINT, acne_filter, learned_logits, load_learned_model, load_numpy_model_cached,
                      oanet_filter, require_torch, shipped_weights)

__all__ = ["oanet_filter", "acne_filter", "learned_logits", "load_learned_model", "load_numpy_model_cached",
           "shipped_weights",
           "train_learned_filter", "torch_available", "LEARNED_FILTERS", "TORCH_HINT"]

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
    steps : int, optional
        Optimisation steps; default: those of the shipped weights (:data:`~.training.TRAINED_HERE_STEPS`),
        which the other defaults then reproduce (same torch version and CPU kind).
    batch_size : int, default 8
        Candidate sets per step.
    n_candidates : int or (int, int), default (500, 1500)
        K, or the range it is drawn from per step (``data="blob"``: its high end caps K).
    lr : float, default 1e-3
        Initial learning rate (the authors' value).
    seed : int, default 0
        Seeds the data and the initialisation: same seed and thread count, same weights.
    config : dict, optional
        Overrides of the network shape (:data:`~.training.TRAINED_HERE_CONFIGS`).
    output : str or Path, optional
        Where to save the weights (labelled "trained here").
    max_images : int, optional
        Only the first embedded images as keypoint sources (tiny runs).
    num_threads, progress : int, bool, default 1, True
        torch intra-op threads during training; a tqdm progress bar.
    validate : bool, default True
        Precision and recall of ``logit > 0`` at the end, on generated sets at 40 % inliers or on the
        held-out blob sets.
    data : {"generated", "blob"}, default "generated"
        The training sets: :mod:`.data`, or ``blob_sets``.
    balanced : bool, default False
        The OANet / CNe authors' balanced loss instead of the plain mean binary cross-entropy.
    init : str or Path, optional
        Start from these weights (same shape): fine-tuning.
    blob_sets : (list, list, dict), optional
        With ``data="blob"``: training sets, validation sets, description
        (:func:`ctxmatch_lib.training.blob_training_sets`).

    Returns
    -------
    TrainResult
        ``.net`` (eval mode), ``.losses`` per step, ``.validation``, ``.seconds``, ``.path``.

    Raises
    ------
    ImportError
        PyTorch is not installed.
    """
    require_torch()
    from .training import train

    return train(arch, steps=steps, batch_size=batch_size, n_candidates=n_candidates, lr=lr, seed=seed,
                 config=config, output=output, max_images=max_images, num_threads=num_threads,
                 progress=progress, validate=validate, data=data, balanced=balanced, init=init,
                 blob_sets=blob_sets)
