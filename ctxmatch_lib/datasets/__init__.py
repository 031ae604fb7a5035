"""Datasets: image pairs with ground truth (embedded offline default, real loaders, custom folders)."""

from .base import EpipolarGT, FlowGT, GroundTruth, HomographyGT, Pair, PairKind

__all__ = ["EpipolarGT", "FlowGT", "GroundTruth", "HomographyGT", "Pair", "PairKind"]
