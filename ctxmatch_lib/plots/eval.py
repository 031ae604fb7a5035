"""Plot helpers for the filter evaluation (Sec. 5.3, Appendix "DTM evaluation"): the precision/recall
scatter of Fig. 7 (``pr_plot``) and the inlier-ratio histograms (``inl_plot``). Each helper draws on a given
``ax`` from a table of :mod:`ctxmatch_lib.report` and never calls ``plt.show()``.

As in the paper, results without a model are blue and with 1SAC red; each method has its own marker.
"""

from __future__ import annotations

import numpy as np

from ..report import method_label, method_order

__all__ = [
    "MODEL_COLORS",
    "method_marker",
    "method_color",
    "plot_pr_scatter",
    "pr_legend",
    "plot_inlier_bars",
    "plot_pair_share",
]

#: Colour per model step: the paper's blue (no model) and red (1SAC).
MODEL_COLORS = {"none": "#1f5fd6", "1sac": "#e0271c", "ransac": "#2a9d3c"}
_MARKERS = {"blob": "*", "th": "x", "dtm": "o", "dtm1": "o", "dtm2": "D", "lmr": "p", "lpm": "v", "glpm": "^",
            "gms": "s", "vfc": "P", "llt": "<", "rfm_scan": ">", "adalam": "h", "oanet": "8", "acne": "d",
            "pfm": "1", "pgm": "2", "scv": "3", "bm": "4"}
_FALLBACK_MARKERS = ("H", "X", "+", "|", "_")


def method_marker(name: str) -> str:
    """Matplotlib marker of a method (fixed for the paper's methods, cycled for others)."""
    if name in _MARKERS:
        return _MARKERS[name]
    return _FALLBACK_MARKERS[sum(map(ord, name)) % len(_FALLBACK_MARKERS)]


def method_color(name: str):
    """A fixed colour per method for the histograms (tab20, in the paper's table order)."""
    import matplotlib

    order = list(_MARKERS)
    i = order.index(name) if name in order else len(order) + sum(map(ord, name))
    return matplotlib.colormaps["tab20"](i % 20)


def _label(name: str, fmt: bool = True) -> str:
    lab = method_label(name)
    return lab if fmt else lab.replace("$_1$", "1").replace("$_2$", "2")


def plot_pr_scatter(ax, table, *, title: str | None = None, models=("none", "1sac"), connect: bool = True,
                    annotate: bool = True, ms: float = 60, lim=(0, 101)) -> None:
    """Mean precision (y) against mean recall (x), one marker per method and one colour per model.

    Parameters
    ----------
    table : DataFrame
        A :func:`ctxmatch_lib.report.method_table` restricted to one kind: index (model, method) (a
        (kind, model, method) index with a single kind also works).
    models : sequence of str
        Models to draw (blue: none, red: 1SAC).
    connect : bool
        A thin grey arrow from each method's no-model point to its 1SAC point (the effect of 1SAC).
    annotate : bool
        Write the method name next to its no-model point.
    """
    t = table.droplevel("kind") if "kind" in table.index.names else table
    methods = method_order(t.index.get_level_values("method"))
    for model in models:
        for m in methods:
            if (model, m) not in t.index:
                continue
            r = t.loc[(model, m)]
            ax.scatter(r["recall (%)"], r["precision (%)"], marker=method_marker(m), s=ms * (1.6 if m == "blob" else 1),
                       c=MODEL_COLORS.get(model, "k"), linewidths=1.2 if method_marker(m) in "x1234+|_" else 0.4,
                       edgecolors="white" if method_marker(m) not in "x1234+|_" else None, zorder=3, alpha=0.9)
    if connect and {"none", "1sac"} <= set(models):
        for m in methods:
            if ("none", m) in t.index and ("1sac", m) in t.index:
                a, b = t.loc[("none", m)], t.loc[("1sac", m)]
                ax.annotate("", xy=(b["recall (%)"], b["precision (%)"]), xytext=(a["recall (%)"], a["precision (%)"]),
                            arrowprops=dict(arrowstyle="-|>", color="0.55", lw=0.7, shrinkA=4, shrinkB=4), zorder=2)
    if annotate:
        for m in methods:
            if ("none", m) in t.index:
                r = t.loc[("none", m)]
                ax.annotate(_label(m), (r["recall (%)"], r["precision (%)"]), xytext=(5, -3),
                            textcoords="offset points", fontsize=7.5, color=MODEL_COLORS["none"], zorder=4)
    ax.set_xlim(*lim)
    ax.set_ylim(*lim)
    ax.set_aspect("equal")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel("recall (%)")
    ax.set_ylabel("precision (%)")
    if title:
        ax.set_title(title, fontsize=10)


def pr_legend(fig_or_ax, methods, *, times: dict | None = None, models=("none", "1sac"), **kwargs):
    """Legend of the scatter: one black marker per method, labelled with its mean running times
    (``times[method]``, a string such as ``"0.16/0.51 s"``), plus the model colours. ``kwargs`` go to
    ``legend``."""
    from matplotlib.lines import Line2D

    from ..report import MODEL_LABELS

    handles, labels = [], []
    for m in method_order(methods):
        handles.append(Line2D([], [], ls="", marker=method_marker(m), color="k", mfc="k", ms=7))
        labels.append(_label(m) + (f" ({times[m]})" if times and m in times else ""))
    for model in models:
        handles.append(Line2D([], [], ls="", marker="o", color=MODEL_COLORS[model], ms=8))
        labels.append(MODEL_LABELS.get(model, model))
    return fig_or_ax.legend(handles, labels, **kwargs)


def _bins(table, drop_empty: bool) -> list:
    bins = list(dict.fromkeys(table.index.get_level_values("bin")))
    if drop_empty:
        n = table.groupby(level="bin", sort=False, observed=True)["n"].max()
        bins = [b for b in bins if n.get(b, 0) > 0] or bins
    return bins


def plot_inlier_bars(ax, table, *, metric: str = "precision (%)", model: str = "none", methods=None,
                     title: str | None = None, min_n: int = 1, drop_empty: bool = True) -> None:
    """Grouped bars of ``metric`` per inlier-ratio bin, one bar per method (the histograms of ``inl_plot``).

    ``table`` is a :func:`ctxmatch_lib.report.inlier_bin_table`; bins with fewer than ``min_n`` cases are
    left blank, and with ``drop_empty`` bins without any case are not drawn. The number of cases of each
    bin is written under its label.
    """
    t = table.xs(model, level="model")
    bins = _bins(t, drop_empty)
    methods = method_order(methods or t.index.get_level_values("method"))
    width = 0.85 / len(methods)
    x = np.arange(len(bins))
    for k, m in enumerate(methods):
        vals = np.array([t.loc[(b, m), metric] if (b, m) in t.index and t.loc[(b, m), "n"] >= min_n else np.nan
                         for b in bins])
        ax.bar(x - 0.425 + (k + 0.5) * width, np.nan_to_num(vals), width, color=method_color(m),
               label=_label(m), edgecolor="none")
    n = [int(t.xs(b, level="bin")["n"].max()) for b in bins]
    ax.set_xticks(x, [f"{b}\n(n={c})" for b, c in zip(bins, n)], fontsize=8)
    ax.set_ylim(0, 100)
    ax.set_ylabel(metric)
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title, fontsize=10)


def plot_pair_share(ax, table, *, color="0.45", title: str | None = None, drop_empty: bool = True) -> None:
    """Bars of the share of (pair, setup) cases per inlier-ratio bin (``share (%)`` of an
    :func:`~ctxmatch_lib.report.inlier_bin_table`); with ``drop_empty`` bins without any case are not drawn."""
    share = table.groupby(level="bin", sort=False, observed=True)["share (%)"].first()
    share = share.loc[_bins(table, drop_empty)]
    x = np.arange(len(share))
    ax.bar(x, share.to_numpy(), 0.6, color=color)
    for xi, v in zip(x, share.to_numpy()):
        ax.text(xi, v + 1, f"{v:.0f} %", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, list(share.index), fontsize=8)
    ax.set_ylim(0, 100)
    ax.set_ylabel("share of pairs (%)")
    ax.set_xlabel("inlier ratio of the blob candidates")
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title, fontsize=10)
