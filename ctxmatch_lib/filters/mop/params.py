"""The parameters of MOP and MOP+MiHo: their defaults, as in the authors' code, and the ``**params`` overrides.

Every field names the authors' parameter it stands for (fb82/MiHo, ``miho.all_params()`` and the keyword
defaults of ``ransac_middle`` in ``src/miho_other.py`` for MOP and ``src/miho.py`` for MOP+MiHo).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from .._common import check_positive

__all__ = ["MopParams", "MihoParams", "MOP_DEFAULTS", "MIHO_DEFAULTS", "resolve_params"]


@dataclass(frozen=True)
class MopParams:
    """The parameters of MOP (``miho_unduplex``); the authors' names in brackets.

    Attributes
    ----------
    strict_threshold : float, default 7
        Pixels [``th_in``]: the matches of a plane within it leave the pool before the next plane is searched.
    loose_threshold : float, default 15
        Pixels [``th_out``]: the support of a hypothesis and the members of a plane.
    max_iterations : int, default 2000
        Hypotheses per plane at most [``max_iter``].
    min_iterations : int, default 50
        Hypotheses per plane at least, and draws per hypothesis for a well-spread sample [``min_iter``].
    confidence : float, default 0.9
        RANSAC's stopping confidence [``p``]; the count ``log(1 - p) / log(1 - w^4)`` is evaluated in float32, as
        the authors' (``-inf`` for an inlier ratio ``w`` below about 1.3 %: the search stops past
        ``min_iterations``).
    min_singular_value : float, default 0.05
        A minimal sample is fitted when the second-smallest singular value of its normalised DLT system exceeds
        it [``svd_th``].
    buffers : int, default 5
        Best, mostly disjoint inlier sets kept per search; all but the best seed the next search [``buffers``].
    reject_reflections : bool, default True
        Minimal samples must keep the orientation of their four triangles [``check_reflection``]; True is the
        "MOP*" setting of the authors' demo, False their library default.
    batch_budget : int, default 100000
        Points times hypotheses scored per batch: ``batch_budget // n`` hypotheses [``par_value``].
    min_plane_size : int, default 12
        A plane needs more members than this [``min_plane_pts``].
    min_new_inliers : int, default 6
        A search must remove more matches than this from the pool to count as progress [``min_pt_gap``].
    max_failures : int, default 3
        Consecutive failed searches tolerated [``max_fail_count``].
    min_sample_spacing : float, default 15
        Pixels: the points of a minimal sample are farther apart than this in both images [``th_grid``].
    assign_top : int, default 5
        A match in several planes goes to the best-fitting one among the planes at least as large as the
        median of its (at most ``assign_top``) largest planes [``median_th``].
    assign_threshold : float, default 15
        Pixels: a match in no plane goes to the best-fitting plane within it, else is rejected [``err_th``].
    """

    strict_threshold: float = 7.0
    loose_threshold: float = 15.0
    max_iterations: int = 2000
    min_iterations: int = 50
    confidence: float = 0.9
    min_singular_value: float = 0.05
    buffers: int = 5
    reject_reflections: bool = True
    batch_budget: int = 100_000
    min_plane_size: int = 12
    min_new_inliers: int = 6
    max_failures: int = 3
    min_sample_spacing: float = 15.0
    assign_top: int = 5
    assign_threshold: float = 15.0


@dataclass(frozen=True)
class MihoParams(MopParams):
    """The parameters of MOP+MiHo (``miho_duplex``): :class:`MopParams` with the duplex defaults, and

    Attributes
    ----------
    rotations : int, default 4
        Candidate rotations of image 2 (multiples of ``360 / rotations`` degrees) before the search; 1 or less
        disables the pre-rotation [``rot_check``].
    """

    min_plane_size: int = 8
    min_new_inliers: int = 4
    rotations: int = 4


MOP_DEFAULTS = MopParams()
MIHO_DEFAULTS = MihoParams()

_POSITIVE = ("strict_threshold", "loose_threshold", "min_sample_spacing", "assign_threshold")
_POSITIVE_INT = ("max_iterations", "min_iterations", "buffers", "batch_budget")
_NON_NEGATIVE_INT = ("min_plane_size", "min_new_inliers", "max_failures", "assign_top", "rotations")


def resolve_params(defaults: MopParams, overrides: dict, name: str) -> MopParams:
    """``defaults`` with ``overrides`` applied and checked.

    Raises
    ------
    ValueError
        For a name that is not a field of ``defaults`` (the message lists the valid ones) or a bad value.
    """
    known = [f.name for f in fields(defaults)]
    unknown = sorted(set(overrides) - set(known))
    if unknown:
        raise ValueError(f"{name} got unknown parameter(s) {unknown}; valid parameters: {', '.join(known)}")
    out = replace(defaults, **overrides)
    checked = {}
    for key in overrides:
        value = getattr(out, key)
        if key in _POSITIVE:
            checked[key] = check_positive(value, key)
        elif key in _POSITIVE_INT:
            checked[key] = check_positive(value, key, integer=True)
        elif key in _NON_NEGATIVE_INT:
            checked[key] = check_positive(value, key, integer=True, allow_zero=True)
        elif key == "min_singular_value":
            checked[key] = check_positive(value, key, allow_zero=True)
        elif key == "confidence":
            if not (isinstance(value, (int, float)) and 0.0 < value < 1.0):
                raise ValueError(f"confidence must lie in (0, 1), got {value!r}")
            checked[key] = float(value)
        elif key == "reject_reflections":
            if not isinstance(value, bool):
                raise ValueError(f"reject_reflections must be a bool, got {value!r}")
    out = replace(out, **checked)
    if out.strict_threshold > out.loose_threshold:
        raise ValueError(f"strict_threshold ({out.strict_threshold:g}) must not exceed loose_threshold "
                         f"({out.loose_threshold:g})")
    return out
