"""Plots of the model's accuracy (issue 30): accuracy against the time to geometry, and cumulative error curves.

Input: the rows of the evaluation engine (:data:`~ctxmatch_lib.evaluation.rows.SWEEP_COLUMNS`) and the table of
:func:`~ctxmatch_lib.geometry_metrics.geometry_table`. Each method keeps the colour and marker it has in every
other figure (:func:`~ctxmatch_lib.plots.eval.method_style`); the axes are drawn on, never shown.
"""

from __future__ import annotations

import numpy as np

from .eval import _label, method_style

__all__ = ["MATCHER_LABELS", "method_name", "accuracy_column", "plot_accuracy_vs_time", "plot_cumulative_errors",
           "geometry_legend"]

#: Display names of the OpenCV matchers (:mod:`ctxmatch_lib.opencv_matchers`).
MATCHER_LABELS = {"opencv_ratio": "OpenCV ratio 0.8", "opencv_mnn": "OpenCV MNN"}


def method_name(name: str) -> str:
    """Display name of a method of the geometry figures: the OpenCV matchers by :data:`MATCHER_LABELS`, the
    others as in every figure.

    Examples
    --------
    >>> method_name("opencv_ratio"), method_name("rfm_scan")
    ('OpenCV ratio 0.8', 'RFM-SCAN')
    """
    return MATCHER_LABELS.get(name) or _label(name)


def accuracy_column(kind: str, auc_px: float = 5.0) -> tuple[str, str]:
    """``(column, axis label)`` of a :func:`~ctxmatch_lib.geometry_metrics.geometry_table` that scores a kind:
    the AUC of the corner error at ``auc_px`` for planar pairs, the mean epipolar consistency otherwise.

    Examples
    --------
    >>> accuracy_column("planar")
    ('auc_5px_pct', 'AUC of the corner error at 5 px (%)')
    """
    if kind == "planar":
        return f"auc_{auc_px:g}px_pct", f"AUC of the corner error at {auc_px:g} px (%)"
    return "epi_share_mean_pct", "GT correspondences consistent with F, mean 1-19 px (%)"


def plot_accuracy_vs_time(ax, table, kind: str, *, model: str, auc_px: float = 5.0, ms: float = 22,
                          title: str | None = None) -> list:
    """The model's accuracy (y) against the mean time to geometry per pair (x, log scale), one point per method.

    Parameters
    ----------
    ax : matplotlib Axes
    table : DataFrame
        :func:`~ctxmatch_lib.geometry_metrics.geometry_table` indexed by (kind, method, model) (a ``blob``
        level, if any, restricted to one setup beforehand).
    kind : {"planar", "nonplanar", "depth"}
    model : str
        The model step whose rows are drawn.
    auc_px : float
        Planar pairs: the AUC threshold (one of the table's).
    ms : float
        Marker area (points²).
    title : str, optional

    Returns
    -------
    list of (method, time, accuracy)
        The points drawn (methods without a finite time or accuracy are left out).
    """
    col, label = accuracy_column(kind, auc_px)
    t = table.xs((kind, model), level=("kind", "model"))
    pts = []
    for method, row in t.iterrows():
        x, y = float(row["geometry_time_s"]), float(row[col])
        if not (np.isfinite(x) and np.isfinite(y) and x > 0):
            continue
        colour, marker = method_style(method)
        ax.scatter(x, y, marker=marker, s=ms, c=[colour], edgecolors=colour, linewidths=0.3, zorder=3)
        pts.append((method, x, y))
    ax.set_xscale("log")
    ax.set_xlabel("time to geometry per pair (s, log)")
    ax.set_ylabel(label)
    ax.grid(True, which="both", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
    return pts


def plot_cumulative_errors(ax, rows, methods, *, model: str, max_px: float = 10.0, title: str | None = None) -> dict:
    """The share of planar pairs whose mean corner error is below ``e`` (y), for ``e`` in [0, ``max_px``] (x):
    the curve whose area :func:`~ctxmatch_lib.geometry_metrics.pose_auc` measures (pairs without a model never
    enter the curve but count in the denominator).

    Parameters
    ----------
    rows : DataFrame
        Engine rows of planar pairs (one row per pair and method: restrict the blob setup beforehand).
    methods : sequence of str
    model : str

    Returns
    -------
    dict of str -> float
        Per method, the share of pairs below ``max_px``.
    """
    out = {}
    for method in methods:
        e = np.sort(rows.loc[(rows["method"] == method) & (rows["model"] == model), "corner_error"].to_numpy())
        if len(e) == 0:
            continue
        colour, _ = method_style(method)
        inside = e[e < max_px]
        x = np.r_[0.0, inside, max_px]
        y = np.r_[0.0, np.arange(1, len(inside) + 1), len(inside)] / len(e)
        ax.plot(x, 100 * y, color=colour, lw=1.0, label=method_name(method))
        out[method] = len(inside) / len(e)
    ax.set_xlim(0, max_px)
    ax.set_ylim(0, 100)
    ax.set_xlabel("mean corner error (px)")
    ax.set_ylabel("pairs below (%)")
    ax.grid(True, lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
    return out


def geometry_legend(fig_or_ax, methods, ms: float = 5, **kwargs):
    """One legend naming each method by its colour and marker (as drawn by :func:`plot_accuracy_vs_time`)."""
    from matplotlib.lines import Line2D

    handles, labels = [], []
    for m in methods:
        colour, marker = method_style(m)
        handles.append(Line2D([], [], ls="-", lw=1.0, color=colour, marker=marker, ms=ms, mfc=colour, mec=colour))
        labels.append(method_name(m))
    return fig_or_ax.legend(handles, labels, **kwargs)
