"""SuperGlue's / LoFTR's pairs-with-ground-truth text format: one pair per line,
``name0 name1 rot0 rot1 K0(9) K1(9) T_0to1(16)`` (:func:`read_pairs_with_gt`, :func:`write_pairs_with_gt`).

``K`` and ``T_0to1`` describe the images as stored (``rot0``/``rot1`` are kept, never applied); pixel
centres at integers; blank and ``#`` lines skipped. Format: ``docs/evaluation.md`` (Calibrated pairs).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cache import atomic_path
from .._numerics.fixedmath import acos
from .._numerics.validation import as_rotation
from ._io import image_size, named_errors
from .base import ROTATION_TEXT_TOL, Dataset, Pair, PoseGT, nearest_rotation
from .strecha import rotation_band, threshold_scale_for

__all__ = ["POSE_LINE_TOKENS", "parse_pose_tokens", "format_pose_tokens", "read_pairs_with_gt",
           "write_pairs_with_gt"]

#: Tokens per line: two names, two rotations, 9 + 9 intrinsics, 16 for ``T_0to1``.
POSE_LINE_TOKENS = 38


def parse_pose_tokens(tokens, *, scale: float = 1.0, difficulty: str | None = None) -> PoseGT:
    """A :class:`PoseGT` from the 36 numeric tokens ``rot0 rot1 K0(9) K1(9) T_0to1(16)``; bad tokens or
    geometry raise ValueError naming the field (callers prefix the file and line)."""
    if len(tokens) != POSE_LINE_TOKENS - 2:
        raise ValueError(f"expected {POSE_LINE_TOKENS - 2} numbers 'rot0 rot1 K0(9) K1(9) T_0to1(16)', "
                         f"got {len(tokens)}")
    values = []
    for v in tokens:
        try:
            values.append(float(v))
        except ValueError:
            raise ValueError(f"not a number: {v!r}") from None
    values = np.array(values, np.float64)
    if not np.isfinite(values).all():
        raise ValueError("NaN or infinite value")
    rots = values[:2]
    if np.any(rots != np.round(rots)) or np.any((rots < 0) | (rots > 3)):
        raise ValueError(f"rot0 and rot1 must be integers 0-3 (quarter turns), got {tokens[0]} {tokens[1]}")
    K0, K1, T = values[2:11].reshape(3, 3), values[11:20].reshape(3, 3), values[20:].reshape(4, 4)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError(f"T_0to1 must end with the row 0 0 0 1, got {T[3].tolist()}")
    R = nearest_rotation(as_rotation(T[:3, :3] / T[3, 3], "the rotation of T_0to1", ROTATION_TEXT_TOL))
    t = T[:3, 3] / T[3, 3]
    if difficulty is None:
        difficulty = rotation_band(float(np.degrees(acos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))))
    for name, K in (("K0", K0), ("K1", K1)):
        if K[0, 0] == 0 or K[1, 1] == 0:
            raise ValueError(f"{name} has a zero focal length (fx = {K[0, 0]:g}, fy = {K[1, 1]:g})")
    return PoseGT(K0, K1, R, t, threshold_scale=scale, difficulty=difficulty,
                  rotations=(int(rots[0]), int(rots[1])))


def format_pose_tokens(gt: PoseGT) -> list[str]:
    """The 36 numeric tokens of ``gt`` (inverse of :func:`parse_pose_tokens`), shortest exact repr."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = gt.R, gt.t
    return [str(r) for r in gt.rotations] + [repr(float(v)) for v in (*gt.K1.ravel(), *gt.K2.ravel(), *T.ravel())]


def read_pairs_with_gt(path, *, image_dir=None, name: str | None = None) -> Dataset:
    """Read a pairs-with-ground-truth file as calibrated pairs, images relative to ``image_dir`` (default:
    the file's folder), ids ``<name>/<stem0>-<stem1>`` (default name: the image folder's). A missing file
    raises FileNotFoundError; a bad line (named), a duplicate or no pair ValueError."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"pairs-with-ground-truth file not found: {path}")
    path = path.resolve()
    folder = Path(image_dir).expanduser().resolve() if image_dir is not None else path.parent
    name = name or folder.name
    pairs, seen = [], set()
    for line_no, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        where = f"{path}, line {line_no}"
        if len(tokens) != POSE_LINE_TOKENS:
            raise ValueError(f"{where}: expected {POSE_LINE_TOKENS} tokens 'name0 name1 rot0 rot1 K0(9) K1(9) "
                             f"T_0to1(16)', got {len(tokens)}")
        images = [folder / tokens[0], folder / tokens[1]]
        try:
            sizes = [image_size(p) for p in images]
        except (FileNotFoundError, ValueError) as exc:
            raise type(exc)(f"{where}: {exc}") from None
        with named_errors(where):
            gt = parse_pose_tokens(tokens[2:], scale=threshold_scale_for((*sizes[0], *sizes[1])))
        stem0 = Path(tokens[0]).stem if Path(tokens[0]).is_absolute() else Path(tokens[0]).with_suffix("").as_posix()
        pair_id = f"{name}/{stem0}-{Path(tokens[1]).stem}"
        if pair_id in seen:
            raise ValueError(f"{where}: duplicate pair {tokens[0]} {tokens[1]}")
        seen.add(pair_id)
        pairs.append(Pair(pair_id, images[0], images[1], sizes[0], sizes[1], "calibrated", gt, dataset=name))
    if not pairs:
        raise ValueError(f"{path} lists no pairs: one line per pair, {POSE_LINE_TOKENS} tokens")
    return Dataset(name, pairs, folder)


def write_pairs_with_gt(dataset, path, *, image_dir=None) -> Path:
    """Write the calibrated pairs of ``dataset`` as a pairs-with-ground-truth file, atomically; names
    relative to ``image_dir`` (default: the file's folder) when the images lie under it, else absolute."""
    import os

    path = Path(path)
    folder = Path(image_dir if image_dir is not None else path.parent).resolve()
    lines = []
    for p in dataset:
        if not isinstance(p.gt, PoseGT):
            raise ValueError(f"pair {p.pair_id!r}: only calibrated pairs (PoseGT) can be written, "
                             f"got {type(p.gt).__name__}")
        names = []
        for img in (p.image1, p.image2):
            rel = Path(os.path.relpath(Path(img).resolve(), folder))
            names.append((Path(img).resolve() if rel.parts[:1] == ("..",) else rel).as_posix())
        if any(len(n.split()) != 1 for n in names):
            raise ValueError(f"pair {p.pair_id!r}: image paths with white space cannot be written: {names}")
        lines.append(" ".join([*names, *format_pose_tokens(p.gt)]))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    return path
