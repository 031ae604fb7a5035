"""Plots of the filter evaluation (Sec. 5.3, Appendix "DTM evaluation"): the precision/recall scatter of
Fig. 7 (:func:`plot_pr_scatter`) and the inlier-ratio histograms (:func:`plot_inlier_method`). Each method
has one colour and marker (:func:`method_style`); hollow: no model, filled: 1SAC.
"""

from __future__ import annotations

import numpy as np

from ..report.tables import MODEL_LABELS, method_label, method_order
from .palette import OKABE_ITO

__all__ = ["METHOD_COLORS", "METHOD_MARKERS", "PAPER_METHOD_STYLES", "SETUP_HEADERS", "row_limits", "METRIC_COLORS",
           "method_style", "plot_pr_scatter", "fit_limits", "pr_legend", "shared_bins", "plot_inlier_method",
           "inlier_legend", "bin_axis_label", "plot_pair_share"]

#: The colours of the methods: Okabe–Ito without yellow (too pale on white) plus Paul Tol's indigo and wine.
METHOD_COLORS = tuple(OKABE_ITO[k] for k in ("black", "blue", "vermillion", "bluish_green", "reddish_purple",
                                             "orange", "sky_blue")) + ("#332288", "#882255")
#: The markers of the methods, all fillable (hollow = no model, filled = 1SAC).
METHOD_MARKERS = ("o", "s", "^", "D", "v", "p", "h", "<", ">")
_K, _B, _V, _G, _P, _O, _S, _I, _W = METHOD_COLORS
#: The paper's methods (Tables 1-3 order) and their (colour, marker): a colour is shared by two methods at most,
#: with markers of different families, and neighbours in the paper's order differ in both.
PAPER_METHOD_STYLES = {
    "blob": (_K, "o"), "th": (_B, "s"), "dtm1": (_V, "^"), "dtm2": (_G, "D"), "lmr": (_P, "v"), "lpm": (_O, "p"),
    "glpm": (_S, "h"), "gms": (_I, "<"), "vfc": (_W, ">"), "llt": (_K, "^"), "rfm_scan": (_B, "o"),
    "adalam": (_V, "s"), "oanet": (_G, "o"), "acne": (_P, "s"), "pfm": (_O, "v"), "pgm": (_S, "D"),
    "scv": (_I, "p"), "bm": (_W, "D"), "dtm": (_K, "s"),
}
#: Colours of the inlier-ratio bars: precision and recall.
METRIC_COLORS = {"precision (%)": OKABE_ITO["blue"], "recall (%)": OKABE_ITO["orange"]}
#: Colour of the cross that marks a bin without a value in the inlier-ratio panels.
EMPTY_COLOR = "0.35"


def method_style(name: str) -> tuple[str, str]:
    """``(colour, marker)`` of a method: :data:`PAPER_METHOD_STYLES`, else a deterministic unused pair.

    Examples
    --------
    >>> method_style("blob")
    ('#000000', 'o')
    >>> method_style("dtm2") != method_style("dtm1")
    True
    """
    if name in PAPER_METHOD_STYLES:
        return PAPER_METHOD_STYLES[name]
    taken = set(PAPER_METHOD_STYLES.values())
    free = [(c, m) for m in METHOD_MARKERS for c in METHOD_COLORS if (c, m) not in taken]
    return free[sum(map(ord, name)) % len(free)]


def fit_limits(values, *, pad: float = 0.06, min_span: float = 10.0, bounds=(0.0, 100.0)) -> tuple[float, float]:
    """Axis limits that show every one of ``values`` (NaNs ignored): ``pad`` × span on each side, at least
    ``min_span`` wide, never more than 2 units beyond ``bounds`` (room for a marker drawn on a bound).

    Examples
    --------
    >>> fit_limits([80, 95, 100])
    (78.8, 101.2)
    """
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return (bounds[0], bounds[1])
    lo, hi = float(v.min()), float(v.max())
    if hi - lo < min_span:
        mid = (lo + hi) / 2
        lo, hi = mid - min_span / 2, mid + min_span / 2
        if hi > bounds[1]:
            lo, hi = lo - (hi - bounds[1]), bounds[1]
        if lo < bounds[0]:
            lo, hi = bounds[0], hi + (bounds[0] - lo)
    span = hi - lo
    lo_lim = max(bounds[0] - 2.0, min(lo - pad * span, float(v.min()) - 1.0))
    hi_lim = min(bounds[1] + 2.0, max(hi + pad * span, float(v.max()) + 1.0))
    return (round(lo_lim, 3), round(hi_lim, 3))


#: Short column headers of :data:`ctxmatch_lib.report.SETUPS` (full titles: ``SETUP_TITLES`` there).
SETUP_HEADERS = {
    "global": "global: every block,\nbaseline and best blob setups",
    "baseline": "baseline: SIFT+RootSIFT,\none-to-one NNR",
    "best": "best: HarrisZ+SOSNet (stand-in),\nbest blob setup",
    "best-rootsgloh2": "best blob setup on\nHarrisZ+RootsGLOH2",
}


def _points(table, models=("none", "1sac")):
    t = table.droplevel("kind") if "kind" in table.index.names else table
    methods = method_order(t.index.get_level_values("method"))
    return [(model, m, float(t.loc[(model, m), "recall (%)"]), float(t.loc[(model, m), "precision (%)"]))
            for model in models for m in methods if (model, m) in t.index]


def row_limits(tables, models=("none", "1sac")) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(xlim, ylim)`` showing every point of every table (:func:`fit_limits`): one range for a row of panels."""
    pts = [p for t in tables for p in _points(t, models)]
    return fit_limits([p[2] for p in pts]), fit_limits([p[3] for p in pts])


def plot_pr_scatter(ax, table, *, title: str | None = None, models=("none", "1sac"), ms: float = 18,
                    lim=None, xlim=None, ylim=None, connect: bool = False) -> list:
    """Mean precision (y) against mean recall (x) per method and model, as Fig. 7 (names: :func:`pr_legend`).

    ``table``: a :func:`ctxmatch_lib.report.method_table` of one kind. Model ``"none"`` is drawn hollow, any
    other filled; ``ms`` is the marker area (points²). ``lim`` sets both axes (default :func:`fit_limits`),
    ``xlim``/``ylim`` one (e.g. :func:`row_limits`); ``connect`` joins each method's no-model and 1SAC points.
    Returns the points drawn, ``(model, method, recall, precision)``.
    """
    pts = _points(table, models)
    fx, fy = row_limits([table], models) if lim is None else (tuple(lim), tuple(lim))
    xlim = tuple(xlim) if xlim is not None else fx
    ylim = tuple(ylim) if ylim is not None else fy
    for model, m, x, y in pts:
        colour, marker = method_style(m)
        filled = model != "none"
        # Hollow markers over filled ones stay visible.
        ax.scatter(x, y, marker=marker, s=ms, c=[colour] if filled else "none", edgecolors=colour,
                   linewidths=0.3 if filled else 0.8, zorder=3 if filled else 4, clip_on=False)
    if connect and {"none", "1sac"} <= set(models):
        at = {(model, m): (x, y) for model, m, x, y in pts}
        for m in method_order(p[1] for p in pts):
            if ("none", m) in at and ("1sac", m) in at:
                (x0, y0), (x1, y1) = at["none", m], at["1sac", m]
                ax.plot([x0, x1], [y0, y1], color="0.7", lw=0.4, zorder=2)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_yticks([v for v in ax.get_yticks() if ylim[0] <= v <= 100])
    ax.set_xticks([v for v in ax.get_xticks() if xlim[0] <= v <= 100])
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel("recall (%)")
    ax.set_ylabel("precision (%)")
    if title:
        ax.set_title(title)
    return pts


def pr_legend(fig_or_ax, methods, *, times: dict | None = None, models=("none", "1sac"), ms: float = 5,
              **kwargs):
    """The scatter's legend: per method its hollow and filled markers and its name (with ``times[method]``
    if given); ``kwargs`` go to ``legend``."""
    from matplotlib.legend_handler import HandlerTuple
    from matplotlib.lines import Line2D

    handles, labels = [], []
    for m in method_order(methods):
        colour, marker = method_style(m)
        pair = tuple(Line2D([], [], ls="", marker=marker, ms=ms, mec=colour, mew=0.8,
                            mfc="none" if model == "none" else colour) for model in models)
        handles.append(pair)
        labels.append(method_label(m) + (f" ({times[m]})" if times and m in times else ""))
    fill = ", ".join(f"{'hollow' if model == 'none' else 'filled'}: {MODEL_LABELS.get(model, model)}"
                     for model in models)
    kwargs.setdefault("title", f"method ({fill})")
    kwargs.setdefault("handlelength", 2.2)
    return fig_or_ax.legend(handles, labels, handler_map={tuple: HandlerTuple(ndivide=None, pad=0.6)}, **kwargs)


def _bins(table, drop_empty: bool) -> list:
    bins = list(dict.fromkeys(table.index.get_level_values("bin")))
    if drop_empty:
        n = table.groupby(level="bin", sort=False, observed=True)["n"].max()
        bins = [b for b in bins if n.get(b, 0) > 0] or bins
    return bins


def shared_bins(tables, drop_empty: bool = True) -> list:
    """The bins shared by the columns of several :func:`~ctxmatch_lib.report.inlier_bin_table` tables: those
    populated in any of them (all with ``drop_empty=False``), in order."""
    tables = list(tables)
    order = list(dict.fromkeys(b for t in tables for b in t.index.get_level_values("bin")))
    if not drop_empty:
        return order
    keep = {b for t in tables for b in _bins(t, True)}
    return [b for b in order if b in keep]


def _bin_name(b) -> str:
    """A bin label without its unit (the axis label carries it): "10-20 %" -> "10–20"."""
    return str(b).replace(" %", "").replace("-", "–")


def _bin_edge_ticks(ax, bins, labels: bool = True) -> None:
    """Ticks at the edges of consecutive bins labelled "0", "10", ... (short labels fit a narrow panel); bins
    that are not consecutive keep their names under their centres."""
    names = [_bin_name(b) for b in bins]
    edges = [n.split("–") for n in names]
    ax.set_xlim(-0.5, len(bins) - 0.5)
    if all(len(e) == 2 for e in edges) and all(a[1] == b[0] for a, b in zip(edges, edges[1:])):
        ax.set_xticks(np.arange(len(bins) + 1) - 0.5, [e[0] for e in edges] + [edges[-1][1]] if labels else [])
    else:
        ax.set_xticks(np.arange(len(bins)), names if labels else [])


def plot_inlier_method(ax, table, method: str, *, bins=None, models=("none", "1sac"),
                       metrics=("precision (%)", "recall (%)"), title: str | None = None, min_n: int = 1,
                       tick_labels: bool = True) -> None:
    """One method's panel of the inlier-ratio histograms (``inl_plot``) of a
    :func:`ctxmatch_lib.report.inlier_bin_table`: per bin a bar per metric (:data:`METRIC_COLORS`) and model
    (hollow: no model). ``bins`` default: the populated ones (:func:`shared_bins`); a bin under ``min_n``
    cases or without a value gets a grey cross, a true 0 % a stroke."""
    bins = list(bins) if bins is not None else _bins(table, True)
    width = 0.84 / (len(metrics) * len(models))
    x = np.arange(len(bins))
    k = 0
    for metric in metrics:
        colour = METRIC_COLORS.get(metric, "0.3")
        for model in models:
            t = table.xs(model, level="model")
            vals = np.array([t.loc[(b, method), metric] if (b, method) in t.index and t.loc[(b, method), "n"] >= min_n
                             else np.nan for b in bins], np.float64)
            filled = model != "none"
            xs = x - 0.42 + (k + 0.5) * width
            ax.bar(xs, np.nan_to_num(vals), width * 0.92,
                   color=colour if filled else "white", edgecolor=colour, linewidth=0 if filled else 0.6)
            # Zero and missing bars are invisible: a stroke marks 0 %, a grey cross a missing value.
            zero, empty = vals == 0, np.isnan(vals)
            if zero.any():
                ax.hlines(np.zeros(zero.sum()), xs[zero] - 0.46 * width, xs[zero] + 0.46 * width, colors=colour,
                          linewidths=1.8, zorder=4, clip_on=False)
            if empty.any():
                ax.scatter(xs[empty], np.full(empty.sum(), 6.0), marker="x", s=7, c=EMPTY_COLOR, linewidths=0.6,
                           zorder=4)
            k += 1
    _bin_edge_ticks(ax, bins, tick_labels)
    ax.set_ylim(0, 100)
    ax.set_yticks([0, 50, 100])
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title, pad=2)


def inlier_legend(fig_or_ax, *, models=("none", "1sac"), metrics=("precision (%)", "recall (%)"),
                  empty: bool = True, **kwargs):
    """The key of :func:`plot_inlier_method`: one bar per metric and model, and (``empty``) the cross of a bin
    without a value."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, labels = [], []
    for metric in metrics:
        colour = METRIC_COLORS.get(metric, "0.3")
        for model in models:
            filled = model != "none"
            handles.append(Patch(fc=colour if filled else "white", ec=colour, lw=0 if filled else 0.8))
            labels.append(f"{metric.split(' ')[0]}, {MODEL_LABELS.get(model, model)}")
    if empty:
        handles.append(Line2D([], [], ls="", marker="x", ms=3.5, mec=EMPTY_COLOR, mew=0.8))
        labels.append("no value\n(0 %: a stroke)")
    return fig_or_ax.legend(handles, labels, **kwargs)


def bin_axis_label(edges, what: str = "inlier ratio of the blob candidates") -> str:
    """The x label of the inlier-ratio panels, noting unequal bins (``edges`` in [0, 1]) drawn equally wide.

    Examples
    --------
    >>> bin_axis_label([0, 0.1, 0.2, 0.3, 0.5, 1.0])
    'inlier ratio of the blob candidates (%); unequal bins drawn equally wide'
    >>> bin_axis_label([0, 0.5, 1.0])
    'inlier ratio of the blob candidates (%)'
    """
    w = np.diff(np.asarray(edges, np.float64))
    equal = np.allclose(w, w[0]) if len(w) else True
    return f"{what} (%)" + ("" if equal else "; unequal bins drawn equally wide")


def plot_pair_share(ax, table, *, color="0.45", title: str | None = None, drop_empty: bool = True, bins=None,
                    fontsize: float = 7.0, xlabel: bool = True) -> None:
    """Bars of the share (%) of (pair, setup) cases per inlier-ratio bin of an
    :func:`~ctxmatch_lib.report.inlier_bin_table`, case counts above; ``bins``: see :func:`shared_bins`."""
    share = table.groupby(level="bin", sort=False, observed=True)["share (%)"].first()
    share = share.reindex(list(bins) if bins is not None else _bins(table, drop_empty)).fillna(0.0)
    n = table.groupby(level="bin", sort=False, observed=True)["n"].max().reindex(share.index).fillna(0)
    x = np.arange(len(share))
    ax.bar(x, share.to_numpy(), 0.7, color=color)
    for xi, v, c in zip(x, share.to_numpy(), n.to_numpy()):
        ax.text(xi, v + 2, f"{c:.0f}", ha="center", va="bottom", fontsize=fontsize)
    _bin_edge_ticks(ax, list(share.index))
    ax.set_ylim(0, 100)
    ax.set_yticks([0, 50, 100])
    ax.set_ylabel("share of cases (%)")
    if xlabel:
        ax.set_xlabel("inlier ratio of the blob candidates (%)")
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title, pad=2)
