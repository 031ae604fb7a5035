"""The OANet and ACNe networks as torch modules (imports torch: load it through the lazy public face).

Input ``(B, 4 + side, N)`` (normalised x1, y1, x2, y2, side channels), output inlier logits ``(B, N)``.
:class:`OANet` (Zhang et al., ICCV 2019, Sec. 3-4), named as the authors' release so their ``state_dict``
loads; :class:`ACNe` (Sun et al., CVPR 2020, Sec. 3-4).
"""

from __future__ import annotations

from ..._numerics.extras import require
from .configs import ACNeConfig, OANetConfig

torch = require("torch", "torch", "defining the learned filters' torch networks")
nn = torch.nn

__all__ = ["OANetConfig", "ACNeConfig", "OANet", "ACNe", "weighted_eight_point", "epipolar_residual",
           "build_network"]


# --------------------------------------------------------------------------------------------- geometry
def weighted_eight_point(x: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Weighted eight-point estimate (OANet Eq. (9)): unit-norm ``F`` (B, 3, 3), float64, minimising
    ``sum_i w_i (x2_i^T F x1_i)^2`` for ``x`` (B, N, 4) and ``weights`` (B, N)."""
    x = x.double()
    x1, y1, x2, y2 = x.unbind(-1)
    one = torch.ones_like(x1)
    X = torch.stack([x2 * x1, x2 * y1, x2, y2 * x1, y2 * y1, y2, x1, y1, one], dim=-1)  # (B, N, 9)
    XwX = X.transpose(1, 2) @ (weights.double().unsqueeze(-1) * X)
    _, vecs = torch.linalg.eigh(XwX)
    F = vecs[..., 0].reshape(-1, 3, 3)
    return F / F.flatten(1).norm(dim=1).clamp_min(1e-12)[:, None, None]


def epipolar_residual(x: torch.Tensor, F: torch.Tensor) -> torch.Tensor:
    """Squared symmetric epipolar distance ``(B, N)``: ``(x2' F x1)^2 (1 / |(F x1)_12|^2 + 1 / |(F' x2)_12|^2)``."""
    x = x.double()
    F = F.double()
    one = torch.ones_like(x[..., :1])
    p1 = torch.cat([x[..., :2], one], -1)  # (B, N, 3)
    p2 = torch.cat([x[..., 2:4], one], -1)
    Fx1 = p1 @ F.transpose(1, 2)  # rows: F @ p1
    Ftx2 = p2 @ F
    num = (p2 * Fx1).sum(-1) ** 2
    d1 = Fx1[..., 0] ** 2 + Fx1[..., 1] ** 2
    d2 = Ftx2[..., 0] ** 2 + Ftx2[..., 1] ** 2
    return num * (1.0 / d1.clamp_min(1e-15) + 1.0 / d2.clamp_min(1e-15))


# ---------------------------------------------------------------------------------------------- OANet
def _cn_bn_relu(channels: int) -> list[nn.Module]:
    # Context normalisation (instance norm over the correspondences, Yi et al. CVPR 2018) then batch norm.
    return [nn.InstanceNorm2d(channels, eps=1e-3), nn.BatchNorm2d(channels), nn.ReLU()]


class _Swap12(nn.Module):
    """Swap the channel and the point axes: (B, C, M, 1) <-> (B, M, C, 1)."""

    def forward(self, x):
        return x.transpose(1, 2)


class PointCN(nn.Module):
    """Residual (CN, BN, ReLU, 1x1 conv) x 2 on (B, C, N, 1) features."""

    def __init__(self, channels: int, out_channels: int | None = None):
        super().__init__()
        out_channels = out_channels or channels
        self.shot_cut = nn.Conv2d(channels, out_channels, 1) if out_channels != channels else None
        self.conv = nn.Sequential(*_cn_bn_relu(channels), nn.Conv2d(channels, out_channels, 1),
                                  *_cn_bn_relu(out_channels), nn.Conv2d(out_channels, out_channels, 1))

    def forward(self, x):
        skip = x if self.shot_cut is None else self.shot_cut(x)
        return self.conv(x) + skip


class OAFilter(nn.Module):
    """Order-Aware Filtering block on (B, C, M, 1) cluster features (OANet Sec. 4.2, Fig. 3)."""

    def __init__(self, channels: int, points: int):
        super().__init__()
        self.conv1 = nn.Sequential(*_cn_bn_relu(channels), nn.Conv2d(channels, channels, 1), _Swap12())
        # Spatial correlation layer: a 1x1 conv across the (ordered) cluster axis.
        self.conv2 = nn.Sequential(nn.BatchNorm2d(points), nn.ReLU(), nn.Conv2d(points, points, 1))
        self.conv3 = nn.Sequential(_Swap12(), *_cn_bn_relu(channels), nn.Conv2d(channels, channels, 1))

    def forward(self, x):
        out = self.conv1(x)
        out = self.conv3(out + self.conv2(out))
        return out + x


class DiffPool(nn.Module):
    """Soft assignment of N correspondences to M clusters, softmax over the correspondences (Eq. (3))."""

    def __init__(self, channels: int, clusters: int):
        super().__init__()
        self.conv = nn.Sequential(*_cn_bn_relu(channels), nn.Conv2d(channels, clusters, 1))

    def forward(self, x):
        S = torch.softmax(self.conv(x), dim=2).squeeze(3)  # (B, M, N)
        return (x.squeeze(3) @ S.transpose(1, 2)).unsqueeze(3)  # (B, C, M, 1)


class DiffUnpool(DiffPool):
    """Back from M clusters to N correspondences, softmax over the clusters (Eq. (6)); layers as DiffPool's."""

    def forward(self, x_up, x_down):
        S = torch.softmax(self.conv(x_up), dim=1).squeeze(3)  # (B, M, N)
        return (x_down.squeeze(3) @ S).unsqueeze(3)  # (B, C, N, 1)


class OANBlock(nn.Module):
    """One OANet stage: PointCN x d/2, DiffPool, OAFilter x d/2, DiffUnpool, PointCN x d/2, logit."""

    def __init__(self, channels: int, in_channels: int, depth: int, clusters: int):
        super().__init__()
        half = max(depth // 2, 1)
        self.conv1 = nn.Conv2d(in_channels, channels, 1)
        self.l1_1 = nn.Sequential(*[PointCN(channels) for _ in range(half)])
        self.down1 = DiffPool(channels, clusters)
        self.l2 = nn.Sequential(*[OAFilter(channels, clusters) for _ in range(half)])
        self.up1 = DiffUnpool(channels, clusters)
        self.l1_2 = nn.Sequential(PointCN(2 * channels, channels), *[PointCN(channels) for _ in range(half - 1)])
        self.output = nn.Conv2d(channels, 1, 1)

    def forward(self, data):
        x1 = self.l1_1(self.conv1(data))
        x2 = self.l2(self.down1(x1))
        out = self.l1_2(torch.cat([x1, self.up1(x1, x2)], dim=1))
        return self.output(out).squeeze(3).squeeze(1)  # (B, N)


class OANet(nn.Module):
    """Order-aware network (Zhang et al., ICCV 2019); input (B, 4 + side, N), output logits per stage."""

    def __init__(self, config: OANetConfig = OANetConfig()):
        super().__init__()
        self.config = config
        depth = config.net_depth // (config.iter_num + 1)
        c_in = 4 + config.side_channels
        self.weights_init = OANBlock(config.net_channels, c_in, depth, config.clusters)
        self.weights_iter = nn.Sequential(
            *[OANBlock(config.net_channels, c_in + 2, depth, config.clusters) for _ in range(config.iter_num)])

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Logits ``(B, N)`` of every stage, the last one is the network's answer."""
        data = x.unsqueeze(3)  # (B, C, N, 1)
        coords = x[:, :4].transpose(1, 2)  # (B, N, 4)
        logits = [self.weights_init(data)]
        for block in self.weights_iter:
            with torch.no_grad():  # the residual is an input feature, not a path for gradients (as released)
                w = torch.relu(torch.tanh(logits[-1]))
                res = epipolar_residual(coords, weighted_eight_point(coords, w)).to(x.dtype)
            extra = torch.stack([res, w.detach()], dim=1).unsqueeze(3)
            logits.append(block(torch.cat([data, extra], dim=1)))
        return logits


# ----------------------------------------------------------------------------------------------- ACNe
class ACN(nn.Module):
    """Attentive Context Normalisation (Sun et al., CVPR 2020, Eq. (5)-(8)) of (B, C, N) features."""

    def __init__(self, channels: int, eps: float = 1e-3):
        super().__init__()
        self.attn = nn.Conv1d(channels, 2, 1)  # channel 0: global (softmax) logit, 1: local (sigmoid) logit
        self.eps = eps

    def forward(self, x):
        a = self.attn(x)
        local_logit = a[:, 1]
        w = torch.softmax(a[:, 0], dim=1) * torch.sigmoid(local_logit)
        w = (w / w.sum(dim=1, keepdim=True).clamp_min(1e-30)).unsqueeze(1)  # (B, 1, N), sums to 1
        mean = (w * x).sum(dim=2, keepdim=True)
        var = (w * (x - mean) ** 2).sum(dim=2, keepdim=True)
        return (x - mean) / torch.sqrt(var + self.eps), local_logit


class ACNLayer(nn.Module):
    """1x1 conv, ACN, group norm, ReLU (the released "post" activation order)."""

    def __init__(self, in_channels: int, channels: int, groups: int):
        super().__init__()
        self.conv = nn.Conv1d(in_channels, channels, 1)
        self.acn = ACN(channels)
        self.norm = nn.GroupNorm(min(groups, channels), channels, eps=1e-5)

    def forward(self, x):
        out, local_logit = self.acn(self.conv(x))
        return torch.relu(self.norm(out)), local_logit


class ACNBlock(nn.Module):
    """Residual block of ``num_inner`` ACN layers (ACNe Fig. 2)."""

    def __init__(self, channels: int, num_inner: int, groups: int):
        super().__init__()
        self.layers = nn.ModuleList([ACNLayer(channels, channels, groups) for _ in range(num_inner)])

    def forward(self, x, attention: list):
        out = x
        for layer in self.layers:
            out, local_logit = layer(out)
            attention.append(local_logit)
        return out + x


class ACNe(nn.Module):
    """Attentive context network (Sun et al., CVPR 2020); input (B, 4 + side, N)."""

    def __init__(self, config: ACNeConfig = ACNeConfig()):
        super().__init__()
        self.config = config
        c = config.net_channels
        self.input = nn.Conv1d(4 + config.side_channels, c, 1)
        self.blocks = nn.ModuleList([ACNBlock(c, config.num_inner, config.groups) for _ in range(config.net_depth)])
        self.logit_softmax = nn.Conv1d(c, 1, 1)  # global attention of the weighted eight-point algorithm
        self.output = nn.Conv1d(c, 1, 1)  # inlier logit (local attention)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """``[logits]`` of shape (B, N) (a one-element list, like OANet's stages); see :meth:`forward_all`."""
        return [self.forward_all(x)[0]]

    def forward_all(self, x: torch.Tensor):
        """Inlier logits (B, N), global-attention logits (B, N) and every ACN's local-attention logits."""
        attention: list = []
        out = self.input(x)
        for block in self.blocks:
            out = block(out, attention)
        return self.output(out).squeeze(1), self.logit_softmax(out).squeeze(1), attention


def build_network(arch: str, config: dict | None = None) -> nn.Module:
    """``OANet`` or ``ACNe`` from a config dict (keys of :class:`OANetConfig` / :class:`ACNeConfig`)."""
    if arch == "oanet":
        return OANet(OANetConfig(**(config or {})))
    if arch == "acne":
        return ACNe(ACNeConfig(**(config or {})))
    raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
