"""What the peer spatial filters share (private): one wrapper around each filter's core, and its helpers.

A filter module writes its method as a *core*, ``core(ms, *, **params) -> keep``, on a prepared
:class:`MatchSet`, and :func:`match_filter` turns it into the public function with the common signature
``f(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None, **params)``.
The wrapper validates the common arguments (:func:`prepare`, with the helpers of
:mod:`ctxmatch_lib._numerics.validation`), maps the thresholds the core reads on the NNR scale to the scale of the
scores (:mod:`ctxmatch_lib._numerics.scores`), merges coincident rows once where the filter asks for it
(:func:`merge_coincident`), puts the rows in their canonical order (:func:`canonical_order`), calls the core on
them and spreads its decisions back to every row in the order given. The parameters every
filter shares are documented once here (:data:`DOCS`) and composed into each docstring (:func:`compose_doc`).
Keypoints are (x, y) pixels with the origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import inspect
import re
import types
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._numerics.scores import check_ratio, nnr_threshold, score_ratio
from .._numerics.docstrings import SHARED, compose_doc as _compose_doc
from .._numerics.order import canonical_order, spread_back
from .._numerics.validation import as_image_size, as_matches, as_points, as_scores

__all__ = ["MatchSet", "prepare", "knn_without_self", "zero_mean_unit_rms", "check_positive",
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
    """Indices (into ``points``) of the ``k`` nearest ``candidates`` of every query, the query excluded.

    ``candidates`` and ``queries`` (default: every point) are index arrays into ``points``; the answer has
    shape ``(len(queries), k')`` with ``k' = min(k, len(candidates) - 1)``, nearest first. A query that is
    itself a candidate is not its own neighbour.

    Ties (equal distances) are broken by the smaller index, not by the k-d tree's traversal order: that
    order is an implementation detail of the scipy build, and it changed the LPM and GLPM results between
    machines. Ties are frequent because many-to-many matches repeat a keypoint: the tree is built on the
    distinct locations, each standing for all the candidates there (smallest indices first), and each
    distinct query location is answered once; a row where two of the locations it needs lie at the same
    distance, or where more may lie at the k-th distance, takes every candidate within that distance and
    sorts them. Distances are recomputed here in one fixed arithmetic. Tested against a brute-force
    (distance, index) sort; on a 4040-candidate embedded pair it takes 2x the plain tree query.
    """
    queries = np.arange(len(points)) if queries is None else np.asarray(queries)
    cand = np.asarray(candidates)
    n = len(queries)
    kk = min(k, len(cand) - 1)
    if kk <= 0 or n == 0:
        return np.empty((n, 0), np.int64)
    pts = np.asarray(points, np.float64)
    # Work per distinct query location (duplicated queries share their neighbours, all but themselves):
    # the kk + 1 nearest candidates of each location by (distance, index), then each query drops itself
    # (or, when it is not among them, the last one).
    # Distinct candidate locations; the members of each, by index (``order[start[u]:start[u] + cnt[u]]``).
    locs, inv, cnt = np.unique(pts[cand], axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    if n == len(cand) and np.array_equal(queries, cand):  # the queries are the candidates: same locations
        qlocs, qinv = locs, inv
    else:
        qlocs, qinv = np.unique(pts[queries], axis=0, return_inverse=True)
        qinv = qinv.reshape(-1)
    kq = kk + 1

    def ranked(rows, jj, valid):
        """Candidates ``cand[jj]`` of the query locations ``qlocs[rows]`` sorted by (distance, index), the
        entries not ``valid`` last (squared distance ``inf``), with their squared distances."""
        idx = cand[jj]
        d2 = ((pts[idx] - qlocs[rows][:, None, :]) ** 2).sum(-1)
        d2[~valid] = np.inf
        key = np.lexsort((idx, d2), axis=1)
        return np.take_along_axis(idx, key, axis=1), np.take_along_axis(d2, key, axis=1)

    order = np.lexsort((cand, inv))
    start = np.r_[0, np.cumsum(cnt)[:-1]]
    # kq locations hold kq candidates at least; one more shows whether the last one needed is tied.
    nq = len(qlocs)
    mu = min(kq + 1, len(locs))
    _, L = cKDTree(locs).query(qlocs, k=mu)
    L = L.reshape(nq, mu)
    # Where the returned locations are strictly increasing in distance (recomputed here), the ranking by
    # (distance, index) is the members of each location in turn, by index: element t of a row lies in
    # location rank r[t].
    dl = ((locs[L] - qlocs[:, None, :]) ** 2).sum(-1)
    cum = np.cumsum(cnt[L], axis=1)
    t = np.arange(kq)
    r = (cum[:, :, None] <= t[None, None, :]).sum(axis=1)
    prev = np.where(r > 0, np.take_along_axis(cum, np.maximum(r - 1, 0), axis=1), 0)
    near_idx = cand[order[start[np.take_along_axis(L, r, axis=1)] + t[None, :] - prev]]
    # Exact unless two of the locations up to the one after the last needed tie (or the last needed one is
    # the last returned and more may lie at its distance): those rows take every candidate within the
    # distance of their kq-th neighbour and rank them by (distance, index).
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
        near_idx[unsure] = ranked(unsure, jj, ok)[0][:, :kq]
    lists = near_idx[qinv]
    is_self = lists == queries[:, None]
    drop = np.argsort(is_self, axis=1, kind="stable")
    return np.take_along_axis(lists, drop, axis=1)[:, :kk]


def zero_mean_unit_rms(p: np.ndarray) -> np.ndarray:
    """Zero mean and unit root-mean-square norm, the normalisation used by VFC and LLT (scale 1 if flat)."""
    c = p - p.mean(axis=0)
    scale = np.sqrt((c**2).sum() / max(len(p), 1))
    return c / scale if scale > 1e-12 else c


def coincident_groups(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group the matches whose keypoints coincide in both images (same coordinates, any keypoint index).

    SIFT keeps one keypoint per dominant orientation, so one correspondence can appear as several candidate
    rows on coincident keypoints, and a many-to-many matcher can repeat a row; a filter that counts such
    copies as distinct matches lets a wrong correspondence support itself through its own copies.

    Parameters
    ----------
    x, y : ndarray of shape (K, 2)
        Image-1 and image-2 keypoint of each match, (x, y) pixels, origin at the centre of the top-left
        pixel. Coincidence is exact equality of the coordinates.

    Returns
    -------
    first : ndarray of shape (G,) int64
        The first row of each group, increasing: ``x[first], y[first]`` are the distinct matches in input
        order.
    group : ndarray of shape (K,) int64
        The group of every row (``first[group[i]]`` is the first copy of row ``i``).
    """
    n = len(x)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    _, first, group = np.unique(np.c_[x, y], axis=0, return_index=True, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return first[order].astype(np.int64), rank[group]


def merge_coincident(ms: MatchSet) -> tuple[np.ndarray, np.ndarray] | None:
    """One row per group of coincident matches (see :func:`coincident_groups`), and the map back.

    Returns None when no two matches coincide, so a filter's result on an input without copies is exactly
    what it was. Otherwise ``(rows, group)``: ``rows`` (G,) picks, for each group in the order of its first
    copy, its best-scored copy (lowest score, the first one on ties), whose keypoint indices and shapes then
    stand for the group; ``group`` (K,) is the position in ``rows`` of every input row. A filter decides
    ``matches[rows]`` and maps the decision back with ``keep[group]``, so every copy gets the decision of its
    group and no copy counts in the support or neighbourhood of another.
    """
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


# ---------------------------------------------------------------------------------------------------------
# Shared documentation, composed into the filters' docstrings (one way of scipy's ``_lib/doccer``).

#: Parameter and section texts shared by the filters. A docstring line holding only ``%(name)s`` is replaced
#: by ``DOCS[name]``, indented as that line; ``{label}`` in an entry is the filter's name (``match_filter``); an
#: entry may itself be made of ``%(name)s`` lines.
DOCS: dict[str, str] = {
    **SHARED,
    "scores_unused": """\
scores : ndarray of shape (K,) or None
    Unused by {label} (validated only).""",
    "nnr_scale": """\
Thresholds on the NNR ratio ({thresholds}) are read on the scale of the scores: the
blob ratio they carry (``blob_matching(...).scores``; ``"D>="`` scores are the NNR ratio
``r``, ``"D+>="`` and ``"D+"`` scores ``r / (1 + r)``, where a threshold ``t`` reads
``t / (1 + t)``), else ``"D>="``, the ratio of Lowe's test (OpenCV's). A plain array whose
scores all lie at or below 1/2 (the D+ range) and that the ``"D>="`` reading would keep whole
warns (``UserWarning``); ``ctxmatch_lib.filters.nnr_scores(scores, ratio)`` tags one.""",
    "image_sizes": """\
image_size1, image_size2 : (int, int)
    Image sizes (width, height), validated only.""",
    "shapes_unused": """\
shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
    Unused.""",
    "common_unused": "%(kpts)s\n%(matches)s\n%(scores_unused)s\n%(image_sizes)s\n%(shapes_unused)s",
    "merge_option": """\
merge_coincident : bool, default True
    Decide coincident rows as one match (see Notes); ``False`` decides every row as given, as the
    authors' code does.""",
    "keep": """\
keep : ndarray of shape (K,), bool
    The kept matches: ``matches[keep]``.""",
    "coincident": """\
Coincident candidates: rows whose keypoints coincide in both images (SIFT's orientation copies of one
correspondence, on distinct keypoint indices, or a row the matcher repeated) are one match here. The filter
decides the distinct matches (each with the best score of its copies) and gives every copy the decision of
its match, so a wrong correspondence cannot support itself through its own copies. The result on inputs
without coincident rows is unchanged.""",
}

def compose_doc(doc: str | None, **fields) -> str | None:
    """``doc`` with every line that holds only ``%(name)s`` replaced by :data:`DOCS` ``[name]`` (see
    :func:`ctxmatch_lib._numerics.docstrings.compose_doc`).

    Examples
    --------
    >>> print(compose_doc('''Parameters
    ...     ----------
    ...     %(scores_unused)s''', label="BM"))
    Parameters
        ----------
        scores : ndarray of shape (K,) or None
            Unused by BM (validated only).
    """
    return _compose_doc(doc, DOCS, **fields)


# ---------------------------------------------------------------------------------------------------------
# The wrapper.

_P = inspect.Parameter
_REQUIRED = _P.empty


def _common_parameters(scores_default) -> list[inspect.Parameter]:
    pos, kw = _P.POSITIONAL_OR_KEYWORD, _P.KEYWORD_ONLY
    return [_P("kpts1", pos), _P("kpts2", pos), _P("matches", pos), _P("scores", pos, default=scores_default),
            _P("image_size1", kw), _P("image_size2", kw), _P("shapes1", kw, default=None),
            _P("shapes2", kw, default=None)]


def match_filter(*, label: str, merge: bool | str = False, one_to_one: bool = False, nnr: tuple[str, ...] = (),
                 ratio_param: str | None = None, shapes: str = "match", scores_required: bool = False):
    """Decorator: the public filter with the common signature around ``core(ms, *, **params) -> keep``.

    The public function takes ``(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2,
    shapes1=None, shapes2=None)`` followed by the core's keyword parameters (with their defaults and
    annotations; ``inspect.signature`` and ``help`` show them), and

    1. validates the common arguments (:func:`prepare`; ``ValueError`` naming the argument);
    2. maps the core's parameters named in ``nnr`` (thresholds on the NNR ratio, checked positive) to the
       scale of the scores: the ratio named by the public parameter ``ratio_param`` when given, else the one
       the scores carry (:func:`ctxmatch_lib._numerics.scores.score_ratio`), else ``"D>="``, with a ``UserWarning``
       where that default keeps every row although every score lies in the D+ range (at most 1/2); a
       ratio given that contradicts the scores' own is a ``ValueError``;
    3. sorts the rows into their canonical order (:func:`canonical_order`: score, keypoint coordinates, keypoint
       indices), so that the core sees the same rows in the same order whatever order they were given in;
    4. merges coincident rows (:func:`merge_coincident`) when ``merge`` is True, or when the public boolean
       parameter named by ``merge`` (default True) is; the core then decides the distinct rows and every
       copy gets the decision of its group; with ``one_to_one`` only the first of the rows that repeat one
       keypoint pair (:func:`first_of_pair`) is kept, so that a one-to-one output stays one-to-one;
    5. returns the core's mask over the rows given, in their order (:func:`spread_back`; rows equal in every
       key of the canonical order get one decision). Every filter is thus equivariant: permuting the rows
       permutes the mask, and changes nothing else.

    ``shapes``: ``"match"`` (checked and gathered per match for the core, ``ms.A1`` / ``ms.A2``), ``"check"``
    (checked only, for a core that reads none) or ``"both"`` (as ``"match"``, and one without the other is a
    ``ValueError``). The docstring is the core's, composed with :func:`compose_doc` (``{label}`` is ``label``,
    ``{thresholds}`` the ``nnr`` parameters). The public function is made in the core's module (its globals),
    so doctest and the docs find it there; the core stays reachable as ``.core``.
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
        sig = inspect.Signature(_common_parameters(_REQUIRED if scores_required else None) + own + extra,
                                return_annotation=csig.return_annotation)
        core_names = [p.name for p in own]
        name = core.__name__

        def run(args, kwargs):
            try:
                bound = sig.bind(*args, **kwargs)
            except TypeError as e:
                raise TypeError(f"{name}() {e}") from None
            bound.apply_defaults()
            a = bound.arguments
            sh1, sh2 = a["shapes1"], a["shapes2"]
            if shapes == "check":
                ms = prepare(a["kpts1"], a["kpts2"], a["matches"], a["scores"], a["image_size1"], a["image_size2"])
                _as_shapes(sh1, np.shape(a["kpts1"])[0], "shapes1")
                _as_shapes(sh2, np.shape(a["kpts2"])[0], "shapes2")
            else:
                ms = prepare(a["kpts1"], a["kpts2"], a["matches"], a["scores"], a["image_size1"], a["image_size2"],
                             sh1, sh2)
            if shapes == "both" and (sh1 is None) != (sh2 is None):
                raise ValueError("shapes1 and shapes2 must be given together")
            params = {k: a[k] for k in core_names}
            if nnr:
                checked = {k: check_positive(params[k], k) for k in nnr}
                ratio = _scale(a["scores"], ms, a[ratio_param] if ratio_param else None, ratio_param, checked,
                               name)
                params.update({k: nnr_threshold(v, ratio) for k, v in checked.items()})
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
    """The blob ratio the scores of a filter are read with (see :func:`match_filter`, step 2)."""
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
