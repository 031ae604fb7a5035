"""MOP and MOP+MiHo: matches clustered on Multiple Overlapping Planes, optionally through Middle Homographies
(Bellavia, Zhao, Morelli, Remondino, "Image Matching Filtering and Refinement by Planes and Beyond",
arXiv 2411.09484).

MOP (:func:`mop_clusters`; :func:`mop_filter`, its keep mask) searches planes one after another by a
RANSAC over four-match samples whose homography maps image 1 onto image 2; a match within the strict threshold
of a plane leaves the pool, and the search goes on until it fails repeatedly. Each match then goes to the plane
it fits best among the large planes it belongs to, or to none (rejected). MOP+MiHo (:func:`mop_miho_clusters`,
:func:`mop_miho_filter`) fits, instead of one homography per plane, two homographies mapping image 1 and
image 2 onto the plane of the middle points ``(p1 + p2) / 2``, which shares the distortion between the two
images, after a pre-rotation of image 2 by the quarter turn that
best keeps the middle distances between the image distances.

This is a numpy re-implementation of the authors' PyTorch code (fb82/MiHo: ``src/miho_other.py``,
``miho_unduplex``, for MOP; ``src/miho.py``, ``miho_duplex``, for MOP+MiHo) with their default parameters
(:mod:`.params`) and the demo's "MOP*" setting (no mirror samples). Its RANSAC draws its own samples
(``numpy.random.default_rng(seed)``), so it reproduces the authors' behaviour, not their samples; the
geometry is computed in float64 where the authors compute in float32, except RANSAC's stopping count, which
is evaluated in float32 as theirs (:func:`.ransac._iterations_needed`): its rounding to ``-inf`` when the best
set holds less than about 1.3 % of the pool is what ends the searches among outliers after ``min_iterations``
hypotheses, and with it the outer loop, on heavily contaminated candidate sets. Left out: the GPU execution (the
authors' batches of ``batch_budget // n`` hypotheses keep their role in the search: sorted offers to the
buffers and the stopping test at the end of each batch; several batches are scored at once in numpy), the
assignment variants (``cluster_assign_base``, ``cluster_assign_other``), the VSAC and "half" options of the
demo, the NCC keypoint refinement and the plotting.

One module per job: :mod:`.homography` (the batched fits and errors), :mod:`.ransac` (one plane search),
:mod:`.clusters` (the search loop and the assignment) and :mod:`.params` (the defaults and the overrides).
"""

from __future__ import annotations

import numpy as np

from .._common import canonical_order, compose_doc, prepare
from .clusters import PlanarClusters, planar_clusters
from .params import MIHO_DEFAULTS, MOP_DEFAULTS, MopParams, resolve_params

__all__ = ["mop_clusters", "mop_miho_clusters", "mop_filter", "mop_miho_filter", "PlanarClusters"]


def _run(defaults: MopParams, name: str, kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1,
         shapes2, seed, params) -> PlanarClusters:
    """Check the arguments, run in an order that depends on the set of matches only, map back."""
    prm = resolve_params(defaults, params, name)
    ms = prepare(kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1, shapes2)
    # Scores do not enter MOP; the order is by keypoint positions (then indices), whatever the scores.
    order, _ = canonical_order(ms.x, ms.y, ms.matches, np.zeros(len(ms)))
    out = planar_clusters(ms.x[order], ms.y[order], np.random.default_rng(seed), prm)
    labels = np.empty(len(ms), np.int64)
    labels[order] = out.labels
    return PlanarClusters(labels >= 0, labels, out.homographies, out.middle1, out.middle2)


_DOC = """\
{summary}
%(kpts)s
%(matches)s
scores : ndarray of shape (K,) or None
    Unused by {label} (validated only).
image_size1, image_size2 : (int, int)
    Image sizes (width, height), validated only.
shapes1, shapes2 : ndarray of shape (N, 2, 2), optional
    Unused (validated only).
seed : None, int or numpy.random.Generator, default 0
    Seed of the RANSAC samples: a call is deterministic for a given int.
**params
    Overrides of the fields of :data:`.params.{defaults}` (:class:`.params.{cls}`, which names the
    authors' parameter of each), e.g. ``max_iterations=500``; an unknown name is a ``ValueError``.

Returns
-------
PlanarClusters
    ``keep`` (K,) bool, ``labels`` (K,) int64 (-1: rejected) and ``homographies`` (P, 3, 3), image 1 ->
    image 2, in the order the planes were found; {middle}.

Notes
-----
Fewer than about a dozen matches, or matches with no four well-spread points (all collinear, all
coincident), give no plane: every match is rejected. The result does not depend on the order of the rows of
``matches`` nor on ``scores``: the matches are searched in the order of their keypoint positions.
"""


def mop_clusters(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                 seed=0, **params) -> PlanarClusters:
    return _run(MOP_DEFAULTS, "mop_clusters", kpts1, kpts2, matches, scores, image_size1, image_size2, shapes1,
                shapes2, seed, params)


def mop_miho_clusters(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None,
                      shapes2=None, seed=0, **params) -> PlanarClusters:
    return _run(MIHO_DEFAULTS, "mop_miho_clusters", kpts1, kpts2, matches, scores, image_size1, image_size2,
                shapes1, shapes2, seed, params)


def mop_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
               seed=0, **params) -> np.ndarray:
    """:func:`mop_clusters`' keep mask (K,) bool behind the common filter signature (``FILTERS["mop"]``)."""
    return mop_clusters(kpts1, kpts2, matches, scores, image_size1=image_size1, image_size2=image_size2,
                        shapes1=shapes1, shapes2=shapes2, seed=seed, **params).keep


def mop_miho_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
                    seed=0, **params) -> np.ndarray:
    """:func:`mop_miho_clusters`' keep mask (K,) bool behind the common filter signature
    (``FILTERS["mop_miho"]``)."""
    return mop_miho_clusters(kpts1, kpts2, matches, scores, image_size1=image_size1, image_size2=image_size2,
                             shapes1=shapes1, shapes2=shapes2, seed=seed, **params).keep


mop_clusters.__doc__ = compose_doc(_DOC.format(
    summary="""\
MOP: the matches on Multiple Overlapping Planes, each plane a homography image 1 -> image 2.

Parameters
----------""",
    label="MOP", defaults="MOP_DEFAULTS", cls="MopParams", middle="``middle1`` and ``middle2`` None") + """
Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> x = rng.uniform(0, 400, (120, 2))
>>> y = x @ np.array([[1.1, 0.05], [-0.05, 1.1]]).T + (20.0, -10.0)
>>> y[:20] = rng.uniform(0, 400, (20, 2))  # 20 outliers
>>> m = np.c_[np.arange(120), np.arange(120)]
>>> out = mop_clusters(x, y, m, image_size1=(400, 400), image_size2=(400, 400))
>>> int(out.keep[20:].sum()), int(out.keep[:20].sum()) <= 2, out.homographies.shape[1:]
(100, True, (3, 3))
""", label="MOP")

mop_miho_clusters.__doc__ = compose_doc(_DOC.format(
    summary="""\
MOP+MiHo: the matches on Multiple Overlapping Planes, each plane a pair of Middle Homographies.

Each plane maps image 1 and image 2 (pre-rotated by a multiple of ``360 / rotations`` degrees) onto the
plane of the middle points, and a match must fit both maps. The pre-rotation is voted by the pairs of
matches whose middle distance lies strictly between their image distances
(:func:`.homography.best_rotation`): on noise-free rigid motion no inlier pair votes (its distances are
equal), the outliers pick the turn, and a half turn collapses the middle points; ``rotations=1`` turns the
vote off.

Parameters
----------""",
    label="MOP+MiHo", defaults="MIHO_DEFAULTS", cls="MihoParams",
    middle="``middle1`` and ``middle2`` (P, 3, 3), image 1 and\n    image 2 -> middle plane") + """
Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(1)
>>> x = rng.uniform(0, 400, (120, 2))
>>> y = x @ np.array([[1.1, 0.05], [-0.05, 1.1]]).T + (20.0, -10.0)
>>> y[:20] = rng.uniform(0, 400, (20, 2))  # 20 outliers
>>> m = np.c_[np.arange(120), np.arange(120)]
>>> out = mop_miho_clusters(x, y, m, image_size1=(400, 400), image_size2=(400, 400))
>>> int(out.keep[20:].sum()), int(out.keep[:20].sum()) <= 2, out.middle1.shape == out.homographies.shape
(100, True, True)
""", label="MOP+MiHo")
