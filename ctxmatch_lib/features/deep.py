"""Deep patch descriptors (HardNet2, SOSNet stand-ins) and OriNet orientation, run in numpy.

The paper (Sec. 5) describes HarrisZ and SIFT patches with HardNet2 and SOSNet after the learned orientation
of Yi et al. (CVPR 2016). Here 32×32 patches are sampled from LAFs ``[support × A | kpt]`` as kornia's
``extract_patches_from_pyramid`` samples them, oriented by OriNet (a learned orientation standing in for Yi et
al.'s, which is not obtainable) and described by a network. HardNet2 and SOSNet weights are not obtainable
here either: the presets of :data:`ctxmatch_lib.features.FEATURE_PRESETS` use **stand-in** weights, and say so:
``HardTFeat.pth`` (TFeat architecture trained with the HardNet loss) for HardNet2, ``tfeat-liberty.params``
(TFeat) for SOSNet, and ``OriNet.pth`` for the orientation.

These three networks run in numpy (:mod:`._nn`, float32; no torch needed) from ``.npz`` copies of their
weights shipped in ``ctxmatch_lib/features/weights/`` (MIT-licensed; the notices are in ``LICENSES.md``
there), converted once from the published files by :func:`export_npz` (``python -m
ctxmatch_lib.features.deep SRC_DIR``, needs torch). A weights name resolves to the shipped copy first, then
to ``$CTXMATCH_WEIGHTS`` (else ``$CTXMATCH_DATA/../weights``); a path is used as given (a ``.pth``/``.params``
file is read with torch). ``backend="torch"`` runs kornia's modules and sampler instead (to check the two
agree), and ``weights=None`` asks kornia for the published HardNet / SOSNet / OriNet weights (torch, kornia
and a network connection needed).
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["weights_dir", "shipped_weights_dir", "resolve_weights", "weights_digest", "load_numpy_net",
           "load_descriptor_net", "load_orinet", "orinet_angles", "deep_descriptors", "describe_patches",
           "export_npz", "NUMPY_IMPL"]

PATCH_SIZE = 32
_DEFAULT_NET = {"hardnet2": "hardnet", "sosnet": "sosnet"}
_NUMPY_NETS = ("tfeat", "hardtfeat")  # descriptor architectures with a numpy implementation (plus OriNet)
_BACKENDS = ("auto", "numpy", "torch")
_NPZ_FORMAT = "ctxmatch-patch-net-npz"
#: Tag of the numpy inference, part of :func:`weights_digest` (and so of the feature cache keys): bump it when
#: a change of :mod:`._nn` changes the descriptors or angles.
NUMPY_IMPL = "numpy-2"  # 2: fixed chunk shapes, one BLAS thread (thread-independent numbers)
_SHIPPED = Path(__file__).resolve().parent / "weights"
#: The published files the shipped ``.npz`` copies come from, their architectures and authors.
_SHIPPED_SOURCES = {
    "HardTFeat.pth": ("hardtfeat", "HardTFeat: TFeat architecture trained with the HardNet loss, by Dmytro Mishkin "
                                   "(github.com/ducha-aiki/affnet, pretrained/HardTFeat.pth)",
                      "Copyright (c) 2018 Dmytro Mishkin"),
    "tfeat-liberty.params": ("tfeat", "TFeat trained on Liberty, by Vassileios Balntas "
                                      "(github.com/vbalnt/tfeat, pretrained-models/tfeat-liberty.params)",
                             "Copyright (c) 2018 Vassileios Balntas"),
    "OriNet.pth": ("orinet", "OriNet, by Dmytro Mishkin (github.com/ducha-aiki/affnet, pretrained/OriNet.pth)",
                   "Copyright (c) 2018 Dmytro Mishkin"),
}


def _require_torch():
    try:
        import kornia  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:  # pragma: no cover - exercised where torch is absent
        raise ImportError(
            "this needs the optional torch extra (the kornia backend, kornia's published weights, or reading a "
            f".pth/.params file): pip install 'ctxmatch[kornia]' ({exc})") from exc


def weights_dir() -> Path | None:
    """The shared weights folder: ``$CTXMATCH_WEIGHTS``, else ``$CTXMATCH_DATA/../weights`` (None if unset)."""
    if os.environ.get("CTXMATCH_WEIGHTS"):
        return Path(os.environ["CTXMATCH_WEIGHTS"])
    if os.environ.get("CTXMATCH_DATA"):
        return Path(os.environ["CTXMATCH_DATA"]).parent / "weights"
    return None


def shipped_weights_dir() -> Path:
    """The folder of the ``.npz`` weights shipped with the package (``ctxmatch_lib/features/weights``)."""
    return _SHIPPED


def resolve_weights(name, what: str = "weights") -> Path:
    """The file of ``name``: an existing path; else the shipped ``.npz`` copy of that name (``HardTFeat.pth`` ->
    ``weights/HardTFeat.npz``); else a file name in :func:`weights_dir`.

    Raises
    ------
    FileNotFoundError
        Naming the folders searched and how to set them.
    """
    p = Path(name)
    if p.is_file():
        return p
    if not p.is_absolute() and p.parent == Path("."):
        shipped = _SHIPPED / (p.stem + ".npz")
        if shipped.is_file():
            return shipped
    base = weights_dir()
    if base is not None and not p.is_absolute() and (base / p).is_file():
        return base / p
    raise FileNotFoundError(
        f"{what} file {str(name)!r} not found (looked for the path itself, in the shipped weights {_SHIPPED} and in "
        f"the weights folder {base}); set CTXMATCH_WEIGHTS to the folder that holds it")


@lru_cache(maxsize=32)
def _file_sha1(path: str, mtime_ns: int, size: int) -> str:
    h = hashlib.sha1()
    if path.endswith(".npz"):  # the arrays, not the zip container (whose member dates change per write)
        with np.load(path, allow_pickle=False) as z:
            for k in sorted(z.files):
                a = z[k]
                h.update(f"{k}:{a.dtype.str}:{a.shape};".encode())
                h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def weights_digest(name, what: str = "weights") -> str:
    """Content hash (SHA-1) of a weights file and the inference that runs it, or ``"kornia-published"`` for
    ``None``. ``.npz`` files are hashed by their arrays; the ``":numpy-N"`` tag (:data:`NUMPY_IMPL`) says the numbers
    come from the numpy inference, so a change of it changes the feature cache keys."""
    if name is None:
        return "kornia-published"
    p = resolve_weights(name, what)
    st = p.stat()
    return f"{_file_sha1(str(p.resolve()), st.st_mtime_ns, st.st_size)}:{NUMPY_IMPL}"


# ------------------------------------------------------------------------------------------- numpy nets
@lru_cache(maxsize=16)
def _numpy_params(path: str, arch: str, mtime_ns: int) -> tuple[str, dict]:
    if path.endswith(".npz"):
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["__meta__"])) if "__meta__" in z.files else {}
            params = {k: np.asarray(z[k], np.float32) for k in z.files if k != "__meta__"}
        if meta.get("format") != _NPZ_FORMAT:
            raise ValueError(f"weights {path} is not a ctxmatch patch-network .npz (no {_NPZ_FORMAT!r} __meta__)")
        if arch != "auto" and meta.get("net") != arch:
            raise ValueError(f"weights {path} hold a {meta.get('net')!r} network, not {arch!r}")
        return meta["net"], params
    # A torch file (.pth / .params): read it with torch through the kornia modules, keep the arrays.
    if arch == "auto":
        raise ValueError(f"weights {path}: give net= (the architecture of a .pth/.params file)")
    _require_torch()
    model = _orinet(path) if arch == "orinet" else _descriptor_net("hardnet2", arch, path)
    sd = {k: v.detach().cpu().numpy() for k, v in model.state_dict().items()}
    return arch, {k: v.astype(np.float32) for k, v in sd.items() if np.issubdtype(v.dtype, np.floating)}


def load_numpy_net(weights, net: str):
    """``(architecture, parameters)`` of ``weights`` for the numpy inference of :mod:`._nn`.

    Parameters
    ----------
    weights : str or Path
        A shipped or exported ``.npz`` (by name or path), or a ``.pth``/``.params`` file (read with torch).
    net : {"tfeat", "hardtfeat", "orinet", "auto"}
        The expected architecture (``"auto"``: the one the ``.npz`` names).
    """
    p = resolve_weights(weights, "weights").resolve()
    return _numpy_params(str(p), net, p.stat().st_mtime_ns)


def _use_numpy(backend: str, weights, arch: str) -> bool:
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {_BACKENDS}, got {backend!r}")
    possible = weights is not None and arch in (*_NUMPY_NETS, "orinet")
    if backend == "numpy" and not possible:
        raise ValueError(f"backend='numpy' runs {_NUMPY_NETS} and OriNet from given weights; got net {arch!r} "
                         f"with weights {weights!r} (use backend='torch')")
    return backend != "torch" and possible


# ------------------------------------------------------------------------------------------- torch path
def _hardtfeat():
    """TFeat trained with the HardNet loss ("HardTFeat" of the HardNet authors): per-patch standardisation,
    TFeat's two tanh convolutions, a final 8×8 convolution to 128 and tanh, as the authors define it."""
    import torch
    from torch import nn

    class HardTFeat(nn.Module):
        def __init__(self):
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(1, 32, kernel_size=7), nn.Tanh(), nn.MaxPool2d(kernel_size=2, stride=2),
                nn.Conv2d(32, 64, kernel_size=6), nn.Tanh())
            self.classifier = nn.Sequential(nn.Dropout(0.1), nn.Conv2d(64, 128, kernel_size=8), nn.Tanh())

        def forward(self, x):
            sp, mp = torch.std_mean(x, dim=(-3, -2, -1), keepdim=True)
            x = (x - mp) / (sp + 1e-7)
            return self.classifier(self.features(x)).flatten(1)

    return HardTFeat()


def _state_dict(path: Path):
    import torch

    if str(path).endswith(".npz"):  # a shipped copy: the same arrays under the same names
        return {k: torch.from_numpy(v) for k, v in load_numpy_net(path, "auto")[1].items()}
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
    model.load_state_dict(_state_dict(Path(path)), strict=False)
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
                  batch: int = 512, backend: str = "auto") -> np.ndarray:
    """OriNet orientation of each keypoint's affine-normalised patch (as kornia's LAFOrienter).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
    kpts : ndarray of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel (kornia's convention too).
    shapes : ndarray of shape (N, 2, 2)
        Affine shapes before orientation; the patch covers ``support × A``.
    weights : str or Path, optional
        OriNet weights (see :func:`resolve_weights`); ``None``: kornia's published ones (torch path).
    backend : {"auto", "numpy", "torch"}
        ``"auto"``: numpy whenever ``weights`` are given.

    Returns
    -------
    ndarray of shape (N,)
        θ such that the oriented shape is ``A @ R(θ)``, ``R(θ) = [[cos, -sin], [sin, cos]]``.
    """
    n = len(kpts)
    if n == 0:
        return np.empty(0)
    if _use_numpy(backend, weights, "orinet"):
        from .._numerics import fixedmath as _fixedmath
        from . import _nn

        _, params = load_numpy_net(weights, "orinet")
        img = np.ascontiguousarray(gray, np.float32) / np.float32(255.0)
        A = np.asarray(shapes, np.float64) * float(support)
        out = np.empty(n)
        for s in range(0, n, batch):
            patches = _nn.pyramid_patches(img, kpts[s : s + batch], A[s : s + batch], PATCH_SIZE)
            a = _nn.orinet(params, patches).astype(np.float64)
            # kornia turns the LAF by R_k(a) = [[cos, sin], [-sin, cos]], i.e. R(-a) in our convention.
            sin, cos = _fixedmath.sincos(a)  # not numpy's sin / cos / arctan2: their last bit follows the CPU
            out[s : s + batch] = _fixedmath.atan2(-sin, cos)
        return out
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


def describe_patches(patches, descriptor: str, *, net: str = "auto", weights=None, batch: int = 256,
                     backend: str = "auto") -> np.ndarray:
    """Deep descriptors of ``(N, 32, 32)`` patches (any intensity scale), unit L2 norm, float32.

    ``backend="auto"`` runs numpy for the TFeat-architecture nets (``net`` ``"tfeat"``/``"hardtfeat"``) with
    given ``weights``, torch otherwise (kornia's HardNet / SOSNet, published weights).
    """
    if descriptor not in _DEFAULT_NET:
        raise ValueError(f"descriptor must be one of {tuple(_DEFAULT_NET)}, got {descriptor!r}")
    arch = _DEFAULT_NET[descriptor] if net == "auto" else net
    p = np.asarray(patches, np.float32).reshape(-1, PATCH_SIZE, PATCH_SIZE)
    out = []
    if _use_numpy(backend, weights, arch):
        from . import _nn

        _, params = load_numpy_net(weights, arch)
        for s in range(0, len(p), batch):
            out.append(_nn.NETS[arch](params, p[s : s + batch]).astype(np.float64))
    else:
        import torch

        model = load_descriptor_net(descriptor, net=net, weights=weights)
        t = torch.as_tensor(p)[:, None]
        with torch.no_grad():
            for s in range(0, len(t), batch):
                out.append(model(t[s : s + batch]).double().numpy())
    d = np.concatenate(out) if out else np.empty((0, 128))
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return d.astype(np.float32)


def deep_descriptors(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, descriptor: str, net: str = "auto",
                     weights=None, support: float = 2.0, batch: int = 512, backend: str = "auto") -> np.ndarray:
    """HardNet2 / SOSNet descriptors of oriented keypoint patches (sampled as kornia samples LAFs).

    Parameters
    ----------
    gray : ndarray of shape (H, W)
    kpts : ndarray of shape (N, 2)
        (x, y) pixels, origin at the centre of the top-left pixel.
    shapes : ndarray of shape (N, 2, 2)
        Oriented affine shapes; the 32×32 patch covers ``support × A`` (kornia's LAF ``[support A | kpt]``).
    descriptor, net, weights, backend
        See :func:`load_descriptor_net` and :func:`describe_patches`.

    Returns
    -------
    ndarray of shape (N, 128), float32
        Unit L2 norm.
    """
    n = len(kpts)
    if n == 0:
        return np.empty((0, 128), np.float32)
    if descriptor not in _DEFAULT_NET:
        raise ValueError(f"descriptor must be one of {tuple(_DEFAULT_NET)}, got {descriptor!r}")
    arch = _DEFAULT_NET[descriptor] if net == "auto" else net
    kw = dict(net=net, weights=weights, backend=backend)
    out = []
    if _use_numpy(backend, weights, arch):
        from . import _nn

        img = np.ascontiguousarray(gray, np.float32) / np.float32(255.0)
        A = np.asarray(shapes, np.float64) * float(support)
        for s in range(0, n, batch):
            patches = _nn.pyramid_patches(img, kpts[s : s + batch], A[s : s + batch], PATCH_SIZE)
            out.append(describe_patches(patches, descriptor, **kw))
        return np.concatenate(out)
    _require_torch()
    import torch
    import kornia.feature as KF

    img = _image(gray)
    with torch.no_grad():
        for s in range(0, n, batch):
            laf = _lafs(kpts[s : s + batch], shapes[s : s + batch], support)
            patches = KF.extract_patches_from_pyramid(img, laf, PATCH_SIZE)[0, :, 0]
            out.append(describe_patches(patches.numpy(), descriptor, **kw))
    return np.concatenate(out)


# ------------------------------------------------------------------------------------------- conversion
def export_npz(source, output, net: str) -> Path:
    """Convert a published weights file to the ``.npz`` the numpy inference reads (needs torch and kornia).

    The arrays are the ``state_dict`` of the kornia module (or :func:`_hardtfeat`) after loading ``source``
    exactly as the torch path loads it; ``__meta__`` (JSON) records the architecture, the source file's name
    and SHA-1, and, for the shipped stand-ins, the origin and copyright notice (MIT).

    Parameters
    ----------
    source : str or Path
        ``HardTFeat.pth``, ``tfeat-liberty.params``, ``OriNet.pth`` or another file of that architecture.
    output : str or Path
        The ``.npz`` to write.
    net : {"tfeat", "hardtfeat", "orinet"}
    """
    from ..cache import atomic_path

    if net not in (*_NUMPY_NETS, "orinet"):
        raise ValueError(f"net must be one of {(*_NUMPY_NETS, 'orinet')}, got {net!r}")
    _require_torch()
    source = Path(source)
    model = _orinet(str(source.resolve())) if net == "orinet" else _descriptor_net("hardnet2", net,
                                                                                   str(source.resolve()))
    arrays = {k: np.ascontiguousarray(v.detach().cpu().numpy(), np.float32) for k, v in model.state_dict().items()
              if v.is_floating_point()}
    origin = _SHIPPED_SOURCES.get(source.name)
    meta = {"format": _NPZ_FORMAT, "version": 1, "net": net, "source": source.name,
            "source_sha1": _file_sha1(str(source.resolve()), source.stat().st_mtime_ns, source.stat().st_size),
            "origin": origin[1] if origin else None, "copyright": origin[2] if origin else None,
            "licence": "MIT" if origin else None}
    output = Path(output)
    with atomic_path(output) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, __meta__=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return output


if __name__ == "__main__":  # python -m ctxmatch_lib.features.deep SRC_DIR [OUT_DIR]: regenerate the shipped .npz
    import sys

    if len(sys.argv) not in (2, 3):
        sys.exit("usage: python -m ctxmatch_lib.features.deep SRC_DIR [OUT_DIR]  (SRC_DIR holds "
                 + ", ".join(_SHIPPED_SOURCES) + ")")
    dst = Path(sys.argv[2]) if len(sys.argv) == 3 else _SHIPPED
    dst.mkdir(parents=True, exist_ok=True)
    for name, (arch, _, _) in _SHIPPED_SOURCES.items():
        print(export_npz(Path(sys.argv[1]) / name, dst / (Path(name).stem + ".npz"), arch))
