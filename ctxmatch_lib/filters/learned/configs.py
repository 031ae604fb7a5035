"""The shapes of the OANet and ACNe networks (no torch: the numpy inference and the torch modules share them)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["OANetConfig", "ACNeConfig"]


@dataclass(frozen=True)
class OANetConfig:
    """Shape of an OANet.

    ``net_depth`` counts the layers of all blocks together (each of the ``iter_num + 1`` blocks gets
    ``net_depth // (iter_num + 1)``), ``clusters`` is the DiffPool size M, ``side_channels`` the side
    information channels after the 4 coordinates. The authors' release uses 128 channels, depth 12, 500
    clusters, 1 iteration; the weights trained here use a smaller network
    (:data:`~ctxmatch_lib.filters.learned.training.TRAINED_HERE_CONFIGS`).
    """

    net_channels: int = 128
    net_depth: int = 12
    clusters: int = 500
    iter_num: int = 1
    side_channels: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ACNeConfig:
    """Shape of an ACNe: ``net_depth`` residual blocks of ``num_inner`` ACN layers of ``net_channels``.

    The authors' release uses 128 channels, 12 blocks of 2 layers, group normalisation in 32 groups.
    """

    net_channels: int = 128
    net_depth: int = 12
    num_inner: int = 2
    groups: int = 32
    side_channels: int = 0

    def to_dict(self) -> dict:
        return asdict(self)
