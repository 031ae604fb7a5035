"""Deep patch descriptors (HardNet2, SOSNet) on OriNet-oriented patches (Sec. 5), run in numpy.

The published weights (and Yi et al.'s orientation) are not obtainable, so the presets use **stand-ins**,
shipped as ``.npz`` (:func:`export_npz`) and run by :mod:`._nn`: ``HardTFeat.pth`` for HardNet2,
``tfeat-liberty.params`` for SOSNet, ``OriNet.pth``. ``backend="torch"`` runs kornia's modules instead.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from .._numerics import fixedmath
from .._numerics.extras import require
from ..cache import atomic_path

__all__ = ["weights_dir", "shipped_weights_dir", "resolve_weights", "weights_digest", "load_numpy_net",
           "load_descriptor_net", "load_orinet", "orinet_angles", "deep_descriptors", "describe_patches",
           "export_npz", "NUMPY_IMPL"]

PATCH_SIZE = 32
_DEFAULT_NET = {"hardnet2": "hardnet", "sosnet": "sosnet"}
_NUMPY_NETS = ("tfeat", "hardtfeat")  # descriptor architectures with a numpy implementation (plus OriNet)
_BACKENDS = ("auto", "numpy", "torch")
_NPZ_FORMAT = "ctxmatch-patch-net-npz"
#: Tag of the numpy inference, part of :func:`weights_digest` and so of the feature cache keys: bump it when
#: :mod:`._nn` changes the descriptors or angles.
NUMPY_IMPL = "numpy-2"
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


_NEEDS_KORNIA = "the torch backend of the deep features (kornia's modules and published weights, .pth/.params files)"


def _torch():
    return require("torch", "kornia", _NEEDS_KORNIA)


def _kornia_feature():
    return require("kornia.feature", "kornia", _NEEDS_KORNIA)


def _require_torch():
    """Check, before any work, that the torch backend can run: torch and kornia import."""
    _torch()
    _kornia_feature()


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
    """The file of ``name``: an existing path, else the shipped ``.npz`` of that stem, else a file in
    :func:`weights_dir`; ``FileNotFoundError`` names the folders searched."""
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
    """SHA-1 of a weights file (of its arrays for ``.npz``) tagged with :data:`NUMPY_IMPL`, or
    ``"kornia-published"`` for ``None``."""
    if name is None:
        return "kornia-published"
    p = resolve_weights(name, what)
    st = p.stat()
    return f"{_file_sha1(str(p.resolve()), st.st_mtime_ns, st.st_size)}:{NUMPY_IMPL}"


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
    """``(architecture, parameters)`` of ``weights`` (an ``.npz``, or a ``.pth``/``.params`` read with torch)
    for :mod:`._nn`; ``net`` is the expected architecture, ``"auto"`` the one the ``.npz`` names."""
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


def _hardtfeat():
    """The torch module of HardTFeat, as its authors define it (see :func:`._nn.hardtfeat`)."""
    torch = _torch()
    nn = torch.nn

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
    torch = _torch()

    if str(path).endswith(".npz"):  # a shipped copy: the same arrays under the same names
        return {k: torch.from_numpy(v) for k, v in load_numpy_net(path, "auto")[1].items()}
    sd = torch.load(path, map_location="cpu", weights_only=False)
    return sd["state_dict"] if isinstance(sd, dict) and "state_dict" in sd else sd


def _architecture(descriptor: str, net: str) -> str:
    """The network of ``descriptor`` (``"hardnet2"``, ``"sosnet"``): ``net``, or kornia's for ``"auto"``."""
    if descriptor not in _DEFAULT_NET:
        raise ValueError(f"descriptor must be one of {tuple(_DEFAULT_NET)}, got {descriptor!r}")
    return _DEFAULT_NET[descriptor] if net == "auto" else net


@lru_cache(maxsize=8)
def _descriptor_net(descriptor: str, net: str, path: str | None):
    KF = _kornia_feature()

    arch = _architecture(descriptor, net)
    kornia_nets = {"hardnet": KF.HardNet, "sosnet": KF.SOSNet, "tfeat": KF.TFeat}
    if path is None:  # the published weights, as kornia loads them (needs network access)
        if arch not in kornia_nets:
            raise ValueError(f"net {arch!r} has no published kornia weights; give weights=")
        return kornia_nets[arch](pretrained=True).eval()
    model = _hardtfeat() if arch == "hardtfeat" else kornia_nets[arch](pretrained=False)
    sd = _state_dict(Path(path))
    if arch == "hardtfeat":  # the file also holds an unused SIFT-gradient helper
        sd = {k: v for k, v in sd.items() if k.split(".")[0] in ("features", "classifier")}
    model.load_state_dict(sd, strict=True)
    return model.eval()


def load_descriptor_net(descriptor: str, *, net: str = "auto", weights=None):
    """The torch module of ``descriptor`` (``"hardnet2"``, ``"sosnet"``) in evaluation mode, cached; ``net``
    ``"auto"``: kornia's architecture; ``weights=None``: kornia's published weights."""
    _require_torch()
    _architecture(descriptor, net)
    path = None if weights is None else str(resolve_weights(weights, "descriptor weights").resolve())
    return _descriptor_net(descriptor, net, path)


@lru_cache(maxsize=4)
def _orinet(path: str | None):
    KF = _kornia_feature()

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
    torch = _torch()

    A = np.asarray(shapes, np.float64) * float(support)
    laf = np.concatenate([A, np.asarray(kpts, np.float64)[:, :, None]], axis=2)  # (N, 2, 3) = [A | c]
    return torch.from_numpy(laf).float()[None]


def _image(gray):
    torch = _torch()

    return torch.from_numpy(np.ascontiguousarray(gray, np.float32) / 255.0)[None, None]


def _numpy_patches(gray, kpts, shapes, support: float, batch: int):
    """``(start, patches)``: the 32×32 patches of ``support × A`` (:func:`._nn.pyramid_patches`), ``batch`` at
    a time."""
    from . import _nn

    img = np.ascontiguousarray(gray, np.float32) / np.float32(255.0)
    A = np.asarray(shapes, np.float64) * float(support)
    for s in range(0, len(kpts), batch):
        yield s, _nn.pyramid_patches(img, kpts[s : s + batch], A[s : s + batch], PATCH_SIZE)


def orinet_angles(gray: np.ndarray, kpts: np.ndarray, shapes: np.ndarray, *, weights=None, support: float = 2.0,
                  batch: int = 512, backend: str = "auto") -> np.ndarray:
    """OriNet angle θ of each keypoint's patch ``support × A`` (kornia's LAFOrienter): the oriented shape is
    ``A @ R(θ)``. ``weights=None``: kornia's published ones (torch); ``backend="auto"``: numpy if ``weights``.
    """
    n = len(kpts)
    if n == 0:
        return np.empty(0)
    if _use_numpy(backend, weights, "orinet"):
        from . import _nn

        _, params = load_numpy_net(weights, "orinet")
        out = np.empty(n)
        for s, patches in _numpy_patches(gray, kpts, shapes, support, batch):
            a = _nn.orinet(params, patches).astype(np.float64)
            # kornia turns the LAF by R(-a) in our convention; fixedmath: numpy's last bit follows the CPU.
            sin, cos = fixedmath.sincos(a)
            out[s : s + batch] = fixedmath.atan2(-sin, cos)
        return out
    torch = _torch()
    KF = _kornia_feature()

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
            out[s : s + batch] = fixedmath.atan2(R[:, 1, 0], R[:, 0, 0])
    return out


def describe_patches(patches, descriptor: str, *, net: str = "auto", weights=None, batch: int = 256,
                     backend: str = "auto") -> np.ndarray:
    """Deep descriptors of ``(N, 32, 32)`` patches, unit L2 norm, float32; ``backend="auto"`` runs numpy for
    the TFeat-architecture nets with given ``weights``, torch otherwise."""
    arch = _architecture(descriptor, net)
    p = np.asarray(patches, np.float32).reshape(-1, PATCH_SIZE, PATCH_SIZE)
    out = []
    if _use_numpy(backend, weights, arch):
        from . import _nn

        _, params = load_numpy_net(weights, arch)
        for s in range(0, len(p), batch):
            out.append(_nn.NETS[arch](params, p[s : s + batch]).astype(np.float64))
    else:
        torch = _torch()

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
    """HardNet2 / SOSNet descriptors ``(N, 128)`` of the 32×32 patches covering ``support × A`` of the
    oriented shapes (kornia's LAF ``[support A | kpt]``); the other arguments as in
    :func:`load_descriptor_net` and :func:`describe_patches`."""
    n = len(kpts)
    if n == 0:
        return np.empty((0, 128), np.float32)
    arch = _architecture(descriptor, net)
    kw = dict(net=net, weights=weights, backend=backend)
    if _use_numpy(backend, weights, arch):
        return np.concatenate([describe_patches(patches, descriptor, **kw)
                               for _, patches in _numpy_patches(gray, kpts, shapes, support, batch)])
    torch = _torch()
    KF = _kornia_feature()

    img = _image(gray)
    out = []
    with torch.no_grad():
        for s in range(0, n, batch):
            laf = _lafs(kpts[s : s + batch], shapes[s : s + batch], support)
            patches = KF.extract_patches_from_pyramid(img, laf, PATCH_SIZE)[0, :, 0]
            out.append(describe_patches(patches.numpy(), descriptor, **kw))
    return np.concatenate(out)


def export_npz(source, output, net: str) -> Path:
    """Convert the published weights ``source`` of architecture ``net`` to the ``.npz`` ``output`` (torch).

    Arrays: the loaded ``state_dict``; ``__meta__`` (JSON): architecture, source name and SHA-1, licence.
    """
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
