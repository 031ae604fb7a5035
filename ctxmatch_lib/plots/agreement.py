"""Our per-method precision and recall against the paper's Tables 1-3: one panel per (configuration, kind).

x is the paper's value, y ours, on the y = x line where the two agree; each method keeps its colour and marker
of the scatter plots (:func:`ctxmatch_lib.plots.eval.method_style`); precision is the filled marker and recall
the hollow one. The panel title gives Spearman's ρ over the filters
(:func:`ctxmatch_lib.report_paper.rank_agreement`).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
from matplotlib.lines import Line2D

from ..report import KIND_LABELS, method_label, method_order
from ..report_paper import rank_agreement
from .eval import method_style

__all__ = ["plot_agreement"]


def plot_agreement(side, setups=None, *, models=("none",), blob: bool = False, ms: float = 14,
                   panel_size: float = 2.0, figsize=None):
    """Ours (y) against the paper (x) per method, precision filled and recall hollow (Tables 1-3, Fig. 7).

    Parameters
    ----------
    side : DataFrame
        A :func:`ctxmatch_lib.report_paper.side_by_side` frame (index setup, kind, model, method).
    setups : sequence of str, optional
        The configurations, one column of panels each (default: those in ``side``, in order); one row of
        panels per kind of pair.
    models : sequence of str
        The models drawn (default no model only); a second model (``"1sac"``) is drawn at half opacity.
    blob : bool
        Draw the blob candidates too (default no: their recall is 100 % by definition).
    ms : float
        Marker area in points².
    panel_size : float
        Width and height of one panel in inches, when ``figsize`` is not given.
    figsize : (float, float), optional
        The figure's size (e.g. :func:`~ctxmatch_lib.plots.base.figsize` for a paper figure); the panels
        share it under the constrained layout, the legend below them.

    Returns
    -------
    Figure
        (kinds) × ``len(setups)`` panels sharing the 0-100 % axes; one legend below them.
    """
    setups = list(dict.fromkeys(side.index.get_level_values("setup"))) if setups is None else list(setups)
    unknown = [s for s in setups if s not in set(side.index.get_level_values("setup"))]
    if unknown:
        raise ValueError(f"setups: {unknown} not in side (has {sorted(set(side.index.get_level_values('setup')))})")
    kinds = [k for k in dict.fromkeys(side.index.get_level_values("kind"))]
    rho = rank_agreement(side)
    if figsize is None:
        figsize = (panel_size * len(setups), panel_size * len(kinds) + 0.8)
    fig, axes = plt.subplots(len(kinds), len(setups), figsize=figsize, squeeze=False, sharex=True, sharey=True,
                             layout="constrained")
    shown = []
    for c, setup in enumerate(setups):
        for r, kind in enumerate(kinds):
            ax = axes[r, c]
            ax.plot([0, 100], [0, 100], color="0.6", lw=0.6, zorder=1)
            for k, model in enumerate(models):
                try:
                    d = side.xs((setup, kind, model), level=("setup", "kind", "model"))
                except KeyError:
                    continue
                if not blob:
                    d = d[~d["blob"].astype(bool)]
                for method in method_order(d.index):
                    colour, marker = method_style(method)
                    row = d.loc[method]
                    alpha = 1.0 if k == 0 else 0.45
                    ax.scatter(row["precision paper (%)"], row["precision ours (%)"], s=ms, marker=marker,
                               c=[colour], edgecolors=colour, linewidths=0.6, alpha=alpha, zorder=3)
                    ax.scatter(row["recall paper (%)"], row["recall ours (%)"], s=ms, marker=marker, c="none",
                               edgecolors=colour, linewidths=0.8, alpha=alpha, zorder=4)
                    shown.append(method)
            key = (setup, kind, models[0])
            text = (f"ρ P {rho.loc[key, 'ρ precision']:.2f}, ρ R {rho.loc[key, 'ρ recall']:.2f}"
                    if key in rho.index else "ρ –")
            ax.set_title(f"{setup}, {KIND_LABELS.get(kind, kind)}\n{text}", fontsize=7)
            ax.set_xlim(0, 102)
            ax.set_ylim(0, 102)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            if r == len(kinds) - 1:
                ax.set_xlabel("paper (%)", fontsize=7)
            if c == 0:
                ax.set_ylabel("ours (%)", fontsize=7)
    handles = [Line2D([], [], ls="", marker=method_style(m)[1], ms=4.5, mfc=method_style(m)[0],
                      mec=method_style(m)[0]) for m in method_order(shown)]
    labels = [method_label(m) for m in method_order(shown)]
    handles += [Line2D([], [], ls="", marker="o", ms=4.5, mfc="0.3", mec="0.3"),
                Line2D([], [], ls="", marker="o", ms=4.5, mfc="none", mec="0.3")]
    labels += ["precision (filled)", "recall (hollow)"]
    if len(models) > 1:
        handles.append(Line2D([], [], ls="", marker="o", ms=4.5, mfc="0.3", mec="0.3", alpha=0.45))
        labels.append(f"{', '.join(models[1:])} (faded)")
    fig.legend(handles, labels, loc="outside lower center", ncol=6, fontsize=7, frameon=False,
               columnspacing=1.0, handletextpad=0.3)
    return fig
