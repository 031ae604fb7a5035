"""Plot helpers for the filter evaluation (Sec. 5.3, Appendix "DTM evaluation"): the precision/recall
scatter of Fig. 7 (``pr_plot``) and the inlier-ratio histograms (``inl_plot``). Each helper draws on a given
``ax`` from a table of :mod:`ctxmatch_lib.report` and never calls ``plt.show()``.

As in the paper, results without a model are blue and with 1SAC red (the colour-blind-safe Okabe–Ito blue and
vermillion); each method has its own marker.
"""

from __future__ import annotations

import numpy as np

from ..report import method_label, method_order
from .palette import OKABE_ITO

__all__ = [
    "MODEL_COLORS",
    "method_marker",
    "method_color",
    "plot_pr_scatter",
    "fit_limits",
    "place_labels",
    "pr_legend",
    "shared_bins",
    "plot_inlier_bars",
    "plot_pair_share",
]

#: Colour per model step: the paper's blue (no model) and red (1SAC), colour-blind safe.
MODEL_COLORS = {"none": OKABE_ITO["blue"], "1sac": OKABE_ITO["vermillion"], "ransac": OKABE_ITO["bluish_green"]}
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


def fit_limits(values, *, pad: float = 0.08, min_span: float = 10.0, bounds=(0.0, 100.0)) -> tuple[float, float]:
    """Axis limits around ``values`` (NaNs ignored): ``pad`` × span on each side, at least ``min_span``
    wide, clipped to ``bounds`` plus a little room for the markers on the bounds.

    Examples
    --------
    >>> fit_limits([80, 95, 100])
    (78.4, 101.0)
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
    return (round(max(bounds[0] - 1.0, lo - pad * span), 3), round(min(bounds[1] + 1.0, hi + pad * span), 3))


def _boxes_overlap(a, b) -> float:
    """Overlap area of two (x0, y0, x1, y1) boxes."""
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def place_labels(ax, xy, texts, colors, *, fontsize: float = 7.0,
                 radii=(2.5, 7, 12, 18, 25, 33, 42, 52, 64, 78), marker_pt: float = 4.5) -> list:
    """Label the points ``xy`` (``(N, 2)`` data coordinates) of ``ax`` without overlaps.

    Each label tries positions around its point, nearest first (right, left, above, below, the diagonals, then
    eight more directions, at growing distances ``radii`` in points); it takes the first one that overlaps no
    label placed before, no marker of the axes and stays inside the axes, or the least bad one. Labels away from their point get a thin
    leader line. Placement uses the figure's current layout, so call it after the layout is settled (legend,
    title, colour bar added); the labels are kept out of the layout so that it does not move afterwards.

    Returns
    -------
    list of matplotlib.text.Annotation
    """
    from matplotlib.collections import PathCollection
    from matplotlib.text import Text

    fig = ax.figure
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()
    px = fig.dpi / 72.0
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    pts = ax.transData.transform(xy)
    frame = ax.get_window_extent(renderer)
    r_mk = marker_pt * px * 0.6
    obstacles = []
    for c in ax.collections:
        if isinstance(c, PathCollection) and len(c.get_offsets()):
            for q in ax.transData.transform(np.asarray(c.get_offsets(), np.float64)):
                obstacles.append((q[0] - r_mk, q[1] - r_mk, q[0] + r_mk, q[1] + r_mk))
    directions = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1),
                  (1, 0.5), (-1, 0.5), (1, -0.5), (-1, -0.5), (0.5, 1), (-0.5, 1), (0.5, -1), (-0.5, -1)]
    # Crowded points first: they have the fewest free places near them.
    near = (np.linalg.norm(pts[:, None] - pts[None], axis=2) < 25 * px).sum(axis=1)
    order = np.argsort(-near, kind="stable")
    placed, out = [], [None] * len(pts)
    for k in order:
        (x, y), (dx, dy), text, colour = pts[k], xy[k], texts[k], colors[k]
        t = Text(0, 0, text, fontsize=fontsize)
        t.set_figure(fig)
        bb = t.get_window_extent(renderer)
        w, h = bb.width, bb.height
        def cost_of(cx, cy):
            box = (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)
            inside = (box[0] >= frame.x0 + 1 and box[2] <= frame.x1 - 1 and box[1] >= frame.y0 + 1
                      and box[3] <= frame.y1 - 1)
            cost = sum(_boxes_overlap(box, b) for b in placed) * 10 + sum(
                _boxes_overlap(box, b) for b in obstacles) + (0 if inside else 1e6)
            return cost + np.hypot(cx - x, cy - y) * 1e-3, box  # nearer is better among equals

        best = None
        for r in radii:
            for ux, uy in directions:
                ox, oy = ux * (r * px + (w / 2 if ux else 0)), uy * (r * px + (h / 2 if uy else 0))
                cost, box = cost_of(x + ox, y + oy)
                if best is None or cost < best[0]:
                    best = (cost, box, (ox / px, oy / px), r)
            if best[0] < 1.0:
                break
        if best[0] >= 1.0:  # no free place around the point: any free place in the axes, nearest first
            for cy in np.arange(frame.y0 + h / 2 + 1, frame.y1 - h / 2, h / 2):
                for cx in np.arange(frame.x0 + w / 2 + 1, frame.x1 - w / 2, max(w / 4, 2.0)):
                    cost, box = cost_of(cx, cy)
                    if cost < best[0]:
                        best = (cost, box, ((cx - x) / px, (cy - y) / px), np.hypot(cx - x, cy - y) / px)
        _, box, (ox, oy), r = best
        placed.append(box)
        arrow = dict(arrowstyle="-", color=colour, lw=0.4, alpha=0.7, shrinkA=0, shrinkB=2) if r > 8 else None
        ann = ax.annotate(text, (dx, dy), xytext=(ox, oy), textcoords="offset points", ha="center", va="center",
                          fontsize=fontsize, color=colour, zorder=5, arrowprops=arrow, annotation_clip=False)
        ann.set_in_layout(False)
        out[k] = ann
    return out


def plot_pr_scatter(ax, table, *, title: str | None = None, models=("none", "1sac"), connect: bool = True,
                    annotate: bool = True, ms: float = 22, lim=None, label_models=("none", "1sac"),
                    fit_exclude=("blob",), fontsize: float = 7.0) -> list:
    """Mean precision (y) against mean recall (x), one marker per method and one colour per model.

    Parameters
    ----------
    table : DataFrame
        A :func:`ctxmatch_lib.report.method_table` restricted to one kind: index (model, method) (a
        (kind, model, method) index with a single kind also works).
    models : sequence of str
        Models to draw (blue: none, vermillion: 1SAC).
    connect : bool
        A thin grey arrow from each method's no-model point to its 1SAC point (the effect of 1SAC).
    annotate : bool
        Write the method names next to the points of ``label_models`` (in the model's colour), placed by
        :func:`place_labels` so that they do not overlap. Placement needs the final layout: with
        ``annotate=False`` call :func:`place_labels` later yourself with the returned points.
    lim : (float, float) or None
        Limits of both axes; ``None``: each axis fitted to the data (:func:`fit_limits`).
    fit_exclude : sequence of str
        Methods left out of the fit (the unfiltered ``blob`` candidates, far below every filter, would squeeze
        the filters into a corner); a point outside the fitted axes is drawn on the border, its label giving its
        true precision / recall and an arrow pointing outwards.

    Returns
    -------
    list of (x, y, label, colour)
        The points to label (those of ``label_models``, in display position), for :func:`place_labels`.
    """
    t = table.droplevel("kind") if "kind" in table.index.names else table
    methods = method_order(t.index.get_level_values("method"))
    pts = [(model, m, float(t.loc[(model, m), "recall (%)"]), float(t.loc[(model, m), "precision (%)"]))
           for model in models for m in methods if (model, m) in t.index]
    if lim is None:
        fit = [p for p in pts if p[1] not in fit_exclude] or pts
        xlim, ylim = fit_limits([p[2] for p in fit]), fit_limits([p[3] for p in fit])
        # Room above 100 % precision for the labels of the many points there; no tick beyond 100.
        ylim = (ylim[0], max(ylim[1], min(104.0, ylim[1] + 0.06 * (ylim[1] - ylim[0]))))
    else:
        xlim = ylim = tuple(lim)
    shown = {}
    for model, m, x, y in pts:
        cx, cy = min(max(x, xlim[0]), xlim[1]), min(max(y, ylim[0]), ylim[1])
        shown[model, m] = (cx, cy, (cx, cy) != (x, y))
    to_label = []
    for model, m, x, y in pts:
        cx, cy, clipped = shown[model, m]
        colour = MODEL_COLORS.get(model, "k")
        line_marker = method_marker(m) in "x1234+|_"
        ax.scatter(cx, cy, marker=method_marker(m), s=ms * (1.6 if m == "blob" else 1), c=colour,
                   linewidths=1.0 if line_marker else 0.3, edgecolors=None if line_marker else "white", zorder=3,
                   alpha=0.9, clip_on=False)
        label = _label(m)
        if clipped:
            dx, dy = np.sign(x - cx), np.sign(y - cy)
            ax.annotate("", (cx + dx * 0.001, cy + dy * 0.001), xytext=(cx, cy),
                        arrowprops=dict(arrowstyle="-|>", color=colour, lw=0.6, mutation_scale=6), zorder=4,
                        annotation_clip=False)
            label = f"{label} (P {y:.0f}, R {x:.0f} %)"
        if model in label_models:
            to_label.append((cx, cy, label, colour))
    if connect and {"none", "1sac"} <= set(models):
        for m in methods:
            if ("none", m) in shown and ("1sac", m) in shown:
                (ax_, ay, _), (bx, by, _) = shown["none", m], shown["1sac", m]
                ax.annotate("", xy=(bx, by), xytext=(ax_, ay),
                            arrowprops=dict(arrowstyle="-|>", color="0.6", lw=0.5, shrinkA=3, shrinkB=3,
                                            mutation_scale=6), zorder=2)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_yticks([v for v in ax.get_yticks() if ylim[0] <= v <= 100])
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.set_xlabel("recall (%)")
    ax.set_ylabel("precision (%)")
    if title:
        ax.set_title(title)
    if annotate and to_label:
        place_labels(ax, [(x, y) for x, y, _, _ in to_label], [lab for _, _, lab, _ in to_label],
                     [c for _, _, _, c in to_label], fontsize=fontsize)
    return to_label


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


def shared_bins(tables, drop_empty: bool = True) -> list:
    """The bins to draw in every column of a figure of several :func:`~ctxmatch_lib.report.inlier_bin_table`
    tables: every bin populated in at least one of them (all bins with ``drop_empty=False``), in order, so that
    all columns share one x axis."""
    tables = list(tables)
    order = list(dict.fromkeys(b for t in tables for b in t.index.get_level_values("bin")))
    if not drop_empty:
        return order
    keep = {b for t in tables for b in _bins(t, True)}
    return [b for b in order if b in keep]


def plot_inlier_bars(ax, table, *, metric: str = "precision (%)", model: str = "none", methods=None,
                     title: str | None = None, min_n: int = 1, drop_empty: bool = True, bins=None,
                     fontsize: float = 7.0) -> None:
    """Grouped bars of ``metric`` per inlier-ratio bin, one bar per method (the histograms of ``inl_plot``).

    ``table`` is a :func:`ctxmatch_lib.report.inlier_bin_table`; bins with fewer than ``min_n`` cases are
    left blank, and with ``drop_empty`` bins without any case are not drawn. ``bins`` fixes the bins drawn
    (:func:`shared_bins`, so that the columns of a figure agree); a bin without cases then shows "n=0". The
    number of cases of each bin is written under its label.
    """
    t = table.xs(model, level="model")
    bins = list(bins) if bins is not None else _bins(t, drop_empty)
    methods = method_order(methods or t.index.get_level_values("method"))
    width = 0.85 / len(methods)
    x = np.arange(len(bins))
    for k, m in enumerate(methods):
        vals = np.array([t.loc[(b, m), metric] if (b, m) in t.index and t.loc[(b, m), "n"] >= min_n else np.nan
                         for b in bins])
        ax.bar(x - 0.425 + (k + 0.5) * width, np.nan_to_num(vals), width, color=method_color(m),
               label=_label(m), edgecolor="none")
    present = set(t.index.get_level_values("bin"))
    n = [int(t.xs(b, level="bin")["n"].max()) if b in present else 0 for b in bins]
    for xi, c in zip(x, n):
        if c < min_n:  # say why the bin is blank
            ax.text(xi, 50, "no pairs", rotation=90, ha="center", va="center", fontsize=fontsize, color="0.5")
    ax.set_xticks(x, [f"{b}\n(n={c})" for b, c in zip(bins, n)], fontsize=fontsize)
    ax.set_ylim(0, 100)
    ax.set_ylabel(metric)
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title)


def plot_pair_share(ax, table, *, color="0.45", title: str | None = None, drop_empty: bool = True, bins=None,
                    fontsize: float = 7.0) -> None:
    """Bars of the share of (pair, setup) cases per inlier-ratio bin (``share (%)`` of an
    :func:`~ctxmatch_lib.report.inlier_bin_table`); with ``drop_empty`` bins without any case are not drawn;
    ``bins`` fixes the bins (:func:`shared_bins`)."""
    share = table.groupby(level="bin", sort=False, observed=True)["share (%)"].first()
    share = share.reindex(list(bins) if bins is not None else _bins(table, drop_empty)).fillna(0.0)
    n = table.groupby(level="bin", sort=False, observed=True)["n"].max().reindex(share.index).fillna(0)
    x = np.arange(len(share))
    ax.bar(x, share.to_numpy(), 0.6, color=color)
    for xi, v, c in zip(x, share.to_numpy(), n.to_numpy()):
        ax.text(xi, v + 1, f"{v:.0f} %\nn={c:.0f}", ha="center", va="bottom", fontsize=fontsize)
    # Bin names without their unit, which the axis label carries, so that five fit in a column-wide panel.
    ax.set_xticks(x, [str(b).replace(" %", "").replace("-", "–") for b in share.index], fontsize=fontsize)
    ax.set_ylim(0, 118)
    ax.set_yticks(range(0, 101, 20))
    ax.set_ylabel("share of pairs (%)")
    ax.set_xlabel("inlier ratio of the blob candidates (%)")
    ax.grid(True, axis="y", lw=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
