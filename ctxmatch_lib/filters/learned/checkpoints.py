"""Loading and saving the learned filters' weights (imports torch: reach it through the lazy public face).

:func:`load_model` reads the ctxmatch ``.npz`` (:func:`.npnets.save_npz`) and ``.pt`` (a ``torch.save``
dict with ``"format": FORMAT``), the OANet release's ``model_best.pth`` or bare ``state_dict`` (input
``"hartley"``, side ``"ratio_mutual"`` with side information) and the ACNe release's TensorFlow checkpoint
(:mod:`.tfbundle`; released configuration only). :func:`convert_to_npz` (``python -m
ctxmatch_lib.filters.learned.checkpoints ARCH WEIGHTS OUT.npz``) writes the ``.npz`` read without torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..._numerics.extras import require
from .configs import ACNeConfig, OANetConfig  # noqa: F401  (re-exported)
from .nets import ACNe, OANet, build_network
from .npnets import (acne_params_from_tf_tensors, is_tf_checkpoint, load_numpy_model, oanet_config_from_state_dict,
                     save_npz, tf_name_map)
from .tfbundle import read_tf_checkpoint, write_tf_checkpoint

torch = require("torch", "torch", "reading or writing a torch checkpoint of the learned filters")

__all__ = ["LoadedModel", "load_model", "save_model", "convert_to_npz", "oanet_config_from_state_dict",
           "acne_from_tf_tensors", "acne_to_tf_tensors", "FORMAT"]

FORMAT = "ctxmatch-learned-filter"


@dataclass
class LoadedModel:
    """A network ready for inference and how to feed it."""

    arch: str  # "oanet" or "acne"
    net: torch.nn.Module
    normalization: str  # "image" or "hartley"
    side: str  # "none", "score_rank" or "ratio_mutual"
    label: str  # provenance shown in figures, e.g. "OANet (trained here)"
    source: str  # the file it came from


def _numpy_state_dict(net: torch.nn.Module) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy() for k, v in net.state_dict().items()}


# ------------------------------------------------------------------------------------------- ACNe / TF
def acne_from_tf_tensors(tensors: dict[str, np.ndarray], *, groups: int = 32) -> ACNe:
    """An :class:`~.nets.ACNe` holding the variables of an ACNe TensorFlow checkpoint."""
    config, params = acne_params_from_tf_tensors(tensors, groups=groups)
    net = ACNe(config)
    sd = net.state_dict()
    new = {}
    for name, arr in params.items():
        if tuple(arr.shape) != tuple(sd[name].shape):
            raise ValueError(f"ACNe parameter {name!r} has shape {arr.shape}, expected {tuple(sd[name].shape)}")
        new[name] = torch.from_numpy(arr)
    net.load_state_dict(new, strict=True)
    return net


def acne_to_tf_tensors(net: ACNe) -> dict[str, np.ndarray]:
    """The variables of an ACNe TensorFlow checkpoint holding ``net``'s weights (inverse of the above)."""
    sd = _numpy_state_dict(net)
    out = {}
    for tf_name, (pt_name, kind) in tf_name_map(net.config).items():
        arr = sd[pt_name].astype(np.float32)
        if kind == "conv":
            arr = arr[:, :, 0].T[None, None]
        out[tf_name] = np.ascontiguousarray(arr)
    return out


# ----------------------------------------------------------------------------------------------- API
def save_model(path, arch: str, net: torch.nn.Module, *, training: dict | None = None,
               normalization: str = "image", side: str | None = None) -> Path:
    """Save ``net`` labelled "trained here" (``.npz``: :func:`.npnets.save_npz`, else ``torch.save``)."""
    from ...cache import atomic_path

    if side is None:
        side = "score_rank" if getattr(net.config, "side_channels", 0) == 1 else "none"
    label = f"{'OANet' if arch == 'oanet' else 'ACNe'} (trained here)"
    path = Path(path)
    if path.suffix == ".npz":
        return save_npz(path, arch, net.config.to_dict(), _numpy_state_dict(net), normalization=normalization,
                        side=side, label=label, training=training)
    payload = {
        "format": FORMAT,
        "version": 1,
        "arch": arch,
        "config": net.config.to_dict(),
        "state_dict": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
        "input": {"normalization": normalization, "side": side},
        "label": label,
        "training": training or {},
    }
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def convert_to_npz(arch: str, weights, output) -> Path:
    """Convert a checkpoint :func:`load_model` reads to the ``.npz`` read without torch, metadata kept."""
    m = load_model(arch, weights)
    training = {}
    if Path(weights).suffix != ".npz" and not is_tf_checkpoint(Path(weights)):
        ckpt = torch.load(weights, map_location="cpu", weights_only=True)
        training = ckpt.get("training", {}) if isinstance(ckpt, dict) else {}
    return save_npz(output, arch, m.net.config.to_dict(), _numpy_state_dict(m.net), normalization=m.normalization,
                    side=m.side, label=m.label, training=training)


def load_model(arch: str, weights) -> LoadedModel:
    """Load the network ``arch`` ("oanet" or "acne") from ``weights`` in any supported format.

    ``FileNotFoundError`` if ``weights`` does not exist, ``ValueError`` if it is no checkpoint of ``arch``.
    """
    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    path = Path(weights)
    if arch == "acne" and is_tf_checkpoint(path):
        net = acne_from_tf_tensors(read_tf_checkpoint(path))
        net.eval()
        return LoadedModel("acne", net, "hartley", "none", "ACNe (authors' weights)", str(path))
    if path.suffix == ".npz" or not path.is_file():  # the numpy loader's checks: missing file, folder
        nm = load_numpy_model(arch, path)
        net = build_network(arch, nm.config)
        net.load_state_dict({**net.state_dict(), **{k: torch.from_numpy(v) for k, v in nm.params.items()}},
                            strict=True)
        net.eval()
        return LoadedModel(arch, net, nm.normalization, nm.side, nm.label, nm.source)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # a pickle that is not a torch checkpoint, a truncated file, …
        raise ValueError(f"weights {path} is not a readable torch checkpoint: {e}") from e
    if not isinstance(ckpt, dict):
        raise ValueError(f"weights {path} must hold a dict, got {type(ckpt).__name__}")
    if ckpt.get("format") == FORMAT:
        if ckpt.get("arch") != arch:
            raise ValueError(f"weights {path} hold a {ckpt.get('arch')!r} network, not {arch!r}")
        net = build_network(arch, ckpt["config"])
        net.load_state_dict(ckpt["state_dict"], strict=True)
        net.eval()
        inp = ckpt.get("input", {})
        return LoadedModel(arch, net, inp.get("normalization", "image"), inp.get("side", "none"),
                           ckpt.get("label", f"{arch} (trained here)"), str(path))
    if arch == "acne":
        raise ValueError(f"weights {path}: ACNe weights must be a TensorFlow checkpoint of the authors' release or "
                         "a ctxmatch checkpoint")
    sd = ckpt.get("state_dict", ckpt)
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ValueError(f"weights {path} hold no OANet state_dict")
    sd = {k.removeprefix("module."): v for k, v in sd.items()}
    config = oanet_config_from_state_dict(sd)
    net = OANet(config)
    try:
        net.load_state_dict(sd, strict=True)
    except RuntimeError as e:
        raise ValueError(f"weights {path} do not match the OANet layout: {e}") from e
    net.eval()
    side = {0: "none", 2: "ratio_mutual"}.get(config.side_channels)
    if side is None:
        raise ValueError(f"weights {path}: OANet with {config.side_channels} side channels is not a released layout")
    return LoadedModel("oanet", net, "hartley", side, "OANet (authors' weights)", str(path))


def export_acne_tf(path, net: ACNe) -> Path:
    """Write ``net`` as an ACNe TensorFlow checkpoint at prefix ``path`` (for TensorFlow users and tests)."""
    return write_tf_checkpoint(path, acne_to_tf_tensors(net))


if __name__ == "__main__":  # python -m ctxmatch_lib.filters.learned.checkpoints ARCH WEIGHTS OUTPUT.npz
    import sys

    if len(sys.argv) != 4 or not sys.argv[3].endswith(".npz"):
        sys.exit("usage: python -m ctxmatch_lib.filters.learned.checkpoints {oanet,acne} WEIGHTS OUTPUT.npz")
    print(convert_to_npz(sys.argv[1], sys.argv[2], sys.argv[3]))
