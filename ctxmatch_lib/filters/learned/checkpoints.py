"""Loading and saving the learned filters' weights (imports torch: reach it through the lazy public face).

Three formats are read by :func:`load_model`:

* **ctxmatch** (the weights trained here, ``weights/{oanet,acne}_trained_here.pt``): a ``torch.save`` dict
  ``{"format": "ctxmatch-learned-filter", "version": 1, "arch", "config", "state_dict", "input",
  "label", "training"}``; ``input`` says how coordinates are normalised and which side channels follow.
* **OANet release** (zjhthu/OANet, PyTorch): ``torch.save({"epoch", "state_dict", "best_acc",
  "optimizer"})`` of ``OANet`` (``model_best.pth``), or a bare ``state_dict``; the network shape (channels,
  depth, clusters, iterations, side channels) is read off the parameter shapes. Their demo normalises each
  image's keypoints to zero mean and mean distance sqrt(2) (``normalization="hartley"``) and, with side
  information, feeds the ratio-test value and the mutual-check flag (``side="ratio_mutual"``).
* **ACNe release** (vcg-uvic/acne, TensorFlow 1): a ``tf.train.Saver`` checkpoint (prefix, ``.index`` file
  or folder), read by :mod:`.tfbundle` without TensorFlow; variables under ``Matchnet/`` are mapped onto
  :class:`~.nets.ACNe` (TensorFlow conv kernels ``[1, 1, in, out]`` become ``(out, in, 1)``). Only the
  released configuration (group normalisation, no extra output non-linearity) is supported.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .nets import ACNe, ACNeConfig, OANet, OANetConfig, build_network
from .tfbundle import read_tf_checkpoint, write_tf_checkpoint

__all__ = ["LoadedModel", "load_model", "save_model", "oanet_config_from_state_dict", "acne_from_tf_tensors",
           "acne_to_tf_tensors", "FORMAT"]

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


def _strip_module(sd: dict) -> dict:
    return {k[len("module."):] if k.startswith("module.") else k: v for k, v in sd.items()}


def oanet_config_from_state_dict(sd: dict) -> OANetConfig:
    """The :class:`~.nets.OANetConfig` of an OANet ``state_dict`` (authors' or ours), from its shapes."""
    try:
        w = sd["weights_init.conv1.weight"]
        clusters = sd["weights_init.down1.conv.3.weight"].shape[0]
    except KeyError as e:
        raise ValueError(f"weights are not an OANet state_dict (missing {e.args[0]!r})") from None
    half = len({k.split(".")[2] for k in sd if k.startswith("weights_init.l1_1.")})
    iters = len({k.split(".")[1] for k in sd if k.startswith("weights_iter.")})
    return OANetConfig(net_channels=int(w.shape[0]), net_depth=2 * half * (iters + 1), clusters=int(clusters),
                       iter_num=iters, side_channels=int(w.shape[1]) - 4)


def _as_tensor_sd(sd: dict) -> dict:
    return {k: torch.as_tensor(v) for k, v in sd.items()}


# ------------------------------------------------------------------------------------------- ACNe / TF
def _tf_name_map(config: ACNeConfig) -> dict[str, tuple[str, str]]:
    """TF variable -> (torch parameter, kind) where kind is 'conv' or 'vec'."""
    m = {
        "Matchnet/hidden-input/self-conv/weights": ("input.weight", "conv"),
        "Matchnet/hidden-input/self-conv/biases": ("input.bias", "vec"),
        "Matchnet/logit_softmax/self-conv/weights": ("logit_softmax.weight", "conv"),
        "Matchnet/logit_softmax/self-conv/biases": ("logit_softmax.bias", "vec"),
        "Matchnet/output/self-conv/weights": ("output.weight", "conv"),
        "Matchnet/output/self-conv/biases": ("output.bias", "vec"),
    }
    for i in range(config.net_depth):
        for j in range(config.num_inner):
            tf = f"Matchnet/hidden-{i}/conv-branch/conv{j + 1}"
            pt = f"blocks.{i}.layers.{j}"
            m[f"{tf}/self-conv/weights"] = (f"{pt}.conv.weight", "conv")
            m[f"{tf}/self-conv/biases"] = (f"{pt}.conv.bias", "vec")
            m[f"{tf}/reweight/weights"] = (f"{pt}.acn.attn.weight", "conv")
            m[f"{tf}/reweight/biases"] = (f"{pt}.acn.attn.bias", "vec")
            m[f"{tf}/gn_norm/gamma"] = (f"{pt}.norm.weight", "vec")
            m[f"{tf}/gn_norm/beta"] = (f"{pt}.norm.bias", "vec")
    return m


def acne_from_tf_tensors(tensors: dict[str, np.ndarray], *, groups: int = 32) -> ACNe:
    """An :class:`~.nets.ACNe` holding the variables of an ACNe TensorFlow checkpoint."""
    try:
        w_in = tensors["Matchnet/hidden-input/self-conv/weights"]
    except KeyError:
        raise ValueError("weights are not an ACNe TensorFlow checkpoint (no Matchnet/hidden-input/self-conv/"
                         "weights variable)") from None
    if any(re.search(r"/(bn|bn_norm)/", k) for k in tensors) or any("Matchnet/nonlinearity/" in k for k in tensors):
        raise ValueError("ACNe checkpoint uses batch normalisation or the output non-linearity; only the released "
                         "configuration (bn_opt=gn, nonlinearity_output=False) is supported")
    depth = len({m.group(1) for k in tensors if (m := re.match(r"Matchnet/hidden-(\d+)/", k))})
    inner = len({m.group(1) for k in tensors if (m := re.match(r"Matchnet/hidden-0/conv-branch/conv(\d+)/", k))})
    config = ACNeConfig(net_channels=int(w_in.shape[3]), net_depth=depth, num_inner=inner, groups=groups,
                        side_channels=int(w_in.shape[2]) - 4)
    net = ACNe(config)
    sd = net.state_dict()
    new = {}
    for tf_name, (pt_name, kind) in _tf_name_map(config).items():
        if tf_name not in tensors:
            raise ValueError(f"ACNe TensorFlow checkpoint lacks variable {tf_name!r}")
        arr = np.asarray(tensors[tf_name], np.float32)
        if kind == "conv":  # [1, 1, in, out] -> (out, in, 1)
            arr = arr.reshape(arr.shape[-2], arr.shape[-1]).T[:, :, None]
        if tuple(arr.shape) != tuple(sd[pt_name].shape):
            raise ValueError(f"ACNe variable {tf_name!r} has shape {arr.shape}, expected {tuple(sd[pt_name].shape)}")
        new[pt_name] = torch.from_numpy(np.ascontiguousarray(arr))
    net.load_state_dict(new, strict=True)
    return net


def acne_to_tf_tensors(net: ACNe) -> dict[str, np.ndarray]:
    """The variables of an ACNe TensorFlow checkpoint holding ``net``'s weights (inverse of the above)."""
    sd = {k: v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    out = {}
    for tf_name, (pt_name, kind) in _tf_name_map(net.config).items():
        arr = sd[pt_name].astype(np.float32)
        if kind == "conv":
            arr = arr[:, :, 0].T[None, None]
        out[tf_name] = np.ascontiguousarray(arr)
    return out


# ----------------------------------------------------------------------------------------------- API
def save_model(path, arch: str, net: torch.nn.Module, *, training: dict | None = None,
               normalization: str = "image", side: str | None = None) -> Path:
    """Save ``net`` in the ctxmatch format (labelled "trained here"); returns the path."""
    from ..._paths import atomic_path

    if side is None:
        side = "score_rank" if getattr(net.config, "side_channels", 0) == 1 else "none"
    payload = {
        "format": FORMAT,
        "version": 1,
        "arch": arch,
        "config": net.config.to_dict(),
        "state_dict": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
        "input": {"normalization": normalization, "side": side},
        "label": f"{'OANet' if arch == 'oanet' else 'ACNe'} (trained here)",
        "training": training or {},
    }
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
        # The temporary file is created private (0600); give the result the permissions the umask allows.
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
    return path


def _is_tf_checkpoint(path: Path) -> bool:
    if path.is_dir():
        return any(path.glob("*.index"))
    return path.name.endswith(".index") or ".data-" in path.name or path.with_name(path.name + ".index").is_file()


def load_model(arch: str, weights) -> LoadedModel:
    """Load the network ``arch`` ("oanet" or "acne") from ``weights`` in any supported format.

    Raises
    ------
    FileNotFoundError
        ``weights`` does not exist.
    ValueError
        The file is not a checkpoint of ``arch`` in a supported format.
    """
    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    path = Path(weights)
    if arch == "acne" and _is_tf_checkpoint(path):
        net = acne_from_tf_tensors(read_tf_checkpoint(path))
        net.eval()
        return LoadedModel("acne", net, "hartley", "none", "ACNe (authors' weights)", str(path))
    if not path.exists():
        raise FileNotFoundError(f"weights not found: {path}")
    if path.is_dir():
        raise ValueError(f"weights must be a checkpoint file, got the folder {path}")
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
    sd = _strip_module(sd)
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
