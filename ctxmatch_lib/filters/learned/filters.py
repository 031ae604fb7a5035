"""The ``oanet`` and ``acne`` entries of the filter registry (torch imported on the first call only).

Both filters score every candidate with a permutation-equivariant network and keep those whose inlier logit
is above ``threshold`` (default 0, i.e. an inlier probability above 1/2; the OANet and ACNe authors' test
threshold). Without ``weights`` they use the weights **trained here** (shipped in
``ctxmatch_lib/filters/learned/weights/``, trained by :func:`~ctxmatch_lib.filters.learned.train_learned_filter`
on correspondences generated from the embedded images; not the authors' weights, which are not obtainable
here). ``weights=`` accepts the authors' released checkpoints in their own formats (see
:mod:`.checkpoints`).
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._common import prepare

__all__ = ["oanet_filter", "acne_filter", "learned_logits", "load_learned_model", "shipped_weights",
           "require_torch", "TORCH_HINT"]

TORCH_HINT = ("the learned filters need PyTorch: pip install torch==2.13.0 "
              "(or install ctxmatch with the 'torch' extra: pip install 'ctxmatch[torch]')")
_WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
_CACHE: dict = {}
_LOCK = threading.Lock()


def require_torch():
    """Import and return ``torch``, or raise ``ImportError`` saying how to install it."""
    try:
        import torch
    except ImportError as e:
        raise ImportError(TORCH_HINT) from e
    return torch


def shipped_weights(arch: str) -> Path:
    """Path of the weights trained here for ``arch`` ("oanet" or "acne")."""
    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    return _WEIGHTS_DIR / f"{arch}_trained_here.pt"


def load_learned_model(arch: str, weights=None):
    """The :class:`~.checkpoints.LoadedModel` for ``arch`` from ``weights`` (default: trained here), cached.

    The cache key is the resolved path and its modification time, so a retrained file is reloaded.
    """
    require_torch()
    from .checkpoints import load_model

    path = Path(weights) if weights is not None else shipped_weights(arch)
    if weights is None and not path.is_file():
        raise FileNotFoundError(f"the weights trained here are missing: {path}; run 'ctxmatch train {arch}'")
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        stamp = None
    key = (arch, str(path.resolve()), stamp)
    with _LOCK:
        if key not in _CACHE:
            _CACHE[key] = load_model(arch, path)
        return _CACHE[key]


@contextmanager
def _one_thread(torch):
    # One intra-op thread: the same sums in the same order whatever the machine, so results do not depend on
    # the thread count; at K = 2000 the networks run well under a second anyway.
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def learned_logits(arch: str, kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, weights=None,
                   normalization: str | None = None) -> np.ndarray:
    """Inlier logits of the candidates, shape ``(K,)``, from the network ``arch`` ("oanet" or "acne").

    Parameters are those of :func:`oanet_filter`. Returns float64 logits; ``logit > 0`` means inlier
    probability above 1/2.
    """
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2)
    if len(ms) == 0:
        return np.empty(0)
    torch = require_torch()
    from .data import network_input

    model = load_learned_model(arch, weights)
    norm = model.normalization if normalization is None else normalization
    x = network_input(ms.x, ms.y, ms.scores if scores is not None else None, ms.size1, ms.size2,
                      normalization=norm, side=model.side)
    with _one_thread(torch), torch.no_grad():
        logits = model.net(torch.from_numpy(x)[None])[-1][0]
    return logits.double().numpy()


def _filter(arch, kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold, normalization):
    if not np.isscalar(threshold) or not np.isfinite(threshold):
        raise ValueError(f"threshold must be a finite number, got {threshold!r}")
    logits = learned_logits(arch, kpts1, kpts2, matches, scores, image_size1=image_size1,
                            image_size2=image_size2, weights=weights, normalization=normalization)
    return logits > threshold


def oanet_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                 weights=None, threshold: float = 0.0, normalization: str | None = None) -> np.ndarray:
    """OANet (Zhang et al., ICCV 2019) as a match filter; default weights **trained here**.

    The network reads, per candidate, the normalised coordinates of its two keypoints and, as side
    information, the rank of its score among the candidates (the weights trained here; the authors'
    side-information models read the ratio-test value and the mutual-check flag instead). It runs its two
    stages (the second adds the epipolar residuals of the first stage's weighted eight-point fit) and keeps
    the candidates whose last-stage logit exceeds ``threshold``.

    Parameters
    ----------
    kpts1, kpts2 : ndarray of shape (N1, 2) and (N2, 2)
        Keypoints as (x, y) pixels, origin at the centre of the top-left pixel.
    matches : ndarray of shape (K, 2)
        Indices into ``kpts1`` and ``kpts2`` (many-to-many allowed).
    scores : ndarray of shape (K,) or None
        Lower is better; only their ranks are used. ``None``: all equal.
    image_size1, image_size2 : (int, int)
        (width, height); coordinates are normalised by them: ``(p + 0.5 - size / 2) / (max(size) / 2)``.
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    weights : str or Path, optional
        A checkpoint: ours (``ctxmatch train oanet``) or the authors' ``model_best.pth``. Default: the
        weights trained here, ``weights/oanet_trained_here.pt``.
    threshold : float, default 0
        Keep ``logit > threshold`` (0: inlier probability above 1/2, the authors' test threshold).
    normalization : {"image", "hartley"}, optional
        Override the checkpoint's coordinate normalisation (``"image"`` for the weights trained here,
        ``"hartley"`` for the authors').

    Returns
    -------
    keep : ndarray of shape (K,), bool

    Raises
    ------
    ImportError
        PyTorch is not installed (``pip install torch==2.13.0`` or the ``torch`` extra).

    References
    ----------
    J. Zhang et al., "Learning two-view correspondences and geometry using order-aware network", ICCV 2019.
    """
    return _filter("oanet", kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold,
                   normalization)


def acne_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                weights=None, threshold: float = 0.0, normalization: str | None = None) -> np.ndarray:
    """ACNe (Sun et al., CVPR 2020) as a match filter; default weights **trained here**.

    The network reads only the normalised coordinates of each candidate's two keypoints (ACNe uses no side
    information; ``scores`` are validated and ignored) and keeps the candidates whose inlier logit (the local
    attention of the output layer) exceeds ``threshold``.

    Parameters
    ----------
    kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2
        As in :func:`oanet_filter`.
    weights : str or Path, optional
        A checkpoint: ours (``ctxmatch train acne``) or the authors' TensorFlow checkpoint (prefix, ``.index``
        file or folder). Default: the weights trained here, ``weights/acne_trained_here.pt``.
    threshold : float, default 0
        Keep ``logit > threshold`` (sigmoid above 1/2, as the authors' inlier test).
    normalization : {"image", "hartley"}, optional
        As in :func:`oanet_filter`.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    W. Sun et al., "ACNe: Attentive context normalization for robust permutation-equivariant learning",
    CVPR 2020.
    """
    return _filter("acne", kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold,
                   normalization)
