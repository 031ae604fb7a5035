"""Image pairs (:class:`Pair`, :class:`Dataset`) and their ground truth (:class:`HomographyGT`,
:class:`EpipolarGT`, :class:`FlowGT`, :class:`PoseGT`). Pixels: x right, y down, (0, 0) the centre of the
top-left pixel."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal, Union

import numpy as np

from .._numerics.validation import as_intrinsics, as_rotation, as_vector3

__all__ = ["HomographyGT", "EpipolarGT", "FlowGT", "PoseGT", "GroundTruth", "Pair", "PairKind", "Dataset",
           "PAIR_KINDS"]

PairKind = Literal["planar", "nonplanar", "depth", "calibrated"]
PAIR_KINDS = ("planar", "nonplanar", "depth", "calibrated")

# Relative singular value below which a 3x3 matrix loses a rank: far beneath any real homography's
# conditioning (about 1e-5 for a 1000 px translation), far above the rounding of an exactly singular one.
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

    ``pts1``/``pts2`` (N, 2), optional: the hand-taken points it was fitted on (Lebeda homogr ships them).
    """

    H: np.ndarray
    pts1: np.ndarray | None = None
    pts2: np.ndarray | None = None

    def __post_init__(self):
        # A rank-deficient H would label every match wrong, silently.
        _check_matrix(self.H, "H", "homography", min_rank=3)
        if (self.pts1 is None) != (self.pts2 is None):
            raise ValueError("pts1 and pts2 must both be given or both be None")
        _check_points(self.pts1, "pts1")
        _check_points(self.pts2, "pts2", None if self.pts1 is None else len(self.pts1))


@dataclass(frozen=True, eq=False)
class EpipolarGT:
    """Non-planar ground truth: ``F`` (3, 3) with ``x2^T F x1 = 0`` and the hand-taken points ``pts1``,
    ``pts2`` (N, 2) of method D's localisation check."""

    F: np.ndarray
    pts1: np.ndarray
    pts2: np.ndarray

    def __post_init__(self):
        for name in ("pts1", "pts2"):
            if getattr(self, name) is None:
                raise ValueError(f"{name}: EpipolarGT needs the hand-taken correspondences, got None")
        _check_matrix(self.F, "F", "fundamental matrix", min_rank=2)
        _check_points(self.pts1, "pts1")
        _check_points(self.pts2, "pts2", len(np.asarray(self.pts1)))


@dataclass(frozen=True, eq=False)
class FlowGT:
    """Dense ground truth: ``flow12`` (H1, W1, 2) moves the image-1 pixel (x = c, y = r) to
    ``(c + flow12[r, c, 0], r + flow12[r, c, 1])``, NaN where unknown or occluded; ``flow21`` (H2, W2, 2)
    the same from image 2, or ``None``."""

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


# A rotation printed with 6 significant digits is orthonormal only to about 1e-6, so the readers accept
# ROTATION_TEXT_TOL and project onto the nearest rotation; PoseGT itself requires _ROTATION_TOL.
_ROTATION_TOL = 1e-6
ROTATION_TEXT_TOL = 1e-4


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def nearest_rotation(R) -> np.ndarray:
    """The rotation closest to ``R`` in the Frobenius norm (``U V^T`` of its SVD), for a matrix read as text."""
    U, _, Vt = np.linalg.svd(np.asarray(R, np.float64))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


@dataclass(frozen=True, eq=False)
class PoseGT:
    """Calibrated two-view ground truth: ``X2 = R @ X1 + t`` (SuperGlue's ``T_0to1``), pixels ``x ~ K @ X``.

    Parameters
    ----------
    K1, K2 : ndarray of shape (3, 3)
        Intrinsics, upper triangular (stored divided by ``K[2, 2]``).
    R : ndarray of shape (3, 3)
        Rotation (``R^T R = I`` within 1e-6).
    t : ndarray of shape (3,)
        Non-zero; only its direction enters the pose error.
    threshold_scale : float
        Factor on the paper's pixel thresholds, set on images about 1000 px wide (Sec. 5.1).
    difficulty : str
        Band, see :func:`ctxmatch_lib.datasets.pose_difficulty`.
    rotations : tuple of int
        Quarter turns ``(rot0, rot1)`` of a pairs-with-ground-truth line, kept to write it back.

    A bad field raises ValueError naming it.
    """

    K1: np.ndarray
    K2: np.ndarray
    R: np.ndarray
    t: np.ndarray
    threshold_scale: float = 1.0
    difficulty: str = ""
    rotations: tuple[int, int] = (0, 0)

    def __post_init__(self):
        object.__setattr__(self, "K1", as_intrinsics(self.K1, "K1"))
        object.__setattr__(self, "K2", as_intrinsics(self.K2, "K2"))
        object.__setattr__(self, "R", as_rotation(self.R, "R", _ROTATION_TOL))
        t = as_vector3(self.t, "t")
        if not np.any(t):
            raise ValueError("t is zero: a pure rotation has no epipolar geometry")
        object.__setattr__(self, "t", t)
        scale = self.threshold_scale
        if not (isinstance(scale, (int, float, np.number)) and np.isfinite(scale) and scale > 0):
            raise ValueError(f"threshold_scale must be a positive number, got {scale!r}")
        object.__setattr__(self, "threshold_scale", float(scale))

    @property
    def E(self) -> np.ndarray:
        """Essential matrix ``[t]x R`` (3, 3): ``X2^T E X1 = 0`` for normalised camera coordinates."""
        return _skew(self.t) @ self.R

    @property
    def F(self) -> np.ndarray:
        """Fundamental matrix ``K2^-T [t]x R K1^-1`` (3, 3), ``x2^T F x1 = 0`` on pixels, Frobenius norm 1."""
        F = np.linalg.inv(self.K2).T @ self.E @ np.linalg.inv(self.K1)
        return F / np.linalg.norm(F)


GroundTruth = Union[HomographyGT, EpipolarGT, FlowGT, PoseGT]


@dataclass(frozen=True)
class Pair:
    """One image pair: sizes as (width, height); ``kind`` ``"planar"``, ``"nonplanar"``, ``"depth"`` or
    ``"calibrated"`` with ``gt`` a ``HomographyGT``, ``EpipolarGT``, ``FlowGT`` or ``PoseGT``."""

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
    """A named, ordered list of :class:`Pair`, with the folder it was read from (``root``, or None)."""

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
        """The sub-dataset of the pairs of one kind (one of :data:`PAIR_KINDS`)."""
        if kind not in PAIR_KINDS:
            raise ValueError(f"kind must be one of {PAIR_KINDS}, got {kind!r}")
        return Dataset(f"{self.name}[{kind}]", [p for p in self.pairs if p.kind == kind], self.root)
