"""Plots of the ground-truth comparison (Appendix "Ground truth estimation methods", ``setup_imgs``): the
groups of :func:`ctxmatch_lib.report.gt_compare.method_groups` as flows on image 1 (:func:`plot_gt_flows`) and
their support regions on image 2 (:func:`plot_support_regions`), one colour per group (:data:`GROUP_COLORS`)."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from .._numerics.fixedmath import sincos
from .palette import OKABE_ITO
from .viz2d import plot_flow, plot_image

__all__ = ["GROUP_COLORS", "DETECTOR_LABELS", "ellipse_polylines", "plot_gt_flows", "groups_legend",
           "plot_support_regions"]

#: One colour per group of the caption (the paper's colour in comments).
#: The groups drawn together (C ∩ D, C ∖ D, B ∖ C, D ∖ C) have no two blues: sky blue is kept for A ∖ D.
GROUP_COLORS = {
    "C ∩ D": OKABE_ITO["blue"],  # blue (planar) / yellow (non-planar)
    "C ∖ D": OKABE_ITO["vermillion"],  # red
    "B ∖ C": OKABE_ITO["reddish_purple"],  # light blue (planar) / light red (non-planar)
    "D ∖ C": OKABE_ITO["orange"],  # orange
    "A ∩ D": OKABE_ITO["bluish_green"],  # yellow
    "A ∖ D": OKABE_ITO["sky_blue"],  # light blue
    "D ∖ A": OKABE_ITO["yellow"],  # orange
}

#: Short column titles of the figure (the detector of a feature block, as the paper's caption names it).
DETECTOR_LABELS = {"sift": "SIFT", "harrisz": "HarrisZ"}


def ellipse_polylines(centres, shapes, n: int = 48) -> np.ndarray:
    """Outlines ``(P, n + 1, 2)`` of the ellipses ``{c + A u : |u| = 1}`` (closed), NaN rows dropped."""
    c = np.asarray(centres, np.float64).reshape(-1, 2)
    A = np.asarray(shapes, np.float64).reshape(-1, 2, 2)
    keep = np.isfinite(c).all(1) & np.isfinite(A).all((1, 2))
    t = np.linspace(0.0, 2.0 * np.pi, n + 1)
    sin, cos = sincos(t)
    u = np.stack([cos, sin], axis=1)
    return c[keep, None, :] + np.einsum("pij,tj->pti", A[keep], u)


def plot_gt_flows(ax, img, kpts1, kpts2, groups, *, colors=None, lw: float = 0.7, ps: float = 2.0,
                  dim: float = 0.55, counts: bool = True, legend: bool = True) -> None:
    """Each group's matches ``kpts1`` -> ``kpts2`` ``(K, 2)`` as flows on image 1 ``img``, one colour per group.

    ``groups``: name -> mask ``(K,)`` (:func:`ctxmatch_lib.report.gt_compare.method_groups`), drawn in order;
    ``colors`` default :data:`GROUP_COLORS`; ``counts`` puts each group's size in the legend, drawn on the
    photo with ``legend`` (else use :func:`groups_legend`).
    """
    colors = GROUP_COLORS if colors is None else colors
    plot_image(ax, img, dim=dim)
    from matplotlib.lines import Line2D

    handles = []
    for name, mask in groups.items():
        mask = np.asarray(mask, bool)
        plot_flow(ax, kpts1[mask], kpts2[mask], color=colors[name], lw=lw, ps=ps)
        handles.append(Line2D([], [], color=colors[name], lw=1.8, label=f"{name} ({mask.sum()})" if counts else name))
    if legend:
        ax.legend(handles=handles, loc="lower left", fontsize=7, frameon=True, framealpha=0.8, handlelength=1.2,
                  borderpad=0.3, labelspacing=0.2)


def groups_legend(fig_or_ax, names, *, colors=None, **kwargs):
    """One key for the groups ``names`` (their :data:`GROUP_COLORS` lines); ``kwargs`` go to ``legend``."""
    from matplotlib.lines import Line2D

    colors = GROUP_COLORS if colors is None else colors
    handles = [Line2D([], [], color=colors[n], lw=1.8) for n in names]
    return fig_or_ax.legend(handles, list(names), **kwargs)


def plot_support_regions(ax, img, kpts2, shapes2, carried_centres, carried_shapes, groups, worst, *,
                         colors=None, dim: float = 0.55, lw: float = 0.35, lw_worst: float = 1.4) -> None:
    """Support regions on image 2 ``img``: thin for every match of a group; thick for its ``worst`` match
    (:func:`ctxmatch_lib.report.gt_compare.worst_in_groups`), with its image-1 region carried by the ground
    truth dashed. ``kpts2``, ``shapes2``: ``(K, 2)``, ``(K, 2, 2)`` regions (scaled); ``carried_centres``,
    ``carried_shapes``: the same carried from image 1 (:class:`ctxmatch_lib.groundtruth.RegionErrors`).
    """
    colors = GROUP_COLORS if colors is None else colors
    plot_image(ax, img, dim=dim)
    for name, mask in groups.items():
        idx = np.flatnonzero(mask)
        col = colors[name]
        ax.add_collection(LineCollection(ellipse_polylines(kpts2[idx], shapes2[idx]), colors=col, linewidths=lw,
                                         alpha=0.45))
        if name in worst:
            k = worst[name]
            ax.add_collection(LineCollection(ellipse_polylines(kpts2[k], shapes2[k]), colors=col,
                                             linewidths=lw_worst, zorder=4))
            ax.add_collection(LineCollection(ellipse_polylines(carried_centres[k], carried_shapes[k]), colors=col,
                                             linewidths=lw_worst, linestyles=(0, (3, 1.5)), zorder=4))
    h, w = np.asarray(img).shape[:2]
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
