"""The planes of MOP and MOP+MiHo, one search after another (the authors' ``get_avg_hom``), and the plane of each
match (their ``cluster_assign``); :class:`PlanarClusters` is the result."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .homography import adjugate, best_rotation, normalise_scale
from .params import MihoParams, MopParams
from .ransac import Views, fit_plane

__all__ = ["PlanarClusters", "planar_clusters", "extract_planes", "assign_labels"]


@dataclass(frozen=True)
class PlanarClusters:
    """The planes found by MOP or MOP+MiHo and the plane of each match.

    Attributes
    ----------
    keep : ndarray of shape (K,), bool
        The matches assigned to a plane: ``matches[keep]``.
    labels : ndarray of shape (K,), int64
        The plane of each match, -1 for a rejected one.
    homographies : ndarray of shape (P, 3, 3), float64
        Image 1 -> image 2 map of each plane (``H[2, 2] = 1`` where it is not 0), in the order found.
    middle1, middle2 : ndarray of shape (P, 3, 3) or None
        MOP+MiHo: the maps of image 1 and of image 2 onto each plane's middle plane (the pre-rotation of
        image 2 included), so that ``homographies = middle2^-1 middle1`` up to scale; None for MOP.
    """

    keep: np.ndarray
    labels: np.ndarray
    homographies: np.ndarray
    middle1: np.ndarray | None = None
    middle2: np.ndarray | None = None


@dataclass(frozen=True)
class _Plane:
    H: np.ndarray  # (J, 3, 3): the plane's maps
    members: np.ndarray  # (n,) bool: the matches within ``loose_threshold`` when it was found
    ref: int  # the first point of its minimal sample, the sign reference


def extract_planes(views: Views, rng: np.random.Generator, prm: MopParams) -> list[_Plane]:
    """Planes found one search after another (:func:`.ransac.fit_plane`), MOP's outer loop.

    After each search the matches within ``strict_threshold`` of the plane leave the pool. A search fails when
    its plane has at most ``min_plane_size`` members (the plane is dropped) or removes at most
    ``min_new_inliers`` matches (the members of every plane so far then leave the pool too); more than
    ``max_failures`` failures in a row, or at most four matches left, end the loop.
    """
    n = len(views)
    removed = np.zeros(n, bool)
    covered = np.zeros(n, bool)
    seeds = np.zeros((n, 0), bool)
    planes: list[_Plane] = []
    failures = removed_count = 0
    while np.count_nonzero(removed) < n - 4:
        rest = np.flatnonzero(~removed)
        fit = fit_plane(views.take(rest), seeds[rest], rng, prm)
        runner_ups = fit.seeds[:, fit.seeds.any(axis=0)]
        seeds = np.zeros((n, runner_ups.shape[1]), bool)
        seeds[rest] = runner_ups
        members = np.zeros(n, bool)
        members[rest] = fit.loose
        removed[rest] = fit.strict
        covered |= members
        # The progress is counted before a stalled search widens the pool's removal (as the authors do).
        previous, removed_count = removed_count, np.count_nonzero(removed)
        too_small = np.count_nonzero(fit.loose) <= prm.min_plane_size
        stalled = removed_count - previous <= prm.min_new_inliers
        if too_small or stalled:
            failures += 1
            if failures > prm.max_failures:
                break
            if stalled:
                removed = covered.copy()
            if too_small:
                continue
        else:
            failures = 0
        planes.append(_Plane(fit.H, members, int(rest[fit.sample[0]])))
    return planes


def assign_labels(views: Views, planes: list[_Plane], prm: MopParams) -> np.ndarray:
    """The plane of each match, -1 if none (the authors' ``cluster_assign``).

    A match that is a member of some planes goes to the one it fits best (squared transfer error,
    :meth:`.ransac.Views.errors`) among its planes at least as large as the median-ranked of its (at most
    ``assign_top``) largest ones; a match of no plane goes to the plane it fits best if the error is within
    ``assign_threshold``, else it is rejected. Ties go to the plane found first.
    """
    n, P = len(views), len(planes)
    if P == 0 or n == 0:
        return np.full(n, -1, np.int64)
    err, _ = views.errors(np.stack([p.H for p in planes]), np.array([[p.ref] for p in planes]))
    member = np.stack([p.members for p in planes])
    size = member * np.count_nonzero(member, axis=1)[:, None]  # (P, n): plane size where a member, else 0
    ranked = -np.sort(-size, axis=0)
    k = np.count_nonzero(ranked[: prm.assign_top] > 0, axis=0)
    half = k / 2.0
    half[half == 1.0] = 1.5  # two planes: the median is the smaller one
    rank = np.maximum(np.ceil(half).astype(np.int64) - 1, 0)
    floor = ranked[rank, np.arange(n)]
    labels = np.argmin(np.where(size < floor, np.inf, err), axis=0).astype(np.int64)
    alone = ~member.any(axis=0)
    labels[alone] = np.argmin(err, axis=0)[alone]
    labels[alone & (err.min(axis=0) > prm.assign_threshold**2)] = -1
    return labels


def planar_clusters(p1: np.ndarray, p2: np.ndarray, rng: np.random.Generator, prm: MopParams) -> PlanarClusters:
    """MOP (``prm`` a :class:`MopParams`) or MOP+MiHo (a :class:`MihoParams`) on the matches ``p1 -> p2``
    ((K, 2) each, in the order the searches index)."""
    middle = isinstance(prm, MihoParams)
    R = np.eye(3)
    if middle and prm.rotations > 1 and len(p1) > 1:
        R = best_rotation(p1, p2, prm.rotations)
    views = Views(p1, p2 @ R[:2, :2].T, middle)
    planes = extract_planes(views, rng, prm)
    labels = assign_labels(views, planes, prm)
    if not planes:
        none = np.zeros((0, 3, 3))
        return PlanarClusters(labels >= 0, labels, none, none if middle else None, none if middle else None)
    H = np.stack([p.H for p in planes])
    if not middle:
        return PlanarClusters(labels >= 0, labels, normalise_scale(H[:, 0]))
    to_middle2 = H[:, 1] @ R
    H12 = adjugate(to_middle2)[0] @ H[:, 0]  # middle2^-1 middle1 up to scale
    return PlanarClusters(labels >= 0, labels, normalise_scale(H12), normalise_scale(H[:, 0]),
                          normalise_scale(to_middle2))
