"""Datasets: image pairs with ground truth (Sec. 5.1), see ``docs/evaluation.md`` (Datasets).

:func:`load_dataset` reads a registered name (:func:`list_datasets`: embedded, real, groups) or a custom
folder (:mod:`.custom`), a pairs-with-ground-truth file (:mod:`.posefile`) or a Strecha-layout folder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from .base import PAIR_KINDS, Dataset, EpipolarGT, FlowGT, GroundTruth, HomographyGT, Pair, PairKind, PoseGT
from .custom import read_custom_dataset, write_custom_dataset
from .downscaled import downscale_pairs
from .embedded import embedded_root, motorcycle_pose_gt
from .posefile import read_pairs_with_gt, write_pairs_with_gt
from .real import REAL_LOADERS, _resolve
from .strecha import DIFFICULTY_BANDS, load_strecha_folder, pose_difficulty, strecha_scenes

__all__ = [
    "Dataset", "EpipolarGT", "FlowGT", "GroundTruth", "HomographyGT", "Pair", "PairKind", "PAIR_KINDS", "PoseGT",
    "DEFAULT_DATASET", "load_dataset", "list_datasets", "read_custom_dataset", "write_custom_dataset",
    "load_strecha", "load_strecha_half", "downscale_pairs", "read_pairs_with_gt", "write_pairs_with_gt",
    "pose_difficulty", "DIFFICULTY_BANDS",
]

DEFAULT_DATASET = "embedded"

_EMBEDDED = {"embedded": None, "embedded-planar": "planar", "embedded-nonplanar": "nonplanar",
             "embedded-depth": "depth"}
_GROUPS = {"planar": ("hpatches", "oxford", "homogr"), "nonplanar": ("kusvod2",), "calibrated": ("strecha",)}


def load_strecha(root=None, **kwargs) -> list:
    """The Strecha pairs under ``root`` (default ``$CTXMATCH_DATA``), see :func:`.strecha.load_strecha_folder`."""
    folder = _resolve(root, "calibrated/strecha", lambda d: bool(strecha_scenes(d)))
    return load_strecha_folder(folder, **kwargs)


def load_strecha_half(root=None, **kwargs) -> list:
    """:func:`load_strecha` at half resolution (:func:`.downscaled.downscale_pairs`)."""
    return downscale_pairs(load_strecha(root, **kwargs), 2)


_LOADERS = {**REAL_LOADERS, "strecha": load_strecha, "strecha-half": load_strecha_half}


def list_datasets() -> list[str]:
    """The registered dataset names, embedded ones first.

    Examples
    --------
    >>> list_datasets()[:2]
    ['embedded', 'embedded-planar']
    """
    return [*_EMBEDDED, "embedded-calibrated", *_LOADERS, *_GROUPS]


def load_dataset(name_or_path=DEFAULT_DATASET, *, root=None) -> Dataset:
    """Load a dataset by registered name or from a folder or file (module docstring).

    Parameters
    ----------
    name_or_path : str or Path
    root : str or Path, optional
        Real datasets: the data root (default ``$CTXMATCH_DATA``); embedded: the folder generated into
        (default the ``datasets`` cache). Ignored for a path.

    Raises
    ------
    ValueError
        Neither a registered name nor a readable folder or file.
    FileNotFoundError
        Real data not found, or a listed file missing.

    Examples
    --------
    >>> ds = load_dataset("embedded-planar")
    >>> len(ds), ds[0].kind
    (15, 'planar')
    """
    if name_or_path == "embedded-calibrated":
        folder = embedded_root(root)
        depth = [p for p in read_custom_dataset(folder, name="embedded").pairs if p.pair_id == "depth/motorcycle"]
        pairs = [dataclasses.replace(p, pair_id="calibrated/motorcycle", kind="calibrated", gt=motorcycle_pose_gt())
                 for p in depth]
        return Dataset(name_or_path, pairs, folder)
    if isinstance(name_or_path, str) and name_or_path in _EMBEDDED:
        folder = embedded_root(root)
        ds = read_custom_dataset(folder, name="embedded")
        kind = _EMBEDDED[name_or_path]
        pairs = [p for p in ds.pairs if kind is None or p.kind == kind]
        return Dataset(name_or_path, pairs, folder)
    if isinstance(name_or_path, str) and name_or_path in _LOADERS:
        return Dataset(name_or_path, _LOADERS[name_or_path](root), Path(root) if root else None)
    if isinstance(name_or_path, str) and name_or_path in _GROUPS:
        pairs = [p for sub in _GROUPS[name_or_path] for p in _LOADERS[sub](root)]
        return Dataset(name_or_path, pairs, Path(root) if root else None)
    path = Path(name_or_path).expanduser()
    if path.is_dir() and not (path / "pairs.csv").is_file():
        if (path / "pairs_with_gt.txt").is_file():
            return read_pairs_with_gt(path / "pairs_with_gt.txt")
        if strecha_scenes(path):
            folder = path.resolve()
            return Dataset(folder.name, load_strecha_folder(folder, dataset=folder.name), folder)
    if path.is_dir():
        return read_custom_dataset(path)
    if path.is_file() and path.name == "pairs.csv":
        return read_custom_dataset(path.parent)
    if path.is_file() and path.suffix.lower() == ".txt":
        return read_pairs_with_gt(path)
    raise ValueError(
        f"name_or_path must be one of {list_datasets()}, a folder holding pairs.csv or pairs_with_gt.txt, a "
        f"pairs-with-ground-truth .txt file or a folder in the Strecha layout, got {str(name_or_path)!r}"
    )
