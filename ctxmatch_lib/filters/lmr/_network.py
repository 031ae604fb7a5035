"""The authors' LMR network (``Trained_Model/Net.mat``, from a user's checkout of StaRainJ/LMR) in NumPy,
and the exact ``MPC.m`` values it reads, for ``lmr_filter(..., network=PATH)``.

Only feed-forward chains are evaluated: ``a_1 = f_1(IW{1,1} x + b{1})``, ``a_l = f_l(LW{l,l-1} a_(l-1) + b{l})``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..._numerics.fixedmath import atan, exp

#: Transfer functions of the Deep Learning Toolbox, by their documented definitions (the exponential is
#: ``_fixedmath``'s, the same bits on any CPU: the outputs are compared with each other).
TRANSFER = {
    "tansig": lambda n: 2.0 / (1.0 + exp(-2.0 * n)) - 1.0,
    "logsig": lambda n: 1.0 / (1.0 + exp(-n)),
    "purelin": lambda n: n,
}

#: ``gaussmf`` parameters ``[sigma c]`` of ``MPC.m``: length ratio and angle consistency.
LENGTH_GAUSSMF = (0.4, 1.0)
ANGLE_GAUSSMF = (0.8, 0.0)
#: The shift ``dv`` that ``MPC.m`` adds to the motion vectors.
MPC_DV = 1e-7


def gaussmf(x: np.ndarray, sigma: float, c: float) -> np.ndarray:
    """MATLAB's ``gaussmf(x, [sigma c])`` = ``exp(-(x - c)^2 / (2 sigma^2))`` (NaN stays NaN)."""
    return exp(-((x - c) ** 2) / (2.0 * sigma**2))


def mpc_motion(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Squared motion length ``d2`` and direction ``theta`` in [0, 2 pi) of every match, as ``MPC.m``.

    ``vec = y - x + dv``, ``theta = atan((vec_y + dv) / (vec_x + dv))`` plus ``MPC.m``'s quadrant rules.
    """
    vec = (y - x) + MPC_DV
    d2 = vec[:, 0] ** 2 + vec[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (vec[:, 1] + MPC_DV) / (vec[:, 0] + MPC_DV)
    theta = atan(ratio)
    below = vec[:, 1] <= 0
    q3 = (theta >= 0) & below
    theta[q3] += np.pi
    q4 = (theta <= 0) & below
    theta[q4] += 2 * np.pi
    q2 = (theta <= 0) & ~below
    theta[q2] += np.pi
    return d2, theta


@dataclass(frozen=True)
class LMRNetwork:
    """A feed-forward network: per layer a weight matrix (out, in), a bias (out,) and a transfer name."""

    weights: tuple
    biases: tuple
    transfers: tuple

    @property
    def n_inputs(self) -> int:
        return self.weights[0].shape[1]

    def forward(self, feats: np.ndarray) -> np.ndarray:
        """The network's outputs for every row of ``feats`` (K, n_inputs) -> (K, n_outputs)."""
        a = np.asarray(feats, np.float64).T
        for w, b, f in zip(self.weights, self.biases, self.transfers):
            a = TRANSFER[f](w @ a + b[:, None])
        return a.T


def _field(obj, name: str, arg: str):
    try:
        return obj[name]
    except (KeyError, ValueError, IndexError, TypeError):
        raise ValueError(f"{arg}: the network has no field {name!r}") from None


def _unwrap(v):
    """Strip scipy's (1, 1) object / struct wrappers."""
    while isinstance(v, np.ndarray) and v.dtype == object and v.size == 1:
        v = v.reshape(-1)[0]
    if isinstance(v, np.ndarray) and v.dtype.names is not None and v.size == 1:
        v = v.reshape(-1)[0]
    return v


def _text(v) -> str:
    v = _unwrap(v)
    if isinstance(v, np.ndarray):
        return "".join(str(s) for s in v.reshape(-1))
    return str(v)


def _cells(v) -> list:
    """A cell array's elements (row-major over its shape), each unwrapped; empty cells as None."""
    v = np.asarray(v, dtype=object) if not isinstance(v, np.ndarray) else v
    out = []
    for e in v.reshape(-1) if v.dtype == object else [v]:
        e = _unwrap(e)
        out.append(None if isinstance(e, np.ndarray) and e.size == 0 else e)
    return out


def _matrix(v, arg: str, what: str) -> np.ndarray:
    try:
        m = np.asarray(v, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{arg}: {what} is not a numeric array") from None
    if m.ndim != 2 or not np.isfinite(m).all():
        raise ValueError(f"{arg}: {what} must be a finite 2-D array, got shape {m.shape}")
    return m


def parse_network(net, arg: str = "network") -> LMRNetwork:
    """An :class:`LMRNetwork` from a network as :func:`scipy.io.loadmat` returns it; ``ValueError`` naming
    ``arg`` for anything but a feed-forward chain of known transfer functions with consistent shapes."""
    net = _unwrap(net)
    ports = _cells(_field(net, "inputs", arg)) + _cells(_field(net, "outputs", arg))
    for port in ports:
        if port is not None and any(f is not None for f in _cells(_field(port, "processFcns", arg))):
            raise ValueError(f"{arg}: the network has input or output processing functions (processFcns), "
                             "which are not supported")
    layers = [p for p in _cells(_field(net, "layers", arg)) if p is not None]
    n = len(layers)
    iw = np.asarray(_field(net, "IW", arg), dtype=object).reshape(n, -1) if n else None
    lw = np.asarray(_field(net, "LW", arg), dtype=object).reshape(n, n) if n else None
    bs = _cells(_field(net, "b", arg))
    if n == 0 or len(bs) != n or iw.shape[1] != 1:
        raise ValueError(f"{arg}: expected one input and as many biases as layers, got {n} layer(s), "
                         f"{len(bs)} bias(es)")
    weights, biases, transfers = [], [], []
    for l, layer in enumerate(layers):
        f = _text(_field(layer, "transferFcn", arg))
        if f not in TRANSFER:
            raise ValueError(f"{arg}: layer {l + 1} has transfer function {f!r}; supported: {sorted(TRANSFER)}")
        links = [(j, _unwrap(lw[l, j])) for j in range(n)]
        links = [j for j, w in links if not (isinstance(w, np.ndarray) and w.size == 0)]
        extra_in = l > 0 and np.asarray(iw[l, 0]).size > 0
        if extra_in or links != ([] if l == 0 else [l - 1]):
            raise ValueError(f"{arg}: layer {l + 1} is not fed by the layer before only (not a feed-forward chain)")
        w = _matrix(_unwrap(iw[0, 0]) if l == 0 else _unwrap(lw[l, l - 1]), arg, f"the weights of layer {l + 1}")
        b = _matrix(np.reshape(bs[l], (-1, 1)), arg, f"the bias of layer {l + 1}").reshape(-1)
        if (l > 0 and w.shape[1] != weights[-1].shape[0]) or len(b) != w.shape[0]:
            raise ValueError(f"{arg}: layer {l + 1}: weights {w.shape} and bias ({len(b)},) do not chain")
        weights.append(w)
        biases.append(b)
        transfers.append(f)
    return LMRNetwork(tuple(weights), tuple(biases), tuple(transfers))


def load_network(path, n_inputs: int, arg: str = "network") -> LMRNetwork:
    """The network ``net`` of the ``.mat`` file ``path`` (cached), checked for ``n_inputs`` inputs, 2 outputs."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise ValueError(f"{arg}: no such file {str(path)!r} (the authors' Trained_Model/Net.mat)")
    st = p.stat()
    net = _load_resolved(str(p.resolve()), st.st_mtime_ns, st.st_size, arg)
    if net.n_inputs != n_inputs or net.weights[-1].shape[0] != 2:
        raise ValueError(f"{arg}: the network maps {net.n_inputs} inputs to {net.weights[-1].shape[0]} outputs; "
                         f"LMR needs {n_inputs} inputs (the MPC features) and 2 outputs")
    return net


@lru_cache(maxsize=4)
def _load_resolved(path: str, mtime_ns: int, size: int, arg: str) -> LMRNetwork:
    from scipy.io import loadmat

    try:
        mat = loadmat(path)
    except Exception as err:  # scipy raises several types for a file that is not a .mat
        raise ValueError(f"{arg}: cannot read {path!r} as a MATLAB .mat file ({err})") from None
    if "net" not in mat:
        raise ValueError(f"{arg}: {path!r} holds no variable 'net'")
    return parse_network(mat["net"], arg)
