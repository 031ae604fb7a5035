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

# Relative size of the smallest singular value below which a 3x3 ground-truth matrix counts as losing a
# rank: far beneath the conditioning of any real homography (about 1e-5 for a 1000 px translation) and far
# above the rounding of a matrix that is exactly singular.
_RANK_TOL = 1e-12


def _matrix_rank(M: np.ndarray) -> int:
    s = np.linalg.svd(M, compute_uv=False)
    return int(np.sum(s > _RANK_TOL * s[0])) if s[0] > 0 else 0


def _check_matrix(M, name: str, what: str, *, min_rank: int) -> None:
    """A finite 3x3 ground-truth matrix of at least ``min_rank``, else a ValueError naming it."""
    M = np.asarray(M)
    if M.shape != (3, 3):
        raise ValueError(f"{what} {name} must be a 3x3 matrix, got shape {M.shape}")
    if not np.issubdtype(M.dtype, np.number) or not np.isfinite(M).all():
        raise ValueError(f"{what} {name} must hold finite numbers, got {M.tolist()}")
    rank = _matrix_rank(M.astype(np.float64))
    if rank == 0:
        raise ValueError(f"{what} {name} is all zeros: no ground truth")
    if rank < min_rank:
        raise ValueError(f"{what} {name} has rank {rank}, it must have rank {min_rank}"
                         f"{' (invertible)' if min_rank == 3 else ''}: degenerate ground truth")


def _check_points(pts, name: str, n: int | None = None) -> None:
    if pts is None:
        return
    pts = np.asarray(pts)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {pts.shape}")
    if n is not None and len(pts) != n:
        raise ValueError(f"pts1 and pts2 must have the same length, got {n} and {len(pts)}")
    if not np.isfinite(pts).all():
        raise ValueError(f"{name} contains NaN or infinite values")


@dataclass(frozen=True, eq=False)
class HomographyGT:
    """Planar ground truth: ``H`` (3, 3) maps image-1 points to image 2, ``x2 ~ H @ [x1, y1, 1]``.

    ``pts1``/``pts2`` (N, 2), optional: hand-taken corresponding points the homography was checked or
    fitted on (the Lebeda homogr set ships them), ``None`` when the dataset has none.
    """

    H: np.ndarray
    pts1: np.ndarray | None = None
    pts2: np.ndarray | None = None

    def __post_init__(self):
        # A zero or rank-deficient H maps the image to a point or a line: every match would be labelled
        # wrong and the pair silently counted as a failure. Loaders prefix the file the matrix came from.
        _check_matrix(self.H, "H", "homography", min_rank=3)
        if (self.pts1 is None) != (self.pts2 is None):
            raise ValueError("pts1 and pts2 must both be given or both be None")
        _check_points(self.pts1, "pts1")
        _check_points(self.pts2, "pts2", None if self.pts1 is None else len(self.pts1))


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

    def __post_init__(self):
        for name in ("pts1", "pts2"):
            if getattr(self, name) is None:
                raise ValueError(f"{name}: EpipolarGT needs the hand-taken correspondences, got None")
        # Rank 2 is what a fundamental matrix has; rank 1 or 0 gives no usable epipolar lines.
        _check_matrix(self.F, "F", "fundamental matrix", min_rank=2)
        _check_points(self.pts1, "pts1")
        _check_points(self.pts2, "pts2", len(np.asarray(self.pts1)))


@dataclass(frozen=True, eq=False)
class FlowGT:
    """Dense ground truth as per-pixel displacement fields (synthetic scenes, stereo disparity).

    ``flow12`` (H1, W1, 2): the image-1 pixel at row ``r``, column ``c`` (the point x = c, y = r) moves to
    ``(c + flow12[r, c, 0], r + flow12[r, c, 1])`` in image 2; NaN where unknown or occluded.
    ``flow21`` (H2, W2, 2) is the same from image 2 to image 1, or ``None`` when only one direction exists.
    """

    flow12: np.ndarray
    flow21: np.ndarray | None = None

    def __post_init__(self):
        for name, flow in (("flow12", self.flow12), ("flow21", self.flow21)):
            if flow is None:
                continue
            flow = np.asarray(flow)
            if flow.ndim != 3 or flow.shape[2] != 2:
                raise ValueError(f"{name} must have shape (H, W, 2), got {flow.shape}")
            if np.isinf(flow).any():
                raise ValueError(f"{name} contains infinite values (NaN marks unknown or occluded pixels)")
        if self.flow12.size == 0 or np.isnan(self.flow12).all():
            raise ValueError("flow12 has no known pixel (all NaN or empty): no ground truth")


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
