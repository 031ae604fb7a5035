"""Two images in, filtered matches out (``ctxmatch match``): features -> blob matching (Sec. 3) -> filters
(Sec. 4) -> optional model step (Sec. 5.1).

:func:`match_images` returns a :class:`MatchResult`; :func:`save_result` / :func:`load_result` write and read
it as ``.npz``, :func:`plot_result` draws it, :func:`match_pairs` runs hloc's ``pairs.txt`` resumably.
Image sizes are (width, height), read from the images; scores are lower-is-better.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "MatchResult",
    "PairFeatures",
    "match_images",
    "resolve_features",
    "resolve_blob",
    "save_result",
    "load_result",
    "plot_result",
    "read_pairs",
    "pair_filename",
    "match_pairs",
    "kernels_ready",
    "warm_up",
]

#: Keys of the ``.npz`` written by :func:`save_result`.
NPZ_KEYS = ("kpts1", "kpts2", "shapes1", "shapes2", "matches", "scores", "image_size1", "image_size2", "settings")


@dataclass(frozen=True, eq=False)
class MatchResult:
    """Filtered matches between two images and everything needed to use them.

    Attributes
    ----------
    kpts1, kpts2, shapes1, shapes2 : ndarray of shape (N, 2) and (N, 2, 2), float64
        Keypoints and affine shapes: a patch is ``{kpt + A @ u : |u| <= 1}`` (3 sigma for SIFT).
    matches, scores : ndarray of shape (K, 2), int64, and (K,), float64
        Kept matches and their blob scores, sorted by score.
    candidates, candidate_scores, keep : ndarray of shape (M, 2), (M,), (M,) bool
        The blob-matching candidates; ``matches == candidates[keep]``.
    image_size1, image_size2 : tuple of int
        (width, height).
    model, settings : ndarray of shape (3, 3) or None, dict
        The fitted ``H`` or ``F``; the settings used (JSON-serialisable).
    model_input : ndarray of shape (M,) bool or None
        The candidates given to the model step (``model_input & ~keep``: those it rejected).
    """

    kpts1: np.ndarray
    kpts2: np.ndarray
    shapes1: np.ndarray
    shapes2: np.ndarray
    matches: np.ndarray
    scores: np.ndarray
    candidates: np.ndarray
    candidate_scores: np.ndarray
    keep: np.ndarray
    image_size1: tuple
    image_size2: tuple
    model: np.ndarray | None = None
    settings: dict = field(default_factory=dict)
    model_input: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.matches)


# ------------------------------------------------------------------------------------------ arguments


def resolve_features(features="sift-rootsift", *, max_keypoints: int | None = None):
    """A :class:`~ctxmatch_lib.features.FeatureConfig` from a preset name or a config.

    Parameters
    ----------
    features : str or FeatureConfig
        A name of :data:`~ctxmatch_lib.features.FEATURE_PRESETS` or a config.
    max_keypoints : int, optional
        Overrides the preset's keypoint cap (0: no cap).
    """
    from dataclasses import replace

    from .features import FEATURE_PRESETS, FeatureConfig

    if isinstance(features, str):
        if features not in FEATURE_PRESETS:
            raise ValueError(f"unknown feature preset {features!r}; known presets: {', '.join(FEATURE_PRESETS)} "
                             "(or pass a FeatureConfig)")
        features = FEATURE_PRESETS[features]
    elif not isinstance(features, FeatureConfig):
        raise ValueError(f"features must be a preset name or a FeatureConfig, got {type(features).__name__}")
    if max_keypoints is not None:
        features = replace(features, max_keypoints=max_keypoints)
    return features


def _parse_value(text: str):
    low = text.strip().lower()
    if low in ("none", "inf", "off"):
        return None
    try:
        return int(low)
    except ValueError:
        pass
    try:
        return float(low)
    except ValueError:
        return text.strip()


def resolve_blob(blob="paper-best"):
    """A :class:`~ctxmatch_lib.blob.BlobConfig` from a preset name, ``"NAME:key=value,..."`` or
    ``"key=value,..."`` (overrides of that preset, else of ``"paper-best"``), a dict of fields or a config.

    Examples
    --------
    >>> resolve_blob("paper-best:t_o=5").label
    "f=10∪ f'=5 t_o=5px D+ W=harmonic"
    """
    from .blob import BLOB_PRESETS, BlobConfig

    if isinstance(blob, BlobConfig):
        return blob
    if isinstance(blob, Mapping):
        return BlobConfig(**{**BLOB_PRESETS["paper-best"].kwargs(), **dict(blob)})
    if not isinstance(blob, str):
        raise ValueError(f"blob must be a preset name, a 'key=value,...' string, a dict or a BlobConfig, "
                         f"got {type(blob).__name__}")
    name, _, rest = blob.partition(":")
    if "=" in name:  # no preset name: only overrides
        name, rest = "paper-best", blob
    name = name.strip()
    if name not in BLOB_PRESETS:
        raise ValueError(f"unknown blob preset {name!r}; known presets: {', '.join(BLOB_PRESETS)}")
    params = BLOB_PRESETS[name].kwargs()
    for item in filter(None, (t.strip() for t in rest.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or key not in params:
            raise ValueError(f"blob override {item!r} must be key=value with key among {', '.join(params)}")
        params[key] = value.strip() if key in ("ratio", "combine", "prefilter", "t_o_kind") else _parse_value(value)
    if params.get("t_o") is not None and isinstance(params["t_o"], float) and math.isinf(params["t_o"]):
        params["t_o"] = None
    return BlobConfig(**params)


def as_filter_list(filters) -> tuple[str, ...]:
    from .evaluation.steps import check_filters

    if filters is None:
        return ()
    if isinstance(filters, str):
        filters = [filters]
    names = [f for f in filters if f.strip().lower() != "none"]
    return check_filters(names)


# ------------------------------------------------------------------------------------------- one pair


def _threshold(value) -> float:
    from .geometry import CONSISTENCY_THRESHOLD_PX

    value = CONSISTENCY_THRESHOLD_PX if value is None else float(value)
    if not value > 0:
        raise ValueError(f"model_threshold must be positive, got {value}")
    return value


def _read(image, name: str):
    """The gray image for the features of a path or an array; errors name the argument."""
    from .features import as_gray_uint8

    try:
        gray = as_gray_uint8(image)
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{name}: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from None
    if gray.ndim != 2 or gray.size == 0:
        raise ValueError(f"{name} must be a non-empty 2-D image, got shape {gray.shape}")
    return gray


def match_images(
    image1,
    image2,
    *,
    features="sift-rootsift",
    blob="paper-best",
    filters: Sequence[str] | str | None = ("dtm",),
    model: str = "none",
    model_kind: str = "F",
    model_threshold: float | None = None,
    filter_params: Mapping[str, dict] | None = None,
    max_keypoints: int | None = None,
    cache_dir=None,
    rng=0,
) -> MatchResult:
    """Match two images: SIFT features, blob matching (Sec. 3), spatial filters (Sec. 4), a model step.

    Parameters
    ----------
    image1, image2 : str, Path or ndarray
        Image files, or pixels (``(H, W)`` gray or ``(H, W, 3|4)`` RGB(A)).
    features, max_keypoints : str or FeatureConfig, int, optional
        Feature preset or configuration (:func:`resolve_features`) and a keypoint cap overriding it.
    blob : str, dict or BlobConfig
        Blob-matching setup (:func:`resolve_blob`); default the paper's best.
    filters, filter_params : sequence of str, str or None; dict of str -> dict, optional
        Registered filters applied in turn (``None``, ``()`` or ``"none"``: none); extra arguments per filter.
    model, model_kind : {"none", "1sac", "ransac", "prosac", "magsac", "poselib"}, {"F", "H"}
        Model step on the filtered matches (:func:`~ctxmatch_lib.geometry.apply_model_step`) and its model.
    model_threshold : float, optional
        Consistency threshold of the model step in pixels (default 15, Sec. 5.1).
    cache_dir : str, Path, None or False
        Feature cache (:func:`~ctxmatch_lib.features.extract_features`); ``False`` disables it.
    rng : None, int or numpy.random.Generator
        Seed of the RANSAC model steps.

    Returns
    -------
    MatchResult
        Empty (not an error) without keypoints or candidates.

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.data import camera
    >>> img = camera()[::2, ::2]
    >>> res = match_images(img, np.ascontiguousarray(img[10:, 12:]), max_keypoints=300, cache_dir=False)
    >>> res.matches.shape[1], res.image_size1, res.image_size2
    (2, (256, 256), (244, 246))
    >>> shift = res.kpts1[res.matches[:, 0]] - res.kpts2[res.matches[:, 1]]
    >>> np.median(shift, axis=0).round().tolist()  # image 2 is image 1 cropped by 12 columns and 10 rows
    [12.0, 10.0]
    """
    _check_model(model, model_kind)
    pending = PairFeatures(image1, image2, features=features, max_keypoints=max_keypoints, cache_dir=cache_dir)
    return pending.match(blob=blob, filters=filters, model=model, model_kind=model_kind,
                         model_threshold=model_threshold, filter_params=filter_params, rng=rng)


def _check_model(model: str, model_kind: str) -> None:
    from .geometry import MODEL_STEPS

    if model not in MODEL_STEPS:
        raise ValueError(f"model must be one of {', '.join(MODEL_STEPS)}, got {model!r}")
    if model_kind not in ("F", "H"):
        raise ValueError(f"model_kind must be 'F' or 'H', got {model_kind!r}")


def _small_pair(step: int) -> tuple[np.ndarray, np.ndarray]:
    """scikit-image's camera taken every ``step``-th pixel, and the same shifted by a crop: a pair that runs
    every step in a fraction of a second."""
    from skimage.data import camera

    img = np.ascontiguousarray(camera()[::step, ::step])
    return img, np.ascontiguousarray(img[12 // step:, 12 // step:])


def _checked(*, features="sift-rootsift", blob="paper-best", filters=("dtm",), model="none", model_kind="F",
             model_threshold=None, filter_params=None, max_keypoints=None) -> dict:
    """:func:`match_images`' settings resolved and checked once (errors name the argument)."""
    _check_model(model, model_kind)
    return {"features": resolve_features(features, max_keypoints=max_keypoints), "blob": resolve_blob(blob),
            "filters": as_filter_list(filters), "model": model, "model_kind": model_kind,
            "model_threshold": _threshold(model_threshold), "filter_params": dict(filter_params or {})}


class PairFeatures:
    """The features of two images, extracted side by side from construction, one thread each, while the caller
    goes on; :meth:`match` then runs the rest of :func:`match_images` on them.

    OpenCV and the compiled kernels release the GIL, so the two images take the time of one on two cores, and
    the later steps load meanwhile; the features do not depend on it. The threads are daemons: a process that
    stops meanwhile does not wait for them (a feature cache entry is written atomically).

    Parameters
    ----------
    image1, image2, features, max_keypoints, cache_dir
        As in :func:`match_images`; a bad image or feature setting raises here.
    """

    def __init__(self, image1, image2, *, features="sift-rootsift", max_keypoints: int | None = None,
                 cache_dir=None):
        import threading

        self.config = resolve_features(features, max_keypoints=max_keypoints)
        grays = (_read(image1, "image1"), _read(image2, "image2"))
        self._out: list = [None, None]
        self._threads = [threading.Thread(target=self._extract, args=(i, g, cache_dir), daemon=True)
                         for i, g in enumerate(grays)]
        for t in self._threads:
            t.start()

    def _extract(self, i: int, gray, cache_dir) -> None:
        from .features import extract_features

        try:
            self._out[i] = extract_features(gray, self.config, cache_dir=cache_dir)
        except BaseException as exc:  # raised in the caller's thread by result()
            self._out[i] = exc

    def result(self) -> tuple:
        """The two images' :class:`~ctxmatch_lib.features.Features`, once extracted."""
        for t in self._threads:
            t.join()
        for out in self._out:
            if isinstance(out, BaseException):
                raise out
        return tuple(self._out)

    def match(self, *, blob="paper-best", filters=("dtm",), model: str = "none", model_kind: str = "F",
              model_threshold: float | None = None, filter_params=None, rng=0) -> MatchResult:
        """:func:`match_images` from here on (same parameters); the settings are checked, and their steps loaded,
        while the features are extracted."""
        steps = _checked(features=self.config, blob=blob, filters=filters, model=model, model_kind=model_kind,
                         model_threshold=model_threshold, filter_params=filter_params)
        if any(t.is_alive() for t in self._threads):
            _load_kernels(steps)
        f1, f2 = self.result()
        return _match_features(f1, f2, rng=rng, **steps)


def _load_kernels(steps: dict) -> None:
    """Run blob matching and the library's own filters on a small pair of the same settings, so that their
    compiled kernels are loaded (or compiled) while the features of the real pair are extracted; the result is
    dropped, and so is any error (the real pair reports its own). A registered filter from outside the library
    is not called on the small pair."""
    from dataclasses import replace

    from .features import extract_features
    from .filters import FILTERS

    def own(name: str) -> bool:
        func = FILTERS.get(name)
        while func is not None and (hasattr(func, "__wrapped__") or isinstance(func, functools.partial)):
            func = func.func if isinstance(func, functools.partial) else func.__wrapped__
        return (getattr(func, "__module__", None) or "").startswith(__name__.rsplit(".", 1)[0] + ".")

    try:
        config = replace(steps["features"], max_keypoints=200)
        small = [extract_features(g, config, cache_dir=False) for g in _small_pair(4)]
        _match_features(*small, rng=0, **{**steps, "filters": tuple(f for f in steps["filters"] if own(f)),
                                          "model": "none"})
    except Exception:  # only a head start: the real pair runs every step anyway
        pass


def _match_features(f1, f2, *, features, blob, filters, model, model_kind, model_threshold, filter_params,
                    rng) -> MatchResult:
    """:func:`match_images` from the two images' features and the settings of :func:`_checked`."""
    from .evaluation.steps import blob_candidates, run_filter
    from .geometry import apply_model_step

    cfg_feat, cfg_blob, names, threshold = features, blob, filters, model_threshold
    size1, size2 = f1.image_size, f2.image_size
    cand, cand_scores, _ = blob_candidates(f1, f2, cfg_blob)
    keep = np.ones(len(cand), bool)
    for name in names:
        idx = np.flatnonzero(keep)
        sub, _ = run_filter(name, f1, f2, cand[idx], cand_scores[idx], image_size1=size1, image_size2=size2,
                            blob_ratio=cfg_blob.ratio, **filter_params.get(name, {}))
        keep[idx[~sub]] = False
    fitted = model_input = None
    if model != "none":
        model_input = keep.copy()
        idx = np.flatnonzero(keep)
        fit = apply_model_step(model, f1.kpts, f2.kpts, cand[idx], cand_scores[idx], kind=model_kind,
                               threshold=threshold, rng=rng)
        keep[idx[~fit.keep]] = False
        fitted = fit.model
    settings = {
        "features": asdict(cfg_feat),
        "blob": cfg_blob.kwargs(),
        "filters": list(names),
        "filter_params": filter_params,
        "model": model,
        "model_kind": model_kind,
        "model_threshold": threshold,
        "rng": rng if isinstance(rng, (int, type(None))) else repr(rng),
    }
    from . import __version__

    settings["ctxmatch_version"] = __version__
    return MatchResult(
        kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes, shapes2=f2.shapes,
        matches=np.ascontiguousarray(cand[keep], np.int64), scores=np.asarray(cand_scores[keep], np.float64),
        candidates=cand, candidate_scores=cand_scores, keep=keep, image_size1=size1, image_size2=size2,
        model=fitted, settings=settings, model_input=model_input,
    )


# ----------------------------------------------------------------------------------------------- files


def save_result(result: MatchResult, path, **extra) -> Path:
    """Write ``result`` to ``path`` (``.npz``, keys :data:`NPZ_KEYS`, plus ``model`` when fitted) atomically.

    Parameters
    ----------
    result : MatchResult
    path : str or Path
        Output file; missing folders are created.
    **extra
        More arrays to store (e.g. image names).
    """
    from .cache import atomic_path

    path = Path(path)
    arrays = {
        "kpts1": result.kpts1, "kpts2": result.kpts2, "shapes1": result.shapes1, "shapes2": result.shapes2,
        "matches": np.asarray(result.matches, np.int64), "scores": np.asarray(result.scores, np.float64),
        "image_size1": np.asarray(result.image_size1, np.int64),
        "image_size2": np.asarray(result.image_size2, np.int64),
        "settings": np.array(json.dumps(result.settings, sort_keys=True, default=str)),
    }
    if result.model is not None:
        arrays["model"] = np.asarray(result.model, np.float64)
    arrays.update({k: np.asarray(v) for k, v in extra.items()})
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    _honour_umask(path)
    return path


def _honour_umask(path: Path) -> None:
    """Temporary files are created 0600; give the final file the permissions a plain ``open`` would."""
    import os

    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)


def load_result(path) -> dict:
    """Read a ``.npz`` of :func:`save_result` into a dict of arrays, ``settings`` parsed back to a dict."""
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    out["settings"] = json.loads(str(out["settings"]))
    return out


def plot_result(result: MatchResult, image1, image2, *, ax=None, title: str | None = None):
    """Draw the images side by side with the kept matches and those the model step rejected
    (:func:`ctxmatch_lib.plots.viz2d.plot_match_result`); returns the figure.

    Parameters
    ----------
    result : MatchResult
    image1, image2 : str, Path or ndarray
        The images the result was computed on (paths are read in colour).
    ax, title : matplotlib Axes, str, optional
        Where to draw (default a new figure); default title: kept matches out of the candidates.
    """
    from .features import load_image
    from .plots.viz2d import plot_match_result

    imgs = [load_image(im, gray=False) if isinstance(im, (str, Path)) else np.asarray(im) for im in (image1, image2)]
    return plot_match_result(result, imgs[0], imgs[1], ax=ax, title=title)


def save_plot(fig, path, *, dpi: int = 150) -> Path:
    """Write a figure to exactly ``path`` (format from the suffix), atomically, and close it."""
    import matplotlib.pyplot as plt

    from .cache import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=(path.suffix[1:] or "png"))
    plt.close(fig)
    _honour_umask(path)
    return path


# ---------------------------------------------------------------------------------------- folder mode


def read_pairs(path) -> list[tuple[str, str]]:
    """Read hloc's pairs file (``name1 name2`` per line, ``#`` comments) into name pairs, in file order,
    without duplicates. ``FileNotFoundError`` if not a file, ``ValueError`` for a malformed line or file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pairs file not found: {path}" if not path.exists()
                                else f"pairs file {path} is not a file")
    try:
        text = path.read_text()
    except UnicodeDecodeError as exc:
        raise ValueError(f"pairs file {path} is not a text file ({exc.reason} at byte {exc.start})") from None
    pairs, seen = [], set()
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise ValueError(f"pairs file {path}, line {n}: expected 'name1 name2', got {line!r}")
        pair = (parts[0], parts[1])
        if pair not in seen:
            seen.add(pair)
            pairs.append(pair)
    return pairs


def pair_filename(name1: str, name2: str) -> str:
    """File name of a pair's result in folder mode: ``"{name1}__{name2}.npz"``, ``/`` turned into ``-``.

    Parameters
    ----------
    name1, name2 : str
        Image names of the pairs file.

    Examples
    --------
    >>> pair_filename("db/a.jpg", "b.jpg")
    'db-a.jpg__b.jpg.npz'
    """
    return f"{name1.replace('/', '-')}__{name2.replace('/', '-')}.npz"


def match_pairs(
    pairs: Iterable[tuple[str, str]],
    image_dir,
    out_dir,
    *,
    progress: bool = True,
    on_pair: Callable[[str, str, Path, bool], None] | None = None,
    **kwargs,
) -> dict:
    """Match every pair of a pairs list, one ``.npz`` per pair in ``out_dir``, written atomically; resumable.

    A pair whose file holds the same settings is skipped (pairs are known by image names only).

    Parameters
    ----------
    pairs : iterable of (str, str)
        Image names relative to ``image_dir`` (:func:`read_pairs`).
    image_dir, out_dir : str or Path
        Image folder; output folder (created), file names from :func:`pair_filename`.
    progress : bool
        A tqdm progress bar on stderr.
    on_pair : callable, optional
        Called as ``on_pair(name1, name2, path, skipped)`` after each pair.
    **kwargs
        Settings of :func:`match_images`.

    Returns
    -------
    dict
        ``{"done": n, "skipped": n, "files": {(name1, name2): Path}}``.
    """
    from tqdm.auto import tqdm

    pairs = list(pairs)
    image_dir, out_dir = Path(image_dir), Path(out_dir)
    files = {p: out_dir / pair_filename(*p) for p in pairs}
    if len(set(files.values())) != len(files):
        raise ValueError("two different pairs map to the same output file name (names that differ only by '/' "
                         "and '-'); rename the images")
    from .cache import check_writable

    check_writable(out_dir, "out_dir", folder=True)
    taken = [f for f in files.values() if f.is_dir()]
    if taken:
        raise ValueError(f"out_dir: {taken[0]} is a folder where a pair's result file goes")
    missing = sorted({n for p in pairs for n in p if not (image_dir / n).is_file()})
    if missing:
        raise FileNotFoundError(f"{len(missing)} image(s) of the pairs file not found under {image_dir}: "
                                f"{', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
    cache_dir, rng = kwargs.pop("cache_dir", None), kwargs.pop("rng", 0)
    steps = _checked(**kwargs)
    # The settings of this run, to tell a finished pair from one computed with other settings.
    wanted = _settings_key(kwargs)
    out_dir.mkdir(parents=True, exist_ok=True)
    finished = {p for p in pairs if files[p].is_file() and _stored_key(files[p]) == wanted}
    todo = [p for p in pairs if p not in finished]
    done = skipped = 0
    bar = tqdm(pairs, desc="ctxmatch match", unit="pair", disable=not progress, dynamic_ncols=True)
    with _Prefetch([image_dir / n for p in todo for n in p], steps["features"], cache_dir) as feats:
        for name1, name2 in bar:
            path = files[(name1, name2)]
            bar.set_postfix_str(f"{name1} {name2}", refresh=False)
            if (name1, name2) in finished:
                skipped += 1
                if on_pair is not None:
                    on_pair(name1, name2, path, True)
                continue
            for stale in out_dir.glob(f".{path.name}.*.tmp"):  # left by a run killed while writing
                stale.unlink(missing_ok=True)
            f1, f2 = feats.get(image_dir / name1), feats.get(image_dir / name2)
            res = _match_features(f1, f2, rng=rng, **steps)
            save_result(res, path, name1=np.array(name1), name2=np.array(name2))
            done += 1
            if on_pair is not None:
                on_pair(name1, name2, path, False)
    return {"done": done, "skipped": skipped, "files": files}


class _Prefetch:
    """The features of a sequence of image uses (repeats allowed), extracted ahead in worker threads while the
    caller matches; an image's features stay in memory while it is used again within the next ``ahead`` uses."""

    def __init__(self, uses: list, config, cache_dir, *, ahead: int = 4):
        import os
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=max(1, min(2, os.cpu_count() or 1)))
        self._uses = deque(uses)
        self._futures: dict = {}
        self._ahead = ahead
        self._config, self._cache_dir = config, cache_dir

    def _extract(self, path):
        from .features import extract_features

        return extract_features(_read(path, str(path)), self._config, cache_dir=self._cache_dir)

    def _fill(self) -> None:
        for path in itertools.islice(self._uses, self._ahead):
            if path not in self._futures:
                self._futures[path] = self._pool.submit(self._extract, path)

    def get(self, path):
        """The features of the next use, ``path``."""
        if self._uses and self._uses[0] == path:
            self._uses.popleft()
        if path not in self._futures:
            self._futures[path] = self._pool.submit(self._extract, path)
        future = self._futures[path]
        if path not in itertools.islice(self._uses, self._ahead):
            del self._futures[path]
        self._fill()
        return future.result()

    def __enter__(self):
        self._fill()
        return self

    def __exit__(self, *exc):
        self._pool.shutdown(wait=True, cancel_futures=True)
        return False


def _settings_key(kwargs: Mapping) -> str:
    cfg = {
        "features": asdict(resolve_features(kwargs.get("features", "sift-rootsift"),
                                            max_keypoints=kwargs.get("max_keypoints"))),
        "blob": resolve_blob(kwargs.get("blob", "paper-best")).kwargs(),
        "filters": list(as_filter_list(kwargs.get("filters", ("dtm",)))),
        "filter_params": dict(kwargs.get("filter_params") or {}),
        "model": kwargs.get("model", "none"),
        "model_kind": kwargs.get("model_kind", "F"),
        "model_threshold": _threshold(kwargs.get("model_threshold")),
    }
    return json.dumps(cfg, sort_keys=True, default=str)


def _stored_key(path: Path) -> str | None:
    try:
        s = load_result(path)["settings"]
    except Exception:  # unreadable or foreign: recompute
        return None
    return json.dumps({k: s.get(k) for k in ("features", "blob", "filters", "filter_params", "model", "model_kind",
                                             "model_threshold")},
                      sort_keys=True, default=str)


# ----------------------------------------------------------------------------------------------- kernels


def kernels_ready() -> bool:
    """Whether the kernel cache (``$NUMBA_CACHE_DIR``, else ``cache_dir("numba")``) holds compiled kernels of blob
    matching and DTM for this code (on a new machine, or after an edit of kernel code, the first
    :func:`match_images` compiles them: about half a minute)."""
    import os

    from ._numerics.jit import kernel_sources_digest
    from .cache import cache_dir

    try:
        base = Path(os.environ.get("NUMBA_CACHE_DIR") or cache_dir("numba"))
    except OSError:
        return False
    root = base / f"{Path(__file__).resolve().parent.name}-{kernel_sources_digest()[:16]}"
    return all(any((root / part).glob("*.nbi")) for part in ("blob", "dtm"))


def warm_up(*, filters: Sequence[str] | str = ("dtm",), models: Sequence[str] = ("magsac",)) -> None:
    """Compile the kernels that :func:`match_images` runs, or load them from numba's cache, on a small pair
    (scikit-image's camera and a shifted crop of it); nothing is written but numba's cache.

    Parameters
    ----------
    filters : sequence of str or str
        As in :func:`match_images`.
    models : sequence of str
        Model steps, each run on the pair's features (extracted once).
    """
    pending = PairFeatures(*_small_pair(2), cache_dir=False)
    for model in models:
        pending.match(filters=filters, model=model)
