"""OANet and ACNe inference in numpy: the default engine of the ``oanet`` and ``acne`` filters (no torch).

The layers of :mod:`.nets` on one candidate set ``(C, K)`` from the same ``state_dict``, evaluated in
float64 (input rounded to float32 as in training) so that ``logit > threshold`` does not follow the BLAS
kernel; one candidate is allowed. Weights: :func:`save_npz` / :func:`load_npz`, or :mod:`.tfbundle`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..._numerics.blas import one_blas_thread
from ..._numerics.fixedmath import exp, tanh
from .configs import ACNeConfig, OANetConfig

__all__ = ["NumpyModel", "oanet_logits", "acne_logits", "weighted_eight_point", "epipolar_residual",
           "save_npz", "load_npz", "load_numpy_model", "from_state_dict", "is_tf_checkpoint", "tf_name_map",
           "acne_params_from_tf_tensors", "oanet_config_from_state_dict", "NPZ_FORMAT"]

NPZ_FORMAT = "ctxmatch-learned-filter-npz"
_F32 = np.float32


# ------------------------------------------------------------------------------------------- layers
def _conv(p: dict, name: str, x: np.ndarray) -> np.ndarray:
    w = p[name + ".weight"]
    out = w.reshape(w.shape[0], -1) @ x
    b = p.get(name + ".bias")
    return out if b is None else out + b[:, None]


def _context_norm(x: np.ndarray, eps: float = 1e-3) -> np.ndarray:
    # Normalisation of each row, biased variance: torch's InstanceNorm2d(eps=1e-3) over the candidates.
    mean = x.mean(axis=1, keepdims=True)
    d = x - mean
    var = (d * d).mean(axis=1, keepdims=True)
    return d / np.sqrt(var + _F32(eps))


def _batch_norm(p: dict, name: str, x: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    scale = p[name + ".weight"] / np.sqrt(p[name + ".running_var"] + _F32(eps))
    shift = p[name + ".bias"] - p[name + ".running_mean"] * scale
    return x * scale[:, None] + shift[:, None]


def _relu(x):
    return np.maximum(x, _F32(0))


def _exp(x: np.ndarray) -> np.ndarray:
    """fixedmath's ``exp`` in the dtype of ``x`` (numpy's follows the CPU's SIMD loop in the last bit)."""
    return exp(x).astype(np.result_type(x, np.float32), copy=False)


def _softmax(x: np.ndarray, axis: int) -> np.ndarray:
    e = _exp(x - x.max(axis=axis, keepdims=True))
    return e / e.sum(axis=axis, keepdims=True)


def _gated(s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``s * sigmoid(x)`` without overflow (``exp(-x)`` overflows float32 below -88.7)."""
    low = x < _F32(-80)
    e = _exp(np.where(low, x, -x))
    return np.where(low, s * e, s) / (_F32(1) + e)


def _cn_bn_relu_conv(p, name, i, x):
    # Sequential (CN, BN, ReLU, conv) whose BN is module i and conv module i + 2.
    return _conv(p, f"{name}.{i + 2}", _relu(_batch_norm(p, f"{name}.{i}", _context_norm(x))))


# ---------------------------------------------------------------------------------------------- OANet
def _point_cn(p, name, x):
    skip = _conv(p, name + ".shot_cut", x) if name + ".shot_cut.weight" in p else x
    out = _cn_bn_relu_conv(p, name + ".conv", 1, x)
    return _cn_bn_relu_conv(p, name + ".conv", 5, out) + skip


def _oa_filter(p, name, x):
    out = _cn_bn_relu_conv(p, name + ".conv1", 1, x).T  # (M, C): the clusters become the channels
    # Spatial correlation layer: BN, ReLU and a 1x1 conv across the (ordered) cluster axis.
    corr = _conv(p, name + ".conv2.2", _relu(_batch_norm(p, name + ".conv2.0", out)))
    out = _cn_bn_relu_conv(p, name + ".conv3", 2, (out + corr).T)
    return out + x


def _count(p, prefix):
    return len({k[len(prefix):].split(".")[0] for k in p if k.startswith(prefix)})


def _oan_block(p, name, data):
    x1 = _conv(p, name + ".conv1", data)
    for i in range(_count(p, name + ".l1_1.")):
        x1 = _point_cn(p, f"{name}.l1_1.{i}", x1)
    S = _softmax(_cn_bn_relu_conv(p, name + ".down1.conv", 1, x1), axis=1)  # (M, K), over the candidates
    x2 = x1 @ S.T  # DiffPool (Eq. (3)): (C, M)
    for i in range(_count(p, name + ".l2.")):
        x2 = _oa_filter(p, f"{name}.l2.{i}", x2)
    S = _softmax(_cn_bn_relu_conv(p, name + ".up1.conv", 1, x1), axis=0)  # (M, K), over the clusters
    out = np.concatenate([x1, x2 @ S])  # DiffUnpool (Eq. (6))
    for i in range(_count(p, name + ".l1_2.")):
        out = _point_cn(p, f"{name}.l1_2.{i}", out)
    return _conv(p, name + ".output", out)[0]


def weighted_eight_point(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """:func:`.nets.weighted_eight_point` of one set: ``x`` (K, 4), ``weights`` (K,) -> ``F`` (3, 3), up to sign."""
    x1, y1, x2, y2 = np.asarray(x, np.float64).T
    X = np.stack([x2 * x1, x2 * y1, x2, y2 * x1, y2 * y1, y2, x1, y1, np.ones_like(x1)], axis=1)
    XwX = X.T @ (np.asarray(weights, np.float64)[:, None] * X)
    F = np.linalg.eigh(XwX)[1][:, 0].reshape(3, 3)
    return F / max(np.linalg.norm(F), 1e-12)


def epipolar_residual(x: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Squared symmetric epipolar distance of each correspondence, shape ``(K,)`` (float64)."""
    x = np.asarray(x, np.float64)
    one = np.ones((len(x), 1))
    p1 = np.concatenate([x[:, :2], one], 1)
    p2 = np.concatenate([x[:, 2:4], one], 1)
    Fx1 = p1 @ F.T
    Ftx2 = p2 @ F
    num = np.einsum("ij,ij->i", p2, Fx1) ** 2
    d1 = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2
    d2 = Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return num * (1.0 / np.maximum(d1, 1e-15) + 1.0 / np.maximum(d2, 1e-15))


def oanet_logits(params: dict, x: np.ndarray) -> list[np.ndarray]:
    """Logits of every OANet stage (the last is the answer) for the input ``x`` of shape ``(C_in, K)``."""
    data = np.asarray(x, _F32)
    logits = [_oan_block(params, "weights_init", data)]
    for k in range(_count(params, "weights_iter.")):
        w = np.maximum(tanh(logits[-1]), 0)
        res = epipolar_residual(data[:4].T, weighted_eight_point(data[:4].T, w)).astype(_F32)
        logits.append(_oan_block(params, f"weights_iter.{k}", np.concatenate([data, res[None], w[None]])))
    return logits


# ----------------------------------------------------------------------------------------------- ACNe
def _group_norm(p, name, x, groups):
    out = _context_norm(x.reshape(groups, -1), eps=1e-5).reshape(x.shape)
    return out * p[name + ".weight"][:, None] + p[name + ".bias"][:, None]


def _acn_layer(p, name, x, groups):
    x = _conv(p, name + ".conv", x)
    a = _conv(p, name + ".acn.attn", x)  # row 0: global (softmax) logit, row 1: local (sigmoid) logit
    w = _gated(_softmax(a[0], axis=0), a[1])  # Eq. (5)-(7): global softmax times local sigmoid
    w = w / max(w.sum(), _F32(1e-30))
    mean = x @ w
    d = x - mean[:, None]
    var = (d * d) @ w
    out = d / np.sqrt(var + _F32(1e-3))[:, None]
    return _relu(_group_norm(p, name + ".norm", out, min(groups, x.shape[0])))


def acne_logits(params: dict, x: np.ndarray, *, groups: int) -> np.ndarray:
    """ACNe's inlier logits, shape ``(K,)``, for the input ``x`` of shape ``(C_in, K)``."""
    out = _conv(params, "input", np.asarray(x, _F32))
    for i in range(_count(params, "blocks.")):
        y = out
        for j in range(_count(params, f"blocks.{i}.layers.")):
            y = _acn_layer(params, f"blocks.{i}.layers.{j}", y, groups)
        out = y + out
    return _conv(params, "output", out)[0]


# --------------------------------------------------------------------------------------------- models
@dataclass
class NumpyModel:
    """A network's parameters (torch ``state_dict`` names, float32 arrays) and how to feed it."""

    arch: str  # "oanet" or "acne"
    config: dict  # the OANetConfig / ACNeConfig fields
    params: dict  # name -> float32 ndarray
    normalization: str  # "image" or "hartley"
    side: str  # "none", "score_rank" or "ratio_mutual"
    label: str
    source: str

    def logits(self, x: np.ndarray) -> np.ndarray:
        """Inlier logits ``(K,)`` of the input ``(C_in, K)``, in float64 on one BLAS thread."""
        params = self._float64_params()
        with one_blas_thread():
            if self.arch == "oanet":
                return oanet_logits(params, x)[-1]
            return acne_logits(params, x, groups=int(self.config.get("groups", 32)))

    def _float64_params(self) -> dict:
        cached = self.__dict__.get("_params64")
        if cached is None or cached[0] is not self.params:
            cached = (self.params, {k: np.asarray(v, np.float64) for k, v in self.params.items()})
            self.__dict__["_params64"] = cached
        return cached[1]


def _float_params(sd: dict) -> dict:
    # num_batches_tracked and other integer buffers play no part in inference.
    return {k: np.ascontiguousarray(np.asarray(v), dtype=_F32) for k, v in sd.items()
            if np.issubdtype(np.asarray(v).dtype, np.floating)}


def save_npz(path, arch: str, config: dict, params: dict, *, normalization: str, side: str, label: str,
             training: dict | None = None) -> Path:
    """Write a network in the ctxmatch ``.npz`` format: the arrays, and ``__meta__`` (JSON) saying what they are."""
    from ...cache import atomic_path

    meta = {"format": NPZ_FORMAT, "version": 1, "arch": arch, "config": config,
            "input": {"normalization": normalization, "side": side}, "label": label, "training": training or {}}
    arrays = {k: np.asarray(v, _F32) for k, v in _float_params(params).items()}
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, __meta__=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return path


def load_npz(arch: str, path) -> NumpyModel:
    """Read a network written by :func:`save_npz` (``ValueError`` if it is not one, or not ``arch``)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["__meta__"])) if "__meta__" in z.files else {}
            params = {k: z[k] for k in z.files if k != "__meta__"}
    except (OSError, ValueError) as e:
        raise ValueError(f"weights {path} is not a readable .npz file: {e}") from e
    if meta.get("format") != NPZ_FORMAT:
        raise ValueError(f"weights {path} is not a ctxmatch learned-filter .npz (no {NPZ_FORMAT!r} __meta__)")
    if meta.get("arch") != arch:
        raise ValueError(f"weights {path} hold a {meta.get('arch')!r} network, not {arch!r}")
    inp = meta.get("input", {})
    return NumpyModel(arch, dict(meta.get("config", {})), _float_params(params), inp.get("normalization", "image"),
                      inp.get("side", "none"), meta.get("label", f"{arch} (trained here)"), str(path))


def oanet_config_from_state_dict(sd: dict) -> OANetConfig:
    """The :class:`~.configs.OANetConfig` of an OANet ``state_dict`` (authors' or ours), from its shapes."""
    try:
        w = sd["weights_init.conv1.weight"]
        clusters = sd["weights_init.down1.conv.3.weight"].shape[0]
    except KeyError as e:
        raise ValueError(f"weights are not an OANet state_dict (missing {e.args[0]!r})") from None
    half = _count(sd, "weights_init.l1_1.")
    iters = _count(sd, "weights_iter.")
    return OANetConfig(net_channels=int(w.shape[0]), net_depth=2 * half * (iters + 1), clusters=int(clusters),
                       iter_num=iters, side_channels=int(w.shape[1]) - 4)


# ------------------------------------------------------------------------------------------ ACNe / TF
def tf_name_map(config: ACNeConfig) -> dict[str, tuple[str, str]]:
    """TF variable of the ACNe release -> (torch parameter name, kind), kind ``'conv'`` or ``'vec'``."""
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


def acne_params_from_tf_tensors(tensors: dict[str, np.ndarray], *, groups: int = 32) -> tuple[ACNeConfig, dict]:
    """The config and the parameters (torch names, conv kernels ``(out, in, 1)``) of an ACNe TF checkpoint."""
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
    params = {}
    for tf_name, (pt_name, kind) in tf_name_map(config).items():
        if tf_name not in tensors:
            raise ValueError(f"ACNe TensorFlow checkpoint lacks variable {tf_name!r}")
        arr = np.asarray(tensors[tf_name], _F32)
        if kind == "conv":  # [1, 1, in, out] -> (out, in, 1)
            arr = arr.reshape(arr.shape[-2], arr.shape[-1]).T[:, :, None]
        params[pt_name] = np.ascontiguousarray(arr)
    return config, params


def is_tf_checkpoint(path: Path) -> bool:
    """Whether ``path`` names a TensorFlow checkpoint (a folder with an ``.index``, a prefix, or one of its files)."""
    path = Path(path)
    if path.is_dir():
        return any(path.glob("*.index"))
    return path.name.endswith(".index") or ".data-" in path.name or path.with_name(path.name + ".index").is_file()


def from_state_dict(arch: str, config: dict, sd: dict, *, normalization: str, side: str, label: str,
                    source: str) -> NumpyModel:
    """A :class:`NumpyModel` from a ``state_dict`` of numpy arrays (or anything ``np.asarray`` reads)."""
    return NumpyModel(arch, dict(config), _float_params(sd), normalization, side, label, source)


def load_numpy_model(arch: str, weights) -> NumpyModel:
    """The :class:`NumpyModel` of a ctxmatch ``.npz`` or an ACNe authors' TensorFlow checkpoint.

    ``FileNotFoundError`` if ``weights`` does not exist, ``ValueError`` if it is no such checkpoint of ``arch``.
    """
    from .tfbundle import read_tf_checkpoint

    if arch not in ("oanet", "acne"):
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    path = Path(weights)
    if arch == "acne" and is_tf_checkpoint(path):
        config, params = acne_params_from_tf_tensors(read_tf_checkpoint(path))
        return NumpyModel("acne", config.to_dict(), params, "hartley", "none", "ACNe (authors' weights)", str(path))
    if not path.exists():
        raise FileNotFoundError(f"weights not found: {path}")
    if path.is_dir():
        raise ValueError(f"weights must be a checkpoint file, got the folder {path}")
    return load_npz(arch, path)
