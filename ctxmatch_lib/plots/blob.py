"""Plot helpers for the blob-matching sweep (Sec. 5.2): the mAP heat map of Fig. 5 and the per-parameter
bands of Fig. 6. Each takes an ``ax`` and never calls ``plt.show``; inputs come from
:func:`ctxmatch_lib.sweep.heatmap_matrix` (mAP in %, rows f × f', columns t_o × D × W)."""

from __future__ import annotations

import numpy as np

from .palette import OKABE_ITO

__all__ = ["plot_blob_heatmap", "plot_blob_bands", "W_LABELS", "FEATURE_LABELS"]

#: Figure titles of the feature presets of :data:`ctxmatch_lib.features.FEATURE_PRESETS`. The paper's learned
#: orientation and its HardNet2/SOSNet weights are not obtainable here: the blocks that use stand-ins say so.
FEATURE_LABELS = {
    "sift-rootsift": "SIFT + RootSIFT",
    "sift-rootsift-upright": "upright SIFT + RootSIFT",
    "sift": "SIFT + SIFT (plain L2)",
    "sift-rootsgloh2": "SIFT + RootsGLOH2",
    "harrisz-rootsift": "HarrisZ + RootSIFT (orientation: dominant-gradient stand-in)",
    "harrisz-rootsgloh2": "HarrisZ + RootsGLOH2",
    "sift-hardnet2": "SIFT + HardNet2 stand-in (HardTFeat weights, OriNet orientation)",
    "sift-sosnet": "SIFT + SOSNet stand-in (TFeat liberty weights, OriNet orientation)",
    "harrisz-hardnet2": "HarrisZ + HardNet2 stand-in (HardTFeat weights, OriNet orientation)",
    "harrisz-sosnet": "HarrisZ + SOSNet stand-in (TFeat liberty weights, OriNet orientation)",
}

#: Short names of W(a, b) (Eq. 15) in the order of the grid.
W_LABELS = {"a": "a", "b": "b", "min": "min", "max": "max", "harmonic": "2ab/(a+b)"}

_D_COLOURS = {"D≥": OKABE_ITO["blue"], "D+≥": OKABE_ITO["orange"], "D+": OKABE_ITO["bluish_green"]}
_W_MARKERS = {"a": "<", "b": ">", "min": "v", "max": "^", "harmonic": "o"}


def _groups(labels):
    """(start, stop, label) runs of equal consecutive labels."""
    out, start = [], 0
    for k in range(1, len(labels) + 1):
        if k == len(labels) or labels[k] != labels[start]:
            out.append((start, k, labels[start]))
            start = k
    return out


def plot_blob_heatmap(ax, matrix, *, title: str = "", vmin=None, vmax=None, cmap: str = "viridis",
                      mark_best: bool = True, row_labels: bool = True, col_labels: bool = True):
    """Draw one detector+descriptor block of the heat map of Fig. 5.

    Parameters
    ----------
    ax : matplotlib Axes
    matrix : DataFrame
        mAP (%) with a (f, f') row index and a (t_o, D, W) column index
        (:func:`~ctxmatch_lib.sweep.heatmap_matrix`).
    title : str
    vmin, vmax : float, optional
        Colour range (default: this block's own range; one shared range washes out the better blocks).
    mark_best : bool
        Outline the best cell in red and write its mAP above it.
    row_labels, col_labels : bool
        Tick labels on the left (f, f') and at the bottom (t_o, with D sub-bands).

    Returns
    -------
    matplotlib.image.AxesImage
        For a shared colour bar.
    """
    from matplotlib.patches import Rectangle

    values = matrix.to_numpy(dtype=float)
    im = ax.imshow(values, aspect="auto", interpolation="nearest", cmap=cmap, vmin=vmin, vmax=vmax)
    rows = list(matrix.index)
    cols = list(matrix.columns)
    # Separators: thick between t_o groups and between f groups, thin between D sub-bands.
    for start, _, _ in _groups([c[0] for c in cols])[1:]:
        ax.axvline(start - 0.5, color="white", lw=1.6)
    for start, _, _ in _groups([c[:2] for c in cols])[1:]:
        ax.axvline(start - 0.5, color="white", lw=0.4, alpha=0.8)
    for start, _, _ in _groups([r[0] for r in rows])[1:]:
        ax.axhline(start - 0.5, color="white", lw=1.2)
    if row_labels:
        # One label per f group (rows f' = 1, 3, 5 inside it), readable at 7 pt in a column-wide block.
        fg = _groups([r[0] for r in rows])
        ax.set_yticks([(a + b - 1) / 2 for a, b, _ in fg], [lab for _, _, lab in fg])
        ax.set_yticks(range(len(rows)), minor=True)
        ax.tick_params(axis="y", which="minor", length=1.5)
        fps = list(dict.fromkeys(str(r[1]) for r in rows))
        ax.set_ylabel(f"f  (rows: f' = {', '.join(fps)})")
    else:
        ax.set_yticks([])
    if col_labels:
        tg = _groups([c[0] for c in cols])
        ax.set_xticks([(a + b - 1) / 2 for a, b, _ in tg], [f"$t_o$ = {lab}" for _, _, lab in tg])
        ax.set_xticks([(a + b - 1) / 2 for a, b, _ in _groups([c[:2] for c in cols])], minor=True)
        ax.tick_params(axis="x", which="minor", length=2)
        ax.set_xlabel("$t_o$ × D (sub-bands D≥, D+≥, D+) × W (a, b, min, max, 2ab/(a+b) in each)")
    else:
        ax.set_xticks([])
    if mark_best and np.isfinite(values).any():
        r, c = np.unravel_index(np.nanargmax(values), values.shape)
        ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec="red", lw=1.2, clip_on=False))
        up = r >= len(rows) / 2  # write the value on the side with more room
        ax.annotate(f"best {values[r, c]:.1f}", (c, r), xytext=(0, 8 if up else -8), textcoords="offset points",
                    ha="center", va="bottom" if up else "top", color="black", fontsize=7,
                    bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="red", lw=0.6, alpha=0.9),
                    annotation_clip=False)
    ax.set_title(title)
    return im


def plot_blob_bands(ax, row, *, title: str = "", ylim=None, legend: bool = True):
    """Per-parameter mAP bands of Fig. 6 for one (f, f') row: t_o groups, D sub-bands, W in order.

    Parameters
    ----------
    ax : matplotlib Axes
    row : Series
        mAP (%) indexed by (t_o, D, W) labels: one row of :func:`~ctxmatch_lib.sweep.heatmap_matrix`.
    title : str
    ylim : (float, float), optional
    legend : bool
        Legends for D (colours) and W (markers).
    """
    from matplotlib.lines import Line2D

    labels = list(row.index)
    y = row.to_numpy(dtype=float)
    x = np.arange(len(y), dtype=float)
    t_groups = _groups([c[0] for c in labels])
    for k, (a, b, lab) in enumerate(t_groups):
        if k % 2 == 0:
            ax.axvspan(a - 0.5, b - 0.5, color="0.93", zorder=0)
        ax.text((a + b - 1) / 2, 1.005, f"$t_o$ = {lab}", transform=ax.get_xaxis_transform(), ha="center",
                va="bottom", fontsize=7)
    for a, b, (_, d) in _groups([c[:2] for c in labels]):
        colour = _D_COLOURS.get(d, "k")
        ax.plot(x[a:b], y[a:b], "-", color=colour, lw=0.9, zorder=2)
        for k in range(a, b):
            ax.plot(x[k], y[k], _W_MARKERS.get(labels[k][2], "o"), color=colour, ms=3, zorder=3)
    ax.set_xlim(-0.5, len(y) - 0.5)
    ax.set_xticks([(a + b - 1) / 2 for a, b, _ in _groups([c[:2] for c in labels])],
                  [d for _, _, (_, d) in _groups([c[:2] for c in labels])], fontsize=7)
    ax.set_ylabel("mAP (%)")
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.grid(axis="y", lw=0.4, alpha=0.6)
    if legend:
        d_handles = [Line2D([], [], color=c, lw=1.5, label=d) for d, c in _D_COLOURS.items()]
        w_handles = [Line2D([], [], color="0.3", ls="", marker=mk, label=f"W = {W_LABELS[w]}")
                     for w, mk in _W_MARKERS.items()]
        ax.legend(handles=d_handles + w_handles, loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7,
                  frameon=False)
    ax.set_title(title, pad=12)
