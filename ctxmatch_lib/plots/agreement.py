"""Our per-method precision and recall against the paper's Tables 1-3 (:func:`plot_agreement`)."""

from __future__ import annotations

import matplotlib.pyplot as plt

from ..report.tables import KIND_LABELS, method_order
from ..report.side_by_side import method_rank_agreement
from .eval import method_style, pr_legend

__all__ = ["plot_agreement"]


def plot_agreement(side, setups=None, *, models=("none",), blob: bool = False, ms: float = 14,
                   panel_size: float = 2.0, figsize=None,
                   metrics=("precision", "recall")):
    """Ours (y) against the paper (x) per method, around y = x: one row of panels per kind and metric, one
    column per configuration, methods styled as in :func:`~ctxmatch_lib.plots.eval.plot_pr_scatter`; each
    title gives Spearman's ρ over the filters (:func:`ctxmatch_lib.report.side_by_side.method_rank_agreement`).

    ``side``: a :func:`ctxmatch_lib.report.side_by_side.side_by_side` frame; ``setups`` default: all of it. Model
    ``"none"`` is drawn hollow; ``blob`` adds the blob candidates (recall 100 % by definition); ``ms`` is the
    marker area (points²); ``figsize`` defaults to ``panel_size`` inches per panel. Returns the Figure.
    """
    present = list(dict.fromkeys(side.index.get_level_values("setup")))
    setups = present if setups is None else list(setups)
    unknown = [s for s in setups if s not in present]
    if unknown:
        raise ValueError(f"setups: {unknown} not in side (has {sorted(present)})")
    bad = [m for m in metrics if m not in ("precision", "recall")]
    if bad:
        raise ValueError(f"metrics must be 'precision' and/or 'recall', got {bad}")
    rows = [(kind, metric) for kind in dict.fromkeys(side.index.get_level_values("kind")) for metric in metrics]
    rho = method_rank_agreement(side)
    if figsize is None:
        figsize = (panel_size * len(setups), panel_size * len(rows) + 0.8)
    fig, axes = plt.subplots(len(rows), len(setups), figsize=figsize, squeeze=False, sharex=True, sharey=True,
                             layout="constrained")
    shown = []
    for c, setup in enumerate(setups):
        for r, (kind, metric) in enumerate(rows):
            ax = axes[r, c]
            ax.plot([0, 100], [0, 100], color="0.6", lw=0.6, zorder=1)
            for model in models:
                try:
                    d = side.xs((setup, kind, model), level=("setup", "kind", "model"))
                except KeyError:
                    continue
                if not blob:
                    d = d[~d["blob"].astype(bool)]
                filled = model != "none"
                for method in method_order(d.index):
                    colour, marker = method_style(method)
                    row = d.loc[method]
                    ax.scatter(row[f"{metric} paper (%)"], row[f"{metric} ours (%)"], s=ms, marker=marker,
                               c=[colour] if filled else "none", edgecolors=colour,
                               linewidths=0.3 if filled else 0.8, zorder=3 if filled else 4)
                    shown.append(method)
            key = (setup, kind, models[0])
            text = f"ρ = {rho.loc[key, f'ρ {metric}']:.2f}" if key in rho.index else "ρ –"
            ax.set_title((f"{setup}\n" if r == 0 else "") + f"{KIND_LABELS.get(kind, kind)} {metric}: {text}",
                         fontsize=7)
            ax.set_xlim(0, 102)
            ax.set_ylim(0, 102)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
            if r == len(rows) - 1:
                ax.set_xlabel("paper (%)", fontsize=7)
            if c == 0:
                ax.set_ylabel(f"ours, {metric} (%)", fontsize=7)
    pr_legend(fig, shown, models=models, ms=4.5, loc="outside lower center", ncol=6, fontsize=7, frameon=False,
              columnspacing=1.0, handletextpad=0.4, title_fontsize=7, handlelength=2.2 if len(models) > 1 else 1.2)
    return fig
