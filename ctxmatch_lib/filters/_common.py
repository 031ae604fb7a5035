"""Shared machinery of the spatial filters (private): the wrapper :func:`match_filter` and its helpers.

A filter module writes its method as a core ``core(ms, **params) -> keep`` on a validated :class:`MatchSet`;
:func:`match_filter` makes it the public function with the common signature (:mod:`ctxmatch_lib.filters`) and
composes its docstring from :data:`DOCS`.
"""

from __future__ import annotations

import inspect
import types
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._numerics.scores import check_ratio, nnr_threshold, score_ratio
from .._numerics.docstrings import SHARED, compose_doc as _compose_doc
from .._numerics.order import canonical_order, spread_back
from .._numerics.validation import as_image_size, as_matches, as_points, as_scores

__all__ = ["MatchSet", "prepare", "knn_without_self", "zero_mean_unit_rms", "inverse_2x2", "check_positive",
           "coincident_groups", "merge_coincident", "first_of_pair", "canonical_order", "spread_back",
           "match_filter", "compose_doc", "DOCS"]


@dataclass(frozen=True)
class MatchSet:
    """The validated input of a filter, one row per match."""

    x: np.ndarray  # (K, 2) keypoint of each match in image 1, (x, y) pixels
    y: np.ndarray  # (K, 2) keypoint of each match in image 2
    matches: np.ndarray  # (K, 2) int64
    scores: np.ndarray  # (K,) lower is better, zeros when not given
    size1: tuple[int, int]  # (width, height)
    size2: tuple[int, int]
    A1: np.ndarray | None  # (K, 2, 2) affine shape of the image-1 keypoint of each match, or None
    A2: np.ndarray | None

    def __len__(self) -> int:
        return len(self.matches)

    def take(self, rows: np.ndarray) -> MatchSet:
        """The match set restricted to ``rows`` (as if only those matches had been given)."""
        return MatchSet(self.x[rows], self.y[rows], self.matches[rows], self.scores[rows], self.size1, self.size2,
                        None if self.A1 is None else self.A1[rows], None if self.A2 is None else self.A2[rows])


def _as_shapes(shapes, n: int, name: str) -> np.ndarray | None:
    if shapes is None:
        return None
    arr = np.asarray(shapes, dtype=np.float64)
    if arr.size == 0 and n == 0:
        return arr.reshape(0, 2, 2)
    if arr.shape != (n, 2, 2):
        raise ValueError(f"{name} must have shape ({n}, 2, 2), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1=None, shapes2=None) -> MatchSet:
    """Validate the common filter arguments (``ValueError`` naming the argument on bad input)."""
    k1 = as_points(kpts1, "kpts1")
    k2 = as_points(kpts2, "kpts2")
    m = as_matches(matches, len(k1), len(k2))
    s = as_scores(scores, len(m))
    size1 = as_image_size(image_size1, "image_size1")
    size2 = as_image_size(image_size2, "image_size2")
    sh1 = _as_shapes(shapes1, len(k1), "shapes1")
    sh2 = _as_shapes(shapes2, len(k2), "shapes2")
    A1 = A2 = None
    if sh1 is not None and sh2 is not None:
        A1, A2 = sh1[m[:, 0]], sh2[m[:, 1]]
    return MatchSet(k1[m[:, 0]], k2[m[:, 1]], m, s, size1, size2, A1, A2)


def check_positive(value, name: str, *, integer: bool = False, allow_zero: bool = False):
    """Return ``value`` if it is a positive number (an int when ``integer``), else raise ``ValueError``."""
    ok = np.isscalar(value) and np.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if integer:
        ok = ok and float(value) == int(value)
    if not ok:
        kind = "integer" if integer else "number"
        sign = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be a {sign} {kind}, got {value!r}")
    return int(value) if integer else float(value)


def knn_without_self(points: np.ndarray, candidates: np.ndarray, k: int, queries: np.ndarray | None = None):
    """The ``k`` nearest ``candidates`` of every query (default: every point), the query excluded.

    Indices into ``points``, shape ``(len(queries), min(k, len(candidates) - 1))``, nearest first; ties go
    to the smaller index, not to the k-d tree's traversal order (which depends on the scipy build).
    """
    queries = np.arange(len(points)) if queries is None else np.asarray(queries)
    cand = np.asarray(candidates)
    n = len(queries)
    kk = min(k, len(cand) - 1)
    if kk <= 0 or n == 0:
        return np.empty((n, 0), np.int64)
    pts = np.asarray(points, np.float64)
    # Members of distinct candidate location u, by index: ``order[start[u]:start[u] + cnt[u]]``.
    locs, inv, cnt = np.unique(pts[cand], axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    if n == len(cand) and np.array_equal(queries, cand):  # the queries are the candidates: same locations
        qlocs, qinv = locs, inv
    else:
        qlocs, qinv = np.unique(pts[queries], axis=0, return_inverse=True)
        qinv = qinv.reshape(-1)
    kq = kk + 1
    order = np.lexsort((cand, inv))
    start = np.r_[0, np.cumsum(cnt)[:-1]]
    # kq locations hold kq candidates at least; one more shows whether the last one needed is tied.
    nq = len(qlocs)
    mu = min(kq + 1, len(locs))
    _, L = cKDTree(locs).query(qlocs, k=mu)
    L = L.reshape(nq, mu)
    # Without ties the ranking is the members of each location in turn: element t lies in location rank r[t].
    dl = ((locs[L] - qlocs[:, None, :]) ** 2).sum(-1)
    cum = np.cumsum(cnt[L], axis=1)
    t = np.arange(kq)
    r = (cum[:, :, None] <= t[None, None, :]).sum(axis=1)
    prev = np.where(r > 0, np.take_along_axis(cum, np.maximum(r - 1, 0), axis=1), 0)
    near_idx = cand[order[start[np.take_along_axis(L, r, axis=1)] + t[None, :] - prev]]
    # Rows with possible ties rank every candidate within the distance of their kq-th neighbour.
    last = r[:, -1]
    tie = np.diff(dl, axis=1) <= dl[:, 1:] * 1e-12
    first_tie = np.where(tie.any(axis=1), tie.argmax(axis=1), mu) if mu > 1 else np.full(nq, mu)
    unsure = np.flatnonzero((first_tie <= last) | ((last == mu - 1) & (mu < len(locs))))
    if len(unsure):
        d_k = dl[unsure, last[unsure]]
        radius = np.sqrt(d_k) * (1 + 1e-9) + 1e-12
        balls = cKDTree(pts[cand]).query_ball_point(qlocs[unsure], radius)
        lens = np.array([len(b) for b in balls])
        width = max(int(lens.max()), kq)
        jj = np.zeros((len(unsure), width), np.int64)
        ok = np.arange(width)[None, :] < lens[:, None]
        jj[ok] = np.concatenate([np.asarray(b, np.int64) for b in balls])
        # Ranked by (distance, index), the padding last.
        idx = cand[jj]
        d2 = ((pts[idx] - qlocs[unsure][:, None, :]) ** 2).sum(-1)
        d2[~ok] = np.inf
        near_idx[unsure] = np.take_along_axis(idx, np.lexsort((idx, d2), axis=1), axis=1)[:, :kq]
    lists = near_idx[qinv]
    is_self = lists == queries[:, None]
    drop = np.argsort(is_self, axis=1, kind="stable")
    return np.take_along_axis(lists, drop, axis=1)[:, :kk]


def zero_mean_unit_rms(p: np.ndarray) -> np.ndarray:
    """Zero mean and unit root-mean-square norm, the normalisation used by VFC and LLT (scale 1 if flat)."""
    c = p - p.mean(axis=0)
    scale = np.sqrt((c**2).sum() / max(len(p), 1))
    return c / scale if scale > 1e-12 else c


def inverse_2x2(A: np.ndarray) -> np.ndarray:
    """Inverses of the (K, 2, 2) matrices ``A`` by the adjugate; inf or NaN where ``A`` is singular."""
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    inv = np.stack([np.stack([A[:, 1, 1], -A[:, 0, 1]], -1), np.stack([-A[:, 1, 0], A[:, 0, 0]], -1)], 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return inv / det[:, None, None]


def coincident_groups(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group the matches whose keypoints ``x``, ``y`` (K, 2) coincide exactly in both images (:data:`DOCS`
    ``["coincident"]``): ``first`` (G,), the first row of each group, increasing, and ``group`` (K,)."""
    if len(x) == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    _, first, group = np.unique(np.c_[x, y], axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return first[order].astype(np.int64), rank[group]


def merge_coincident(ms: MatchSet) -> tuple[np.ndarray, np.ndarray] | None:
    """None when no two matches coincide (:func:`coincident_groups`), else ``(rows, group)``: ``rows`` (G,),
    the best-scored copy of each group (the first on ties), and ``group`` (K,), each row's position in
    ``rows``. The core decides ``matches[rows]`` and ``keep[group]`` maps the decision back."""
    first, group = coincident_groups(ms.x, ms.y)
    if len(first) == len(ms):
        return None
    order = np.lexsort((np.arange(len(ms)), ms.scores, group))
    starts = np.r_[0, np.flatnonzero(np.diff(group[order])) + 1]
    return order[starts], group  # groups are numbered 0..G-1 in order of first copy


def first_of_pair(ms: MatchSet) -> np.ndarray:
    """``(K,)`` bool: the best-scored row (the first on ties) of every set of rows repeating one keypoint pair."""
    m = ms.matches
    order = np.lexsort((np.arange(len(m)), ms.scores, m[:, 1], m[:, 0]))
    first = np.zeros(len(m), bool)
    first[order[np.r_[True, (np.diff(m[order], axis=0) != 0).any(axis=1)]]] = True
    return first


#: Parameter and section texts shared by the filters' docstrings (see :func:`compose_doc`); ``{label}`` is
#: the filter's name, ``{thresholds}`` its NNR thresholds (:func:`match_filter`).
DOCS: dict[str, str] = {
    **SHARED,
    "scores_unused": """\
scores : ndarray of shape (K,) or None
    Unused by {label} (validated only).""",
    "nnr_scale": """\
Thresholds on the NNR ratio ({thresholds}) are read on the scores' scale: the blob ratio they
carry (``"D+>="`` and ``"D+"`` scores are ``r / (1 + r)``, so ``t`` reads ``t / (1 + t)``), else
``"D>="`` (Lowe's ratio), with a ``UserWarning`` when every score is at most 1/2 and would be
kept; ``ctxmatch_lib.filters.nnr_scores(scores, ratio)`` tags a plain array.""",
    "image_sizes": """\
image_size1, image_size2 : (int, int)
    Image sizes (width, height), validated only.""",
    "shapes_unused": """\
shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
    Unused.""",
    "common_unused": "%(kpts)s\n%(matches)s\n%(scores_unused)s\n%(image_sizes)s\n%(shapes_unused)s",
    # Section openings: the Parameters of every filter start with the keypoints and matches.
    "parameters": "Parameters\n----------\n%(kpts)s\n%(matches)s",
    "parameters_unused": "Parameters\n----------\n%(common_unused)s",
    "merge_option": """\
merge_coincident : bool, default True
    Decide coincident rows as one match (see Notes); ``False`` decides every row as given, as the
    authors' code does.""",
    "keep": """\
keep : ndarray of shape (K,), bool
    The kept matches: ``matches[keep]``.""",
    "coincident": """\
Rows whose keypoints coincide in both images (SIFT's orientation copies, repeated rows) are decided
as one match, with the best score of its copies, so a wrong correspondence cannot support itself
through its own copies.""",
    # The Returns section and the Notes opening of the filters that decide coincident rows as one match.
    "keep_coincident": "Returns\n-------\n%(keep)s\n\nNotes\n-----\n%(coincident)s",
    "merge_keep_coincident": "%(merge_option)s\n\n%(keep_coincident)s",
    # The EM of VFC and LLT: a Gaussian-inlier / uniform-outlier mixture on normalised coordinates.
    "em_mixture": """\
beta : float, default 0.1
    Width of the Gaussian kernel ``exp(-beta |x - c|^2)`` on normalised coordinates.
tau : float, default 0.75
    Posterior threshold of an inlier and of the inlier-fraction update (``conf.theta``).
gamma, a : float, default 0.9 and 10
    Initial inlier fraction (updates clipped to [0.05, 0.95]) and volume of the uniform outliers.""",
    "em_rng": """\
min_p : float, default 1e-5
    Posterior floor of the M-step, for a well-conditioned system.
rng : None, int or numpy.random.Generator, default 0
    Seed of the control-point draw; the fixed default makes the result deterministic.""",
}

def compose_doc(doc: str | None, **fields) -> str | None:
    """``doc`` with every line that holds only ``%(name)s`` replaced by :data:`DOCS` ``[name]``, indented alike.

    >>> print(compose_doc("    %(scores_unused)s", label="BM"))
        scores : ndarray of shape (K,) or None
            Unused by BM (validated only).
    """
    return _compose_doc(doc, DOCS, **fields)


_P = inspect.Parameter


def _common_parameters(scores_default) -> list[inspect.Parameter]:
    pos, kw = _P.POSITIONAL_OR_KEYWORD, _P.KEYWORD_ONLY
    return [_P("kpts1", pos), _P("kpts2", pos), _P("matches", pos), _P("scores", pos, default=scores_default),
            _P("image_size1", kw), _P("image_size2", kw), _P("shapes1", kw, default=None),
            _P("shapes2", kw, default=None)]


def match_filter(*, label: str, merge: bool | str = False, one_to_one: bool = False, nnr: tuple[str, ...] = (),
                 ratio_param: str | None = None, shapes: str = "match", scores_required: bool = False,
                 positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = (), integer: tuple[str, ...] = ()):
    """Decorator: the public filter with the common signature around ``core(ms, *, **params) -> keep``.

    The public function (1) validates the common arguments (:func:`prepare`) and, by :func:`check_positive`,
    the core's parameters named in ``positive``, ``non_negative``, ``integer`` (positive) and ``nnr``; (2)
    reads the NNR thresholds named in ``nnr`` on the scores' scale (:func:`_scale`); (3) sorts the rows
    canonically; (4) merges coincident rows when ``merge`` is True or names a public boolean parameter
    (``one_to_one``: keep :func:`first_of_pair` only); (5) spreads the mask back. ``shapes``: ``"match"``
    (``ms.A1``/``ms.A2``), ``"check"`` (validated only) or ``"both"`` (both or neither). Docstring: the
    core's, composed.
    """
    if shapes not in ("match", "check", "both"):
        raise ValueError(f"shapes must be 'match', 'check' or 'both', got {shapes!r}")

    def wrap(core: Callable) -> Callable:
        csig = inspect.signature(core)
        own = list(csig.parameters.values())[1:]  # the first one is the MatchSet
        extra = []
        if ratio_param is not None:
            extra.append(_P(ratio_param, _P.KEYWORD_ONLY, default=None, annotation="str | None"))
        if isinstance(merge, str):
            extra.append(_P(merge, _P.KEYWORD_ONLY, default=True, annotation="bool"))
        sig = inspect.Signature(_common_parameters(_P.empty if scores_required else None) + own + extra,
                                return_annotation=csig.return_annotation)
        core_names = [p.name for p in own]
        name = core.__name__
        checks = {**dict.fromkeys(positive + nnr, {}), **dict.fromkeys(non_negative, {"allow_zero": True}),
                  **dict.fromkeys(integer, {"integer": True})}
        if not set(checks) <= set(core_names):
            raise TypeError(f"{name} has no parameter {sorted(set(checks) - set(core_names))}")

        def run(args, kwargs):
            try:
                bound = sig.bind(*args, **kwargs)
            except TypeError as e:
                raise TypeError(f"{name}() {e}") from None
            bound.apply_defaults()
            a = bound.arguments
            sh1, sh2 = a["shapes1"], a["shapes2"]
            ms = prepare(a["kpts1"], a["kpts2"], a["matches"], a["scores"], a["image_size1"], a["image_size2"],
                         sh1, sh2)
            if shapes == "check":
                ms = replace(ms, A1=None, A2=None)  # validated only
            if shapes == "both" and (sh1 is None) != (sh2 is None):
                raise ValueError("shapes1 and shapes2 must be given together")
            params = {k: check_positive(a[k], k, **checks[k]) if k in checks else a[k] for k in core_names}
            if nnr:
                given = a[ratio_param] if ratio_param else None
                ratio = _scale(a["scores"], ms, given, ratio_param, {k: params[k] for k in nnr}, name)
                params.update({k: nnr_threshold(params[k], ratio) for k in nnr})
            order, twins = canonical_order(ms.x, ms.y, ms.matches, ms.scores)
            ms = ms.take(order)  # scores were read for their scale above; the core sees the canonical order
            merged = merge_coincident(ms) if (a[merge] if isinstance(merge, str) else merge) else None
            if merged is None:
                keep = core(ms, **params)
            else:
                rows, group = merged
                keep = core(ms.take(rows), **params)[group]
                keep = keep & first_of_pair(ms) if one_to_one else keep
            return spread_back(keep, order, twins)

        def public(*args, **kwargs):  # refers to no global: it runs in the core's module (see below)
            return run(args, kwargs)

        f = types.FunctionType(public.__code__, core.__globals__, name, None, public.__closure__)
        f.__qualname__, f.__module__, f.__signature__, f.core = name, core.__module__, sig, core
        f.__doc__ = compose_doc(core.__doc__, label=label, thresholds=", ".join(f"``{k}``" for k in nnr))
        if ratio_param is not None:
            f.uses_blob_ratio = True  # the evaluation engine passes the blob setup's ratio (steps.run_filter)
        if nnr:
            f.nnr_thresholds = tuple(nnr)
        return f

    return wrap


def _scale(scores, ms: MatchSet, given, given_name, thresholds: dict, name: str) -> str:
    """The blob ratio the scores are read with: ``given`` (``ValueError`` if it contradicts the scores'),
    the carried one, else ``"D>="`` (``UserWarning`` where every score is at most 1/2, the D+ range, and the
    thresholds keep every row)."""
    carried = score_ratio(scores)
    if given is not None:
        check_ratio(given, given_name)
        if carried is not None and carried != given:
            raise ValueError(f"{given_name}={given!r} contradicts the scores, which blob matching made with "
                             f"ratio {carried!r}; leave {given_name} out or pass the same")
        return given
    if carried is not None:
        return carried
    if scores is not None and len(ms) and ms.scores.max() <= 0.5 and all(
            ms.scores.max() <= t for t in thresholds.values()):
        told = ", ".join(f"{k}={v:g}" for k, v in thresholds.items())
        warnings.warn(f"{name}: every score is at most 0.5, the range of D+ / D+>= blob scores (r / (1 + r)), "
                      f"and read as NNR ratios (D>=, the default) the thresholds ({told}) keep every row; say "
                      "which blob ratio made the scores: " + (f"pass {given_name}=..., or " if given_name else "")
                      + "pass ctxmatch_lib.filters.nnr_scores(scores, ratio) (blob_matching's scores carry it)",
                      UserWarning, stacklevel=4)
    return "D>="
