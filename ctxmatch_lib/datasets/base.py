"""Image pairs and their ground-truth objects, shared by every dataset loader.

Pixel convention everywhere: x right, y down, (0, 0) the centre of the top-left pixel; keypoints are
``(N, 2)`` float arrays of (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal, Union

import numpy as np

__all__ = ["HomographyGT", "EpipolarGT", "FlowGT", "GroundTruth", "Pair", "PairKind", "Dataset", "PAIR_KINDS"]

PairKind = Literal["planar", "nonplanar", "depth"]
PAIR_KINDS = ("planar", "nonplanar", "depth")


@dataclass(frozen=True, eq=False)
class HomographyGT:
    """Planar ground truth: ``H`` (3, 3) maps image-1 points to image 2, ``x2 ~ H @ [x1, y1, 1]``.

    ``pts1``/``pts2`` (N, 2), optional: hand-taken corresponding points the homography was checked or
    fitted on (the Lebeda homogr set ships them), ``None`` when the dataset has none.
    """

    H: np.ndarray
    pts1: np.ndarray | None = None
    pts2: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class EpipolarGT:
    """Non-planar ground truth from hand-taken correspondences.

    ``F`` (3, 3) satisfies ``x2^T F x1 = 0`` for homogeneous image-1 point ``x1`` and image-2 point ``x2``.
    ``pts1``/``pts2`` (N, 2) are the hand-taken corresponding points used by the spatial-localisation check
    of method D.
    """

    F: np.ndarray
    pts1: np.ndarray
    pts2: np.ndarray


@dataclass(frozen=True, eq=False)
class FlowGT:
    """Dense ground truth as per-pixel displacement fields (synthetic scenes, stereo disparity).

    ``flow12`` (H1, W1, 2): the image-1 pixel at row ``r``, column ``c`` (the point x = c, y = r) moves to
    ``(c + flow12[r, c, 0], r + flow12[r, c, 1])`` in image 2; NaN where unknown or occluded.
    ``flow21`` (H2, W2, 2) is the same from image 2 to image 1, or ``None`` when only one direction exists.
    """

    flow12: np.ndarray
    flow21: np.ndarray | None = None


GroundTruth = Union[HomographyGT, EpipolarGT, FlowGT]


@dataclass(frozen=True)
class Pair:
    """One image pair of a dataset.

    ``image_size1``/``image_size2`` are (width, height). ``kind`` is ``"planar"``, ``"nonplanar"`` or
    ``"depth"``; ``gt`` holds the matching ground-truth object.
    """

    pair_id: str
    image1: Path
    image2: Path
    image_size1: tuple[int, int]
    image_size2: tuple[int, int]
    kind: PairKind
    gt: GroundTruth = field(repr=False)
    dataset: str = ""


@dataclass(frozen=True, eq=False)
class Dataset:
    """A named, ordered list of :class:`Pair`; iterable, indexable and sized.

    ``root`` is the folder the pairs were read from (or generated into), when there is one.
    """

    name: str
    pairs: list[Pair]
    root: Path | None = None

    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[Pair]:
        return iter(self.pairs)

    def __getitem__(self, index):
        return self.pairs[index]

    def __repr__(self) -> str:
        kinds = {k: sum(p.kind == k for p in self.pairs) for k in PAIR_KINDS}
        counts = ", ".join(f"{k}={n}" for k, n in kinds.items() if n)
        return f"Dataset({self.name!r}, {len(self.pairs)} pairs{': ' + counts if counts else ''})"

    def by_kind(self, kind: str) -> "Dataset":
        """The sub-dataset of the pairs of one kind (``"planar"``, ``"nonplanar"`` or ``"depth"``)."""
        if kind not in PAIR_KINDS:
            raise ValueError(f"kind must be one of {PAIR_KINDS}, got {kind!r}")
        return Dataset(f"{self.name}[{kind}]", [p for p in self.pairs if p.kind == kind], self.root)
