"""Delaunay Triangulation Matching (Sec. 4): :func:`dtm` (DTM1 contraction/expansion, DTM2 re-addition),
its record types and :func:`dtm_filter`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._numerics.validation import as_image_size, as_matches, as_points, as_scores, check_inside
from .._numerics.order import canonical_order, spread_back
from ..geometry import dlt_normal_matrix, hartley_normalise, transfer_errors
from ._kernels import contract_expand_kernel, neighbourhood_kernel, row_counts_kernel, transfer_test_kernel
from .boundary import BOUNDARY_METHODS, Boundary, boundaries_and_triangulations, keypoint_boundary
from .triangulation import Triangulation, collapse_vertices, stable_argsort_small, triangulate

__all__ = ["DTMResult", "DTMTrace", "DTM1Iteration", "DTM2Level", "dtm", "dtm_filter"]


@dataclass(frozen=True)
class DTM1Iteration:
    """Everything DTM1 iteration ``i`` computed (one row of Fig. 3); match indices are rows of ``matches``.

    Attributes
    ----------
    iteration : int
        ``i``, from 1.
    active, kept : ndarray
        ``M^{i-1}`` entering and ``M^i`` leaving the iteration (increasing).
    vertex1, vertex2 : ndarray of shape (n,)
        Vertex of ``tri1``/``tri2`` each active match collapsed into.
    boundary1, boundary2, tri1, tri2 : Boundary, Triangulation
        ``B^i`` (Fig. 2) and the triangulations of ``V ∪ B^i`` (Fig. 3, blue).
    consistency, rank : ndarray of shape (n,)
        ``|M_{A^1_{v_l}} ∩ M_{A^2_{v_r}}|`` per active match, and the ranking order (step 4).
    contraction : ndarray of shape (t,)
        ``T`` in build order (step 5; orange in Fig. 3).
    cluster_ptr, cluster_members : ndarray
        CSR expansion clusters (step 6; yellow in Fig. 3): ``contraction[c]``'s is
        ``cluster_members[cluster_ptr[c]:cluster_ptr[c + 1]]``.
    """

    iteration: int
    active: np.ndarray
    vertex1: np.ndarray
    vertex2: np.ndarray
    boundary1: Boundary
    boundary2: Boundary
    tri1: Triangulation
    tri2: Triangulation
    consistency: np.ndarray
    rank: np.ndarray
    contraction: np.ndarray
    cluster_ptr: np.ndarray
    cluster_members: np.ndarray
    kept: np.ndarray

    @property
    def removed(self) -> np.ndarray:
        """``M^{i-1} \\ M^i``: the matches this iteration removed."""
        return np.setdiff1d(self.active, self.kept)


@dataclass(frozen=True)
class DTM2Level:
    """One level ``i`` of the DTM2 reverse pass (Fig. 3f).

    Attributes
    ----------
    level : int
        ``i``: the DTM1 iteration whose removed matches are re-examined.
    base, tri1, tri2 : ndarray, Triangulation
        ``E^i`` (increasing) and its triangulations with boundaries ``T'_1``, ``T'_2`` (DTM2 step 1).
    candidates, added : ndarray
        ``M^{i-1} \\ M^i``, and those passing the two-way test (step 2): ``E^{i-1} = E^i ∪ added``.
    """

    level: int
    base: np.ndarray
    tri1: Triangulation
    tri2: Triangulation
    candidates: np.ndarray
    added: np.ndarray


@dataclass(frozen=True)
class DTMTrace:
    """Per-step record of a DTM run, for Fig. 2, Fig. 3 and Appendix A.

    Attributes
    ----------
    iterations, levels : tuple of DTM1Iteration, tuple of DTM2Level
        DTM1 iterations ``1..ī``; DTM2 levels ``ī - 1`` down to 1 (empty with ``stages=1``).
    image_size1, image_size2 : tuple of int
        ``(width, height)`` of the two images.
    """

    iterations: tuple
    levels: tuple
    image_size1: tuple
    image_size2: tuple


@dataclass(frozen=True)
class DTMResult:
    """Output of :func:`dtm`.

    Attributes
    ----------
    keep : ndarray of shape (K,) bool
        The output ``E`` (``M^ī`` with ``stages=1``): ``matches[keep]``.
    removed_at, readded_at : ndarray of shape (K,) int
        The DTM1 iteration that removed / DTM2 level that re-added each match, 0 for none.
    trace : DTMTrace or None
        The per-step record with ``trace=True``.
    whole_set : bool
        Whether the whole-set rule (:func:`dtm`) kept every match (the other fields: DTM alone).
    """

    keep: np.ndarray
    removed_at: np.ndarray
    readded_at: np.ndarray
    trace: DTMTrace | None = None
    whole_set: bool = False


def _csr_by(keys: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """``(ptr, order)`` grouping positions ``0..len(keys)-1`` by key: group ``k`` is
    ``order[ptr[k]:ptr[k + 1]]`` (positions increasing inside each group)."""
    order = stable_argsort_small(keys, n_keys)
    ptr = np.zeros(n_keys + 1, np.int64)
    np.cumsum(np.bincount(keys, minlength=n_keys), out=ptr[1:])
    return ptr, order


def _neighbourhood_pairs(tri: Triangulation, other: Triangulation, vertex: np.ndarray, other_vertex: np.ndarray):
    """DTM1 step 3: the pairs ``(m, m')`` with the vertex of ``m'`` adjacent to (not equal to) that of ``m``
    in ``tri``, grouped by ``m``, and whether they are adjacent in ``other`` too (:func:`dtm`, Notes)."""
    return neighbourhood_kernel(*(np.asarray(a, np.int64) for a in (tri.indptr, tri.indices, vertex, other.indptr,
                                                                     other.indices, other_vertex)))


@dataclass(frozen=True)
class _Setup:
    """Per-run boundary settings and a cache of the triangulations built so far."""

    size1: tuple
    size2: tuple
    boundary: str
    shrink: float
    others1: np.ndarray | None  # all keypoints of each image, collapsed ("keypoints" boundary only)
    others2: np.ndarray | None
    built: dict = field(default_factory=dict, compare=False, repr=False)

    def triangulations(self, v1: np.ndarray, v2: np.ndarray):
        """``(B_1, B_2, T_1, T_2)`` for vertex sets ``v1``, ``v2`` (steps 1-2), built once per vertex set."""
        keys = [(0, v1.shape, v1.tobytes()), (1, v2.shape, v2.tobytes())]
        new = [j for j in (0, 1) if keys[j] not in self.built]
        vs, sizes, others = (v1, v2), (self.size1, self.size2), (self.others1, self.others2)
        if self.boundary == "keypoints":
            for j in new:
                b = keypoint_boundary(vs[j], sizes[j], others[j], collapsed=True)
                self.built[keys[j]] = b, triangulate(vs[j], b.points)
        elif new:
            pairs = boundaries_and_triangulations([vs[j] for j in new], [sizes[j] for j in new], self.boundary,
                                                  shrink=self.shrink)
            for j, (b, s) in zip(new, pairs):
                self.built[keys[j]] = b, triangulate(vs[j], b.points, simplices=s)
        (b1, t1), (b2, t2) = self.built[keys[0]], self.built[keys[1]]
        return b1, b2, t1, t2


def _dtm1_iteration(i, active, kp1, kp2, score, canon, setup: _Setup, want_record):
    """One DTM1 iteration (steps 1-6) on the active matches; local indices are positions in ``active``."""
    n = len(active)
    # Steps 1-2: collapsed vertices, boundaries, triangulations.
    v1, vl = collapse_vertices(kp1[active])
    v2, vr = collapse_vertices(kp2[active])
    b1, b2, t1, t2 = setup.triangulations(v1, v2)
    # Step 3: pairs (m, m') with m' in M_{A1(vl(m))}, flagged when also in M_{A2(vr(m))}; and vice versa.
    m_a, o_a, in_both = _neighbourhood_pairs(t1, t2, vl, vr)
    m_b, o_b, in_1 = _neighbourhood_pairs(t2, t1, vr, vl)
    # Step 4: rank by score ascending, then |M_A1 ∩ M_A2| descending, then the canonical key.
    consistency = row_counts_kernel(m_a, in_both, n)
    rank = np.lexsort((canon, -consistency, score))
    # Step 5: contraction. Each pick removes (M_A1 ∪ M_A2) \ (M_A1 ∩ M_A2): the pairs of M_A1 not in M_A2
    # and those of M_A2 not in M_A1, both already grouped by match (rows of m_a and m_b never decrease).
    # Step 6: expansion, the union of the picked matches' intersections. One compiled pass over the pairs.
    picked, kept_flag = contract_expand_kernel(rank, m_a, o_a, in_both, m_b, o_b, in_1, n)
    kept_local = np.flatnonzero(kept_flag)
    record = None
    if want_record:
        pos_in_t = np.full(n, -1, np.int64)
        pos_in_t[picked] = np.arange(len(picked))
        sel = in_both & (pos_in_t[m_a] >= 0)
        cm, co = pos_in_t[m_a[sel]], o_a[sel]
        cptr, corder = _csr_by(cm, len(picked))
        record = dict(iteration=i, active=active, vertex1=vl, vertex2=vr, boundary1=b1, boundary2=b2,
                      tri1=t1, tri2=t2, consistency=consistency, rank=active[rank],
                      contraction=active[picked], cluster_ptr=cptr, cluster_members=active[co[corder]],
                      kept=active[kept_local])
    return active[kept_local], b1.points, b2.points, (t1, t2), record


def _shared_keypoint_spread(p1: np.ndarray, p2: np.ndarray, canon: np.ndarray, tol: float) -> bool:
    """Whether two matches share an image-1 keypoint with image-2 keypoints over ``2 tol`` apart (no map fits
    both, so the whole-set fit is skipped); ``canon`` ranks the matches by image-1 keypoint first."""
    order = np.empty(len(canon), np.int64)
    order[canon] = np.arange(len(canon))
    a, b = p1[order], p2[order]
    same = (a[1:] == a[:-1]).all(axis=1)
    d = b[1:][same] - b[:-1][same]
    return bool((np.hypot(d[:, 0], d[:, 1]) > 2.0 * tol).any())


def _one_homography(p1: np.ndarray, p2: np.ndarray, tol: float) -> bool:
    """Whether one proper homography maps every ``p1`` onto its ``p2`` within ``tol`` pixels, and back.

    Normalised DLT of all pairs (Hartley & Zisserman, Alg. 4.2). *Proper*: unique, every ``p1`` in front
    of the horizon and ``det H > 0``.
    """
    if len(p1) < 4:
        return False
    n1, t1 = hartley_normalise(p1)
    n2, t2 = hartley_normalise(p2)
    evals, evecs = np.linalg.eigh(dlt_normal_matrix(n1, n2))
    if not evals[-1] > 0 or evals[1] <= 1e-12 * evals[-1]:
        return False  # no unique homography
    h = np.linalg.solve(t2, evecs[:, 0].reshape(3, 3) @ t1)
    w = p1 @ h[2, :2] + h[2, 2]
    h = h * np.sign(w[0]) if w[0] != 0 else h
    det = np.linalg.det(h)
    if not det > 0 or not (w * np.sign(w[0]) > 0).all():
        return False
    fwd, bwd = transfer_errors(h, p1, p2)
    return bool((fwd <= tol).all() and (bwd <= tol).all())


def _transfer_test(tri_src: Triangulation, q_src: np.ndarray, q_dst: np.ndarray, base_src: np.ndarray,
                   base_dst: np.ndarray, base_vertex: np.ndarray) -> np.ndarray:
    """DTM2 step 2 in one direction: the mask of candidates ``(q_src, q_dst)`` that pass.

    With ``W`` the triangle of ``tri_src`` holding ``q_src``: three keypoint vertices -> ``q_dst`` must lie
    strictly inside a same-orientation partner triangle of base-match keypoints; one or two boundary
    vertices -> ``q_dst`` translated by a base match adjacent to ``W``'s nearest keypoint vertex must land
    strictly inside ``W`` (the author's port; the paper states only the first case); otherwise it fails.
    """
    if len(q_src) == 0 or len(base_src) == 0 or tri_src.delaunay is None:
        return np.zeros(len(q_src), bool)
    simplex = tri_src.find_simplex(q_src)
    return transfer_test_kernel(simplex, np.ascontiguousarray(tri_src.simplices, np.int64),
                                np.ascontiguousarray(tri_src.points, np.float64), tri_src.n_vertices,
                                tri_src.indptr, tri_src.indices, *(np.ascontiguousarray(a, np.float64) for a in
                                                                   (q_src, q_dst, base_src, base_dst)),
                                np.asarray(base_vertex, np.int64))


def _dtm2_level(base, cand, kp1, kp2, setup: _Setup, stored, tris=None):
    """One DTM2 level: triangulate ``E`` (``base``) in both images and two-way test the candidates.

    ``stored``: DTM1's ``(B_1^i, B_2^i)``, or ``None`` to build boundaries around ``E``; ``tris``: known
    triangulations of ``E`` to reuse."""
    v1, vl = collapse_vertices(kp1[base])
    v2, vr = collapse_vertices(kp2[base])
    if tris is not None:
        t1, t2 = tris
    elif stored is None:
        _, _, t1, t2 = setup.triangulations(v1, v2)
    else:
        t1, t2 = triangulate(v1, stored[0]), triangulate(v2, stored[1])
    q1, q2 = kp1[cand], kp2[cand]
    ok = _transfer_test(t1, q1, q2, kp1[base], kp2[base], vl)
    if ok.any():
        sub = np.flatnonzero(ok)
        ok[sub[~_transfer_test(t2, q2[sub], q1[sub], kp2[base], kp1[base], vr)]] = False
    return cand[ok], t1, t2


def dtm(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, stages: int = 2,
        boundary: str = "alpha", shrink: float = 0.5, dtm2_boundary: str = "current",
        whole_set_tol: float | None = 1.0, trace: bool = False) -> DTMResult:
    """Delaunay Triangulation Matching (Sec. 4): keep matches whose Delaunay neighbourhoods agree.

    DTM1 (steps 1-6) triangulates the rounded keypoints of the surviving matches plus a boundary (Fig. 2),
    ranks the matches by score and neighbourhood consistency, and contracts/expands until nothing changes.
    DTM2 walks the iterations back and re-adds removed matches that fall in corresponding triangles of
    both images (steps 1-2).

    Parameters
    ----------
    kpts1, kpts2 : array_like of shape (N1, 2), (N2, 2)
        Keypoints, (x, y) pixels, origin at the centre of the top-left pixel; all must lie on their image.
    matches : array_like of shape (K, 2)
        Indices into ``kpts1``/``kpts2``; many-to-many allowed.
    scores : array_like of shape (K,), optional
        Descriptor distances, lower is better (step 4); ``None``: all equal.
    image_size1, image_size2 : tuple of int
        ``(width, height)``; they set the boundary distance ``s = min(w, h) / 10``.
    stages : {1, 2}
        1 runs DTM1 only, 2 also DTM2.
    boundary : {"alpha", "convex", "canvas", "corners", "keypoints"}
        See :func:`~ctxmatch_lib.dtm.boundary.dtm_boundary`; ``"alpha"`` is the paper's.
    shrink : float
        MATLAB ``boundary`` shrink factor of the alpha shape (footnote 2).
    dtm2_boundary : {"current", "stored"}
        DTM2's boundaries: built around ``E^i`` (as the port) or DTM1's ``B^i`` (the paper's text).
    whole_set_tol : float or None
        Transfer error in pixels of the whole-set rule (Notes); ``None`` turns it off.
    trace : bool
        Record every step in ``result.trace`` (:class:`DTMTrace`).

    Returns
    -------
    DTMResult

    Raises
    ------
    ValueError
        On keypoints outside their image (e.g. a size given as (height, width)) or arguments out of domain.

    Notes
    -----
    Where the paper leaves a choice open, DTM follows the author's Python port (see docs/dtm.md): only
    matches on *adjacent* vertices count as neighbours (step 3), DTM2 tests triangles touching the boundary
    by translation (:func:`_transfer_test`), "inside" is strict and unmirrored, and DTM2's boundaries are
    built around ``E^i``. Ties are broken by keypoint coordinates, then indices, so the result does not
    depend on the match order. **Whole-set rule** (not in the paper): when one proper homography maps all
    ``K >= 4`` matches (on 4+ distinct vertices per image) within ``whole_set_tol`` pixels both ways, every
    match is kept (``result.whole_set``); it saves small sets that the boundary cuts (docs/dtm.md).

    References
    ----------
    Bellavia, TPAMI 2022, Sec. 4, Fig. 2-3, App. A; DTM Python port, https://github.com/fb82/DTM.

    Examples
    --------
    >>> from ctxmatch_lib.testing import planted_homography_matches
    >>> p = planted_homography_matches(1500, 0.4, rng=0)
    >>> res = dtm(p.kpts1, p.kpts2, p.matches, p.scores, image_size1=p.image_size, image_size2=p.image_size)
    >>> precision = p.is_inlier[res.keep].mean()
    >>> bool(precision > 0.95)
    True
    """
    kp1 = as_points(kpts1, "kpts1")
    kp2 = as_points(kpts2, "kpts2")
    m = as_matches(matches, len(kp1), len(kp2))
    k = len(m)
    score = as_scores(scores, k)
    size1 = as_image_size(image_size1, "image_size1")
    size2 = as_image_size(image_size2, "image_size2")
    if stages not in (1, 2):
        raise ValueError(f"stages must be 1 or 2, got {stages!r}")
    if boundary not in BOUNDARY_METHODS:
        raise ValueError(f"boundary must be one of {BOUNDARY_METHODS}, got {boundary!r}")
    if not 0.0 <= shrink <= 1.0:
        raise ValueError(f"shrink must be in [0, 1], got {shrink}")
    if dtm2_boundary not in ("stored", "current"):
        raise ValueError(f"dtm2_boundary must be 'stored' or 'current', got {dtm2_boundary!r}")
    if whole_set_tol is not None and not (isinstance(whole_set_tol, (int, float, np.floating, np.integer))
                                          and 0 <= whole_set_tol < np.inf):
        raise ValueError(f"whole_set_tol must be a non-negative number of pixels or None, got {whole_set_tol!r}")
    check_inside(kp1, size1, "kpts1")
    check_inside(kp2, size2, "kpts2")
    removed_at = np.zeros(k, np.int64)
    readded_at = np.zeros(k, np.int64)
    if k == 0:
        empty_trace = DTMTrace((), (), size1, size2) if trace else None
        return DTMResult(np.zeros(0, bool), removed_at, readded_at, empty_trace)

    others = (collapse_vertices(kp1)[0], collapse_vertices(kp2)[0]) if boundary == "keypoints" else (None, None)
    setup = _Setup(size1, size2, boundary, shrink, *others)
    p1, p2 = kp1[m[:, 0]], kp2[m[:, 1]]
    # Order-independent tie-break key: keypoint coordinates, then keypoint indices.
    canon = np.empty(k, np.int64)
    canon[np.lexsort((m[:, 1], m[:, 0], p2[:, 1], p2[:, 0], p1[:, 1], p1[:, 0]))] = np.arange(k)

    active = np.arange(k, dtype=np.int64)
    boundaries = {}
    records = []
    i = 0
    while True:
        i += 1
        kept, bnd1, bnd2, tris, record = _dtm1_iteration(i, active, p1, p2, score[active], canon[active], setup,
                                                         trace)
        boundaries[i] = (bnd1, bnd2)
        if trace:
            records.append(DTM1Iteration(**record))
        if len(kept) == len(active):
            break
        removed_at[active] = i  # M^{i-1} \ M^i (kept is a subset of active, none removed before)
        removed_at[kept] = 0
        active = kept
        if len(active) == 0:
            i += 1  # M^{i} = M^{i-1} = ∅ trivially; nothing to triangulate
            break
    last = i

    levels = []
    if stages == 2:
        base = active
        tris = tris if len(active) and dtm2_boundary == "current" else None
        for level in range(last - 1, 0, -1):
            cand = np.flatnonzero(removed_at == level)
            stored = boundaries[level] if dtm2_boundary == "stored" else None
            # With boundaries built around E, a level that adds nothing leaves the next one E's triangulations,
            # and the first level's E is M^ī, which the last DTM1 iteration triangulated.
            added, t1, t2 = _dtm2_level(base, cand, p1, p2, setup, stored, tris)
            tris = (t1, t2) if stored is None and len(added) == 0 else None
            readded_at[added] = level
            if trace:
                levels.append(DTM2Level(level, base, t1, t2, cand, added))
            base = np.sort(np.concatenate([base, added]))  # added: none of them in base

    keep = (removed_at == 0) | (readded_at > 0)
    tr = DTMTrace(tuple(records), tuple(levels), size1, size2) if trace else None
    whole = (whole_set_tol is not None and not keep.all()
             and not _shared_keypoint_spread(p1, p2, canon, float(whole_set_tol))
             and _one_homography(p1, p2, float(whole_set_tol))
             and min(len(collapse_vertices(p1)[0]), len(collapse_vertices(p2)[0])) >= 4)
    if whole:
        keep = np.ones(k, bool)
    return DTMResult(keep, removed_at, readded_at, tr, whole)


def dtm_filter(kpts1, kpts2, matches, scores=None, *, image_size1, image_size2, shapes1=None, shapes2=None,
               **params) -> np.ndarray:
    """:func:`dtm`'s keep mask (K,) bool behind the common filter signature (``FILTERS["dtm"]``).

    Arguments as :func:`dtm`; ``shapes1``, ``shapes2`` are ignored. Rows are decided in their canonical
    order, so repeated rows get one decision and the mask does not depend on the row order.
    """

    kp1, kp2 = as_points(kpts1, "kpts1"), as_points(kpts2, "kpts2")
    m = as_matches(matches, len(kp1), len(kp2))
    s = as_scores(scores, len(m))
    order, twins = canonical_order(kp1[m[:, 0]], kp2[m[:, 1]], m, s)
    res = dtm(kp1, kp2, m[order], s[order], image_size1=image_size1, image_size2=image_size2, **params)
    return spread_back(res.keep, order, twins)
