"""Learned match filters: OANet (Zhang et al., ICCV 2019) and ACNe (Sun et al., CVPR 2020), with weights trained here.

The paper compares DTM with OANet and ACNe (Sec. 5, Tables 1-3, Fig. 9). Their authors' weights are not
obtainable on the project machines, so the default weights are **trained here** by
:func:`train_learned_filter` (``ctxmatch train oanet|acne``) on correspondences generated from the embedded
images (:mod:`.data`), and shipped in ``weights/{oanet,acne}_trained_here.npz``. They are smaller networks
than the authors' and every label says "trained here". The authors' checkpoints load with ``weights=``.

The filters run in numpy (:mod:`.npnets`): they need no torch and give the same numbers with or without it.
PyTorch is needed only to train (:func:`train_learned_filter`, ``ctxmatch train``), to read torch checkpoints
(``.pt``/``.pth``; :func:`~.checkpoints.convert_to_npz` converts them once) and for ``backend="torch"``; those
raise ``ImportError`` with the install hint (``pip install torch==2.13.0``, or the ``torch`` extra).

====================  ======================================================================================
name                  what
====================  ======================================================================================
``oanet_filter``      registry ``"oanet"``: keep mask from OANet's last-stage inlier logits (``logit > 0``)
``acne_filter``       registry ``"acne"``: keep mask from ACNe's inlier logits (``logit > 0``)
``learned_logits``    the logits themselves, for precision/recall curves
``train_learned_filter``  train either network here (seeded, tqdm progress), optionally save the weights
``shipped_weights``   path of the weights trained here
====================  ======================================================================================
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
    """Train OANet or ACNe here, on generated correspondences or on blob candidates of generated pairs.

    Each step draws ``batch_size`` candidate sets of K correspondences (K uniform in ``n_candidates``) from
    :func:`~.data.random_training_set`: SIFT keypoints of the embedded images under a random homography or
    a layered non-planar scene, planted outliers, inlier ratio uniform in 5-60 %. Never reads
    ``CTXMATCH_DATA``. With ``data="blob"``, each step draws ``batch_size`` of the given ``blob_sets`` (the
    project's blob candidates on warped and layered scenes of scikit-image's photos, built above the evaluation
    engine: :func:`ctxmatch_lib.training.train_on_blob_candidates` builds them and calls this function)
    instead, each cut to a random subset of K = min(their sizes, ``n_candidates`` high end) rows.

    Parameters
    ----------
    arch : {"oanet", "acne"}
    steps : int, optional
        Optimisation steps (Adam, cosine learning-rate decay). Default: those of the shipped weights, 400
        for OANet and 2000 for ACNe (:data:`~.training.TRAINED_HERE_STEPS`); with the other defaults this
        reproduces them (same torch version and CPU kind).
    batch_size : int, default 8
        Candidate sets per step.
    n_candidates : int or (int, int), default (500, 1500)
        K, or the range it is drawn from per step.
    lr : float, default 1e-3
        Initial learning rate (the authors' value).
    seed : int, default 0
        Seeds the data generator and the weight initialisation: same seed and thread count, same weights.
    config : dict, optional
        Overrides of the network shape (:data:`~.training.TRAINED_HERE_CONFIGS`).
    output : str or Path, optional
        Where to save the weights (ctxmatch format, labelled "trained here").
    max_images : int, optional
        Use only the first embedded images as keypoint sources (tiny runs).
    num_threads : int, default 1
        torch intra-op threads during training (restored afterwards).
    progress : bool, default True
        Show a tqdm progress bar.
    validate : bool, default True
        Measure precision and recall of ``logit > 0`` at the end: on 20 generated sets at 40 % inliers, or
        (``data="blob"``) on the held-out scenes' blob sets (the last 10 %).
    data : {"generated", "blob"}, default "generated"
        The training sets: :mod:`.data`, or the given ``blob_sets``.
    balanced : bool, default False
        The OANet / CNe authors' balanced loss (mean over inliers and mean over outliers, half each)
        instead of the plain mean binary cross-entropy.
    init : str or Path, optional
        Start from these weights (same network shape): fine-tuning.
    blob_sets : (list, list, dict), optional
        With ``data="blob"``: the training sets, the validation sets and a description recorded in the
        weights' metadata (:func:`ctxmatch_lib.training.blob_training_sets`).

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
