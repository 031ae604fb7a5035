"""The shapes of the OANet and ACNe networks (no torch: the numpy inference and the torch modules share them)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["OANetConfig", "ACNeConfig"]


@dataclass(frozen=True)
class OANetConfig:
    """Shape of an OANet (defaults: the authors' release).

    ``net_depth``: layers of all ``iter_num + 1`` blocks together; ``clusters``: the DiffPool size M;
    ``side_channels``: channels after the 4 coordinates.
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
    """Shape of an ACNe: ``net_depth`` residual blocks of ``num_inner`` ACN layers (defaults: the release)."""

    net_channels: int = 128
    net_depth: int = 12
    num_inner: int = 2
    groups: int = 32
    side_channels: int = 0

    def to_dict(self) -> dict:
        return asdict(self)
