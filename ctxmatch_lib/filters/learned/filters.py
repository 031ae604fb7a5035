"""The ``oanet`` and ``acne`` entries of the filter registry (numpy inference: torch is not needed).

Both keep the candidates whose inlier logit exceeds ``threshold`` (default 0, the authors' test threshold).
Default weights: **trained here** (``weights/``). Inference is numpy (:mod:`.npnets`);
``learned_logits(..., backend="torch")`` runs the torch modules of :mod:`.nets`, to check that they agree.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..._numerics.docstrings import shared_doc
from ..._numerics.extras import install_hint, require
from ..._numerics.order import canonical_order, spread_back
from .._common import prepare

__all__ = ["oanet_filter", "acne_filter", "learned_logits", "load_learned_model", "load_numpy_model_cached",
           "shipped_weights", "require_torch", "TORCH_HINT"]

_NEEDS_TORCH = "training the learned filters (and their torch backend)"
#: What to install when torch is missing.
TORCH_HINT = install_hint("torch", "torch", _NEEDS_TORCH)
_BACKENDS = ("numpy", "torch")
_WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
_CACHE: dict = {}
_LOCK = threading.Lock()


def require_torch():
    """Import and return ``torch``, or raise ``ImportError`` saying how to install it (:data:`TORCH_HINT`)."""
    return require("torch", "torch", _NEEDS_TORCH)


def shipped_weights(arch: str) -> Path:
    """Path of the weights trained here for ``arch`` ("oanet" or "acne")."""
    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    return _WEIGHTS_DIR / f"{arch}_trained_here.npz"


def _cached(kind, loader, arch, weights):
    # The cache key is the resolved path and its modification time, so a retrained file is reloaded.
    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    path = Path(weights) if weights is not None else shipped_weights(arch)
    if weights is None and not path.is_file():
        raise FileNotFoundError(f"the weights trained here are missing: {path}; run 'ctxmatch train {arch}'")
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        stamp = None
    key = (kind, arch, str(path.resolve()), stamp)
    with _LOCK:
        if key not in _CACHE:
            _CACHE[key] = loader(arch, path)
        return _CACHE[key]


def _load_numpy(arch: str, path: Path):
    from .npnets import from_state_dict, is_tf_checkpoint, load_numpy_model

    if path.suffix == ".npz" or not path.is_file() or (arch == "acne" and is_tf_checkpoint(path)):
        return load_numpy_model(arch, path)
    # A torch checkpoint (ours, the OANet authors'): read with torch, run in numpy.
    require("torch", "torch", f"reading the torch checkpoint {path}",
            alternative="convert it once to .npz, where torch is installed, with python -m "
                        "ctxmatch_lib.filters.learned.checkpoints ARCH WEIGHTS OUT.npz")
    from .checkpoints import load_model

    m = load_model(arch, path)
    sd = {k: v.detach().cpu().numpy() for k, v in m.net.state_dict().items()}
    return from_state_dict(arch, m.net.config.to_dict(), sd, normalization=m.normalization, side=m.side,
                           label=m.label, source=m.source)


def load_numpy_model_cached(arch: str, weights=None):
    """The :class:`~.npnets.NumpyModel` of ``weights`` (default: trained here), cached by path and mtime."""
    return _cached("numpy", _load_numpy, arch, weights)


def load_learned_model(arch: str, weights=None):
    """The torch :class:`~.checkpoints.LoadedModel` for ``arch`` from ``weights``, cached (needs torch)."""
    require_torch()
    from .checkpoints import load_model

    return _cached("torch", load_model, arch, weights)


@contextmanager
def _one_thread(torch):
    # One intra-op thread: the same sums in the same order, whatever the machine's thread count.
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def learned_logits(arch: str, kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, weights=None,
                   normalization: str | None = None, backend: str = "numpy") -> np.ndarray:
    """Inlier logits of the candidates, shape ``(K,)``, from the network ``arch`` ("oanet" or "acne").

    Parameters as :func:`oanet_filter`; ``backend``: ``"numpy"`` or ``"torch"`` (the training modules;
    K = 1 is scored by numpy, as torch's instance norm refuses it).
    """
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2)
    if len(ms) == 0:
        return np.empty(0)
    from .data import network_input

    if backend == "torch" and len(ms) > 1:
        torch = require_torch()
        model = load_learned_model(arch, weights)
    else:
        model = load_numpy_model_cached(arch, weights)
    norm = model.normalization if normalization is None else normalization
    x = network_input(ms.x, ms.y, ms.scores if scores is not None else None, ms.size1, ms.size2,
                      normalization=norm, side=model.side)
    if backend == "torch" and len(ms) > 1:
        with _one_thread(torch), torch.no_grad():
            return model.net(torch.from_numpy(x)[None])[-1][0].double().numpy()
    return model.logits(x).astype(np.float64)


def _filter(arch, kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold, normalization):
    if not np.isscalar(threshold) or not np.isfinite(threshold):
        raise ValueError(f"threshold must be a finite number, got {threshold!r}")
    # The rows in their canonical order (as every registered filter), the decisions spread back.
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2)
    order, twins = canonical_order(ms.x, ms.y, ms.matches, ms.scores)
    logits = learned_logits(arch, kpts1, kpts2, ms.matches[order], None if scores is None else ms.scores[order],
                            image_size1=image_size1, image_size2=image_size2, weights=weights,
                            normalization=normalization)
    return spread_back(logits > threshold, order, twins)


@shared_doc
def oanet_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                 weights=None, threshold: float = 0.0, normalization: str | None = None) -> np.ndarray:
    """OANet (Zhang et al., ICCV 2019) as a match filter; default weights **trained here**.

    Reads coordinates and score ranks; the second stage adds the first's epipolar residuals (Eq. (9)).

    Parameters
    ----------
    %(kpts)s
    %(matches)s
    scores : ndarray of shape (K,) or None
        Lower is better; only their ranks are used. ``None``: all equal.
    image_size1, image_size2 : (int, int)
        (width, height), for the coordinate normalisation (:func:`.data.normalise_coordinates`).
    shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
        Unused.
    weights : str or Path, optional
        Ours (``.npz``, ``.pt``) or the authors' ``model_best.pth`` (``.pt``/``.pth`` need torch).
        Default: ``weights/oanet_trained_here.npz``.
    threshold : float, default 0
        Keep ``logit > threshold``.
    normalization : {"image", "hartley"}, optional
        Override the checkpoint's coordinate normalisation.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    J. Zhang et al., "Learning two-view correspondences and geometry using order-aware network", ICCV 2019.
    """
    return _filter("oanet", kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold,
                   normalization)


def acne_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                weights=None, threshold: float = 0.0, normalization: str | None = None) -> np.ndarray:
    """ACNe (Sun et al., CVPR 2020) as a match filter; default weights **trained here**.

    Reads only the normalised coordinates (``scores`` are validated, unused); the inlier logit is the
    output layer's local attention.

    Parameters
    ----------
    kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2, threshold, normalization
        As in :func:`oanet_filter`.
    weights : str or Path, optional
        Ours (``.npz`` or ``.pt``) or the authors' TensorFlow checkpoint (prefix, ``.index`` file or folder;
        read without TensorFlow). Default: ``weights/acne_trained_here.npz``.

    Returns
    -------
    keep : ndarray of shape (K,), bool

    References
    ----------
    W. Sun et al., "ACNe: Attentive context normalization for robust permutation-equivariant learning", CVPR 2020.
    """
    return _filter("acne", kpts1, kpts2, matches, scores, image_size1, image_size2, weights, threshold,
                   normalization)
