"""Plots of the accuracy after the model step (:func:`plot_accuracy_by_method`, :func:`plot_accuracy_vs_time`,
:func:`plot_cumulative_errors`); methods keep their :func:`~.eval.method_style`."""

from __future__ import annotations

import numpy as np

from ..report.tables import method_label
from .eval import method_style

__all__ = ["MATCHER_LABELS", "MATCHER_STYLES", "method_name", "geometry_style", "accuracy_column",
           "plot_accuracy_by_method", "plot_accuracy_vs_time", "plot_cumulative_errors", "geometry_legend",
           "threshold_legend"]

#: Display names of the OpenCV matchers (:mod:`ctxmatch_lib.opencv_matchers`).
MATCHER_LABELS = {"opencv_ratio": "OpenCV ratio 0.8", "opencv_mnn": "OpenCV MNN"}
#: Colour and marker of the OpenCV matchers: a grey that no filter wears, so they never look like a filter.
MATCHER_STYLES = {"opencv_ratio": ("#8C8C8C", "X"), "opencv_mnn": ("#8C8C8C", "P")}


def geometry_style(name: str) -> tuple[str, str]:
    """``(colour, marker)``: :data:`MATCHER_STYLES` for the OpenCV matchers, else :func:`method_style`.

    Examples
    --------
    >>> geometry_style("opencv_ratio") != geometry_style("dtm2")
    True
    """
    return MATCHER_STYLES.get(name) or method_style(name)


def method_name(name: str) -> str:
    """Display name of a method: :data:`MATCHER_LABELS` for the OpenCV matchers, else the usual label.

    Examples
    --------
    >>> method_name("opencv_ratio"), method_name("rfm_scan")
    ('OpenCV ratio 0.8', 'RFM-SCAN')
    """
    return MATCHER_LABELS.get(name) or method_label(name)


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
    if kind == "calibrated":
        return "auc_5deg_pct", "AUC of the pose error at 5° (%)"
    return "epi_share_mean_pct", "GT correspondences consistent with F, mean 1-19 px (%)"


#: Marker of each AUC threshold (px) in :func:`plot_accuracy_by_method`, and of the epipolar shares.
THRESHOLD_MARKERS = {1: "|", 3: "o", 5: "s", 10: "D"}
#: Marker of each AUC threshold of the pose error (degrees), calibrated pairs.
POSE_MARKERS = {5: "^", 10: "v", 20: "*"}


def plot_accuracy_by_method(ax, table, kind: str, *, model: str, title: str | None = None, order=None) -> list:
    """The accuracy of step ``model``, one row per method of a
    :func:`~ctxmatch_lib.geometry_metrics.geometry_table`, best on top: planar, the AUC of the corner error
    at 1/3/5/10 px (:data:`THRESHOLD_MARKERS`); calibrated, the AUC of the pose error at 5/10/20°
    (:data:`POSE_MARKERS`); otherwise the share of GT points consistent with F per threshold and its 1-19 px
    mean as a bar. A whisker under each row is the 95 % interval of the 5 px AUC, the mean share or the 5° AUC
    (the table's ``_lo``, ``_hi`` columns). ``order`` fixes the rows (side-by-side panels). Returns the methods, top to bottom.
    """
    t = table.xs((kind, model), level=("kind", "model"))
    planar, posed = kind == "planar", kind == "calibrated"
    if posed:
        markers = POSE_MARKERS
        cols = {deg: f"auc_{deg}deg_pct" for deg in POSE_MARKERS}
        keys = ["auc_5deg_pct", "auc_10deg_pct"]
    else:
        markers = THRESHOLD_MARKERS
        cols = {px: (f"auc_{px}px_pct" if planar else f"epi_share_{px}_pct") for px in THRESHOLD_MARKERS}
        keys = ["auc_5px_pct" if planar else "epi_share_mean_pct"]
    t = t[t[keys[0]].notna()].sort_values(keys, kind="stable") if order is None else t.reindex(list(order)[::-1])
    for y, (method, row) in enumerate(t.iterrows()):
        colour, marker = geometry_style(method)
        vals = [row[c] for c in cols.values() if c in row.index and np.isfinite(row[c])]
        if not (planar or posed):
            ax.barh(y, row[keys[0]], height=0.55, color=colour, alpha=0.35, lw=0)
        if vals:
            ax.plot([min(vals), max(vals)], [y, y], color=colour, lw=1.0, zorder=2)
        lo, hi = keys[0][:-len("pct")] + "lo", keys[0][:-len("pct")] + "hi"
        if lo in row.index and np.isfinite(row[lo]) and np.isfinite(row[hi]):  # the 95 % interval of keys[0]
            ax.plot([row[lo], row[hi]], [y - 0.3, y - 0.3], color=colour, lw=1.3, marker="|", ms=4, zorder=2)
        for th, c in cols.items():
            if c in row.index and np.isfinite(row[c]):
                ax.plot(row[c], y, marker=markers[th], ms=3.5, color=colour, mec=colour, ls="none",
                        mfc="white" if th in (3, 10) else colour, zorder=3)
        # x in axes fraction, y in data: just left of the axis.
        ax.plot(-0.06, y, marker=marker, ms=3.2, color=colour, mec=colour, ls="none", clip_on=False,
                transform=ax.get_yaxis_transform(), zorder=3)
    fits = t["pairs"] * t["runs"] if "runs" in t.columns else t["pairs"]
    names = [method_name(m) + (f" ({int(r['no_model'])} of {int(n)} w/o model)" if r["no_model"] > 0 else "")
             for (m, r), n in zip(t.iterrows(), fits)]
    ax.set_yticks(range(len(t)), names)
    ax.tick_params(axis="y", pad=10)
    ax.set_ylim(-0.7, len(t) - 0.3)
    ax.set_xlim(0, 100)
    ax.set_xlabel("AUC of the mean corner error (%)" if planar else
                  "AUC of the pose error (%)" if posed else "GT points consistent with F (%)")
    ax.grid(True, axis="x", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
    return list(t.index)[::-1]


def threshold_legend(fig_or_ax, *, pose: bool = False, pixels: bool = True, **kwargs):
    """The key of :func:`plot_accuracy_by_method`'s markers: pixel thresholds and the mean-share bar
    (``pixels``), pose thresholds in degrees (``pose``), and the interval band."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, labels = [], []
    if pixels:
        handles = [Line2D([], [], ls="none", marker=m, ms=4, color="0.2", mfc="white" if px == 3 else "0.2")
                   for px, m in THRESHOLD_MARKERS.items()]
        labels = [f"at {px} px" for px in THRESHOLD_MARKERS]
        handles.append(Patch(color="0.2", alpha=0.35, lw=0))
        labels.append("F: mean share over 1-19 px")
    if pose:
        handles += [Line2D([], [], ls="none", marker=m, ms=4, color="0.2", mfc="white" if deg == 10 else "0.2")
                    for deg, m in POSE_MARKERS.items()]
        labels += [f"pose at {deg}°" for deg in POSE_MARKERS]
    handles.append(Line2D([0, 1], [0, 0], color="0.2", lw=1.3, marker="|", ms=4))
    labels.append("95 % interval (" + ", ".join([*(["5 px", "mean share"] if pixels else []),
                                                 *(["5°"] if pose else [])]) + ")")
    return fig_or_ax.legend(handles, labels, **kwargs)


def plot_accuracy_vs_time(ax, table, kind: str, *, model: str, auc_px: float = 5.0, ms: float = 22,
                          title: str | None = None) -> list:
    """The model's accuracy (y, :func:`accuracy_column`) against the mean time to geometry per pair (x, log),
    one point per method of a :func:`~ctxmatch_lib.geometry_metrics.geometry_table`; returns the
    ``(method, time, accuracy)`` points drawn (finite ones only)."""
    col, label = accuracy_column(kind, auc_px)
    t = table.xs((kind, model), level=("kind", "model"))
    pts = []
    for method, row in t.iterrows():
        x, y = float(row["geometry_time_s"]), float(row[col])
        if not (np.isfinite(x) and np.isfinite(y) and x > 0):
            continue
        colour, marker = geometry_style(method)
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
    """The share of planar pairs (engine ``rows``) whose mean corner error is below ``e``, ``e`` in [0,
    ``max_px``]: the curve :func:`~ctxmatch_lib.geometry_metrics.pose_auc` integrates (pairs without a model
    count in the denominator). Returns, per method, the share below ``max_px``."""
    out = {}
    for method in methods:
        e = np.sort(rows.loc[(rows["method"] == method) & (rows["model"] == model), "corner_error"].to_numpy())
        if len(e) == 0:
            continue
        colour, marker = geometry_style(method)
        inside = e[e < max_px]
        x = np.r_[0.0, inside, max_px]
        y = np.r_[0.0, np.arange(1, len(inside) + 1), len(inside)] / len(e)
        # The method's marker at its largest error below max_px: two methods of one colour stay apart.
        ax.plot(x, 100 * y, color=colour, lw=1.0, label=method_name(method), marker=marker, ms=3.5,
                markevery=[len(inside)] if len(inside) else [])
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
        colour, marker = geometry_style(m)
        handles.append(Line2D([], [], ls="-", lw=1.0, color=colour, marker=marker, ms=ms, mfc=colour, mec=colour))
        labels.append(method_name(m))
    return fig_or_ax.legend(handles, labels, **kwargs)
