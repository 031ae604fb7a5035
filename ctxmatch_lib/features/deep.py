"""Deep patch descriptors (HardNet2, SOSNet) and OriNet orientation through kornia: the optional torch extra.

The paper (Sec. 5) describes HarrisZ and SIFT patches with HardNet2 and SOSNet after the learned orientation
of Yi et al. (CVPR 2016). Here the patches are sampled by kornia (:func:`kornia.feature.extract_patches_from_pyramid`,
32×32, from LAFs ``[support × A | kpt]``), oriented by kornia's :class:`~kornia.feature.OriNet` (a learned
orientation standing in for Yi et al.'s, which is not obtainable) and described by kornia's networks.

Weights load the way kornia does: ``weights=None`` asks kornia for its published weights (a download on a
connected machine); ``weights="file"`` loads that file instead (a path, or a name in the weights folder:
``$CTXMATCH_WEIGHTS``, else ``$CTXMATCH_DATA/../weights``). Without network access the presets of
:data:`ctxmatch_lib.features.FEATURE_PRESETS` use **stand-in** weights, and say so: ``HardTFeat.pth`` (TFeat
architecture trained with the HardNet loss) for HardNet2, ``tfeat-liberty.params`` (TFeat) for SOSNet, and
``OriNet.pth`` for the orientation.

torch and kornia are imported only when these functions run; ``import ctxmatch_lib`` never needs them.
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["weights_dir", "resolve_weights", "weights_digest", "load_descriptor_net", "load_orinet",
           "orinet_angles", "deep_descriptors", "describe_patches"]

PATCH_SIZE = 32
_DEFAULT_NET = {"hardnet2": "hardnet", "sosnet": "sosnet"}


def _require_torch():
    try:
        import kornia  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:  # pragma: no cover - exercised where torch is absent
        raise ImportError(
            "the deep descriptors and OriNet need the optional torch extra: pip install 'ctxmatch[kornia]' "
            f"({exc})") from exc


def weights_dir() -> Path | None:
    """The shared weights folder: ``$CTXMATCH_WEIGHTS``, else ``$CTXMATCH_DATA/../weights`` (None if unset)."""
    if os.environ.get("CTXMATCH_WEIGHTS"):
        return Path(os.environ["CTXMATCH_WEIGHTS"])
    if os.environ.get("CTXMATCH_DATA"):
        return Path(os.environ["CTXMATCH_DATA"]).parent / "weights"
    return None


def resolve_weights(name, what: str = "weights") -> Path:
    """The file of ``name``: an existing path, or a file name in :func:`weights_dir`.

    Raises
    ------
    FileNotFoundError
        Naming the folders searched and how to set them.
    """
    p = Path(name)
    if p.is_file():
        return p
    base = weights_dir()
    if base is not None and not p.is_absolute() and (base / p).is_file():
        return base / p
    raise FileNotFoundError(
        f"{what} file {str(name)!r} not found (looked for the path itself and in the weights folder "
        f"{base}); set CTXMATCH_WEIGHTS to the folder that holds it")


@lru_cache(maxsize=32)
def _file_sha1(path: str, mtime_ns: int, size: int) -> str:
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def weights_digest(name, what: str = "weights") -> str:
    """Content hash (SHA-1) of a weights file, or ``"kornia-published"`` for ``None``."""
    if name is None:
        return "kornia-published"
    p = resolve_weights(name, what)
    st = p.stat()
    return _file_sha1(str(p.resolve()), st.st_mtime_ns, st.st_size)


def _hardtfeat():
    """TFeat trained with the HardNet loss ("HardTFeat" of the HardNet authors): per-patch standardisation,
    TFeat's two tanh convolutions, a final 8×8 convolution to 128, L2 normalisation."""
    import torch
    from torch import nn

    class HardTFeat(nn.Module):
        def __init__(self):
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(1, 32, kernel_size=7), nn.Tanh(), nn.MaxPool2d(kernel_size=2, stride=2),
                nn.Conv2d(32, 64, kernel_size=6), nn.Tanh())
            self.classifier = nn.Sequential(nn.Dropout(0.1), nn.Conv2d(64, 128, kernel_size=8))

        def forward(self, x):
            sp, mp = torch.std_mean(x, dim=(-3, -2, -1), keepdim=True)
            x = (x - mp) / (sp + 1e-7)
            return self.classifier(self.features(x)).flatten(1)

    return HardTFeat()


def _state_dict(path: Path):
    import torch

    sd = torch.load(path, map_location="cpu", weights_only=False)
    return sd["state_dict"] if isinstance(sd, dict) and "state_dict" in sd else sd


@lru_cache(maxsize=8)
def _descriptor_net(descriptor: str, net: str, path: str | None):
    import kornia.feature as KF

    arch = _DEFAULT_NET[descriptor] if net == "auto" else net
    if path is None:  # the published weights, as kornia loads them (needs network access)
        model = {"hardnet": lambda: KF.HardNet(pretrained=True), "sosnet": lambda: KF.SOSNet(pretrained=True),
                 "tfeat": lambda: KF.TFeat(pretrained=True)}.get(arch)
        if model is None:
            raise ValueError(f"net {arch!r} has no published kornia weights; give weights=")
        return model().eval()
    model = {"hardnet": lambda: KF.HardNet(pretrained=False), "sosnet": lambda: KF.SOSNet(pretrained=False),
             "tfeat": lambda: KF.TFeat(pretrained=False), "hardtfeat": _hardtfeat}[arch]()
    sd = _state_dict(Path(path))
    if arch == "hardtfeat":  # the file also holds an unused SIFT-gradient helper
        sd = {k: v for k, v in sd.items() if k.split(".")[0] in ("features", "classifier")}
    model.load_state_dict(sd, strict=True)
    return model.eval()


def load_descriptor_net(descriptor: str, *, net: str = "auto", weights=None):
    """The torch module of a deep descriptor, in evaluation mode (cached per process).

    Parameters
    ----------
    descriptor : {"hardnet2", "sosnet"}
    net : {"auto", "hardnet", "sosnet", "tfeat", "hardtfeat"}
        Architecture; ``"auto"``: kornia's HardNet for hardnet2, SOSNet for sosnet.
    weights : str or Path, optional
        Weights file (see :func:`resolve_weights`); ``None``: kornia's published weights.
    """
    _require_torch()
    if descriptor not in _DEFAULT_NET:
        raise ValueError(f"descriptor must be one of {tuple(_DEFAULT_NET)}, got {descriptor!r}")
    path = None if weights is None else str(resolve_weights(weights, "descriptor weights").resolve())
    return _descriptor_net(descriptor, net, path)


@lru_cache(maxsize=4)
def _orinet(path: str | None):
    import torch
    import kornia.feature as KF

    if path is None:
        return KF.OriNet(pretrained=True).eval()
    model = KF.OriNet(pretrained=False)
    # As kornia: the checkpoint's "state_dict", loaded non-strictly.
    model.load_state_dict(torch.load(path, map_location="cpu", weights_only=False)["state_dict"], strict=False)
    return model.eval()


def load_orinet(weights=None):
    """kornia's OriNet in evaluation mode, with ``weights`` (path or name) or kornia's published ones."""
    _require_torch()
    path = None if weights is None else str(resolve_weights(weights, "OriNet weights").resolve())
    return _orinet(path)


def _lafs(kpts, shapes, support):
    import torch

    A = np.asarray(shapes, np.float64) * float(support)
    laf = np.concatenate([A, np.asarray(kpts, np.float64)[:, :, None]], axis=2)  # (N, 2, 3) = [A | c]
    return torch.from_numpy(laf).float()[None]


def _image(gray):
    import torch

    return torch.from_numpy(np.ascontiguousarray(gray, np.float32) / 255.0)[None, None]


def orinet_angles(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, weights=None, support: float = 2.0,
                  batch: int = 2048) -> np.ndarray:
    """OriNet orientation of each keypoint's affine-normalised patch (kornia's LAFOrienter).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
    kpts : ndarray of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel (kornia's convention too).
    shapes : ndarray of shape (N, 2, 2)
        Affine shapes before orientation; the patch covers ``support × A``.

    Returns
    -------
    ndarray of shape (N,)
        θ such that the oriented shape is ``A @ R(θ)``, ``R(θ) = [[cos, -sin], [sin, cos]]``.
    """
    n = len(kpts)
    if n == 0:
        return np.empty(0)
    _require_torch()
    import torch
    import kornia.feature as KF

    model = load_orinet(weights)
    orienter = KF.LAFOrienter(PATCH_SIZE, angle_detector=model).eval()
    img = _image(gray)
    out = np.empty(n)
    with torch.no_grad():
        for s in range(0, n, batch):
            laf = _lafs(kpts[s : s + batch], shapes[s : s + batch], support)
            new = orienter(laf, img)[0, :, :, :2].double().numpy()
            old = laf[0, :, :, :2].double().numpy()
            R = np.linalg.solve(old, new)  # old @ R = new
            out[s : s + batch] = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return out


def describe_patches(patches, descriptor: str, *, net: str = "auto", weights=None, batch: int = 1024) -> np.ndarray:
    """Deep descriptors of ``(N, 32, 32)`` patches (any intensity scale), unit L2 norm, float32."""
    import torch

    model = load_descriptor_net(descriptor, net=net, weights=weights)
    p = torch.as_tensor(np.asarray(patches, np.float32)).reshape(-1, 1, PATCH_SIZE, PATCH_SIZE)
    out = []
    with torch.no_grad():
        for s in range(0, len(p), batch):
            out.append(model(p[s : s + batch]).double().numpy())
    d = np.concatenate(out) if out else np.empty((0, 128))
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return d.astype(np.float32)


def deep_descriptors(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, descriptor: str, net: str = "auto",
                     weights=None, support: float = 2.0, batch: int = 2048) -> np.ndarray:
    """HardNet2 / SOSNet descriptors of oriented keypoint patches sampled by kornia.

    Parameters
    ----------
    gray : ndarray of shape (H, W)
    kpts : ndarray of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.
    shapes : ndarray of shape (N, 2, 2)
        Oriented affine shapes; the 32×32 patch covers ``support × A`` (kornia's LAF ``[support A | kpt]``).
    descriptor, net, weights
        See :func:`load_descriptor_net`.

    Returns
    -------
    ndarray of shape (N, 128), float32
        Unit L2 norm.
    """
    n = len(kpts)
    if n == 0:
        return np.empty((0, 128), np.float32)
    _require_torch()
    import torch
    import kornia.feature as KF

    img = _image(gray)
    out = []
    with torch.no_grad():
        for s in range(0, n, batch):
            laf = _lafs(kpts[s : s + batch], shapes[s : s + batch], support)
            patches = KF.extract_patches_from_pyramid(img, laf, PATCH_SIZE)[0, :, 0]
            out.append(describe_patches(patches.numpy(), descriptor, net=net, weights=weights))
    return np.concatenate(out)
