"""Plots of the blob-matching sweep (Sec. 5.2): the mAP heat map of Fig. 5 and the bands of Fig. 6, from
:func:`ctxmatch_lib.report.blob.heatmap_matrix` (mAP %, rows f × f', columns t_o × D × W)."""

from __future__ import annotations

import numpy as np

from .palette import OKABE_ITO

__all__ = ["plot_blob_heatmap", "heatmap_key", "plot_blob_bands", "W_LABELS", "FEATURE_LABELS"]

#: Figure titles of :data:`ctxmatch_lib.features.FEATURE_PRESETS`, naming the stand-ins.
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


#: Colours of the heat map's W key strip (the Okabe–Ito colours D does not use) and f' greys.
_W_COLOURS = {"a": OKABE_ITO["sky_blue"], "b": OKABE_ITO["yellow"], "min": OKABE_ITO["vermillion"],
              "max": OKABE_ITO["reddish_purple"], "harmonic": OKABE_ITO["black"]}
_FP_GREYS = ("0.85", "0.55", "0.15")
_BEST_COLOR = "#ff1f1f"


def _w_key(label) -> str:
    """The W code of a column label (``"a"``, ``"harmonic"``, ... or its display name)."""
    inv = {v: k for k, v in W_LABELS.items()}
    return inv.get(str(label), str(label))


def plot_blob_heatmap(ax, matrix, *, title: str = "", vmin=None, vmax=None, cmap: str = "viridis",
                      mark_best: bool = True, row_labels: bool = True, col_labels: bool = True,
                      key_strips: bool = True):
    """Draw one detector+descriptor block of the heat map of Fig. 5; key strips (no room for texts) give each
    column its D and W colour and each row its f' grey, explained by :func:`heatmap_key`.

    ``matrix``: :func:`~ctxmatch_lib.report.blob.heatmap_matrix`. ``vmin``/``vmax`` default to the block's own
    range (a shared one washes out the better blocks); ``mark_best`` outlines the best cell. Returns the
    ``AxesImage``, for a colour bar.
    """
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Rectangle

    values = matrix.to_numpy(dtype=float)
    n_rows, n_cols = values.shape
    im = ax.imshow(values, aspect="auto", interpolation="nearest", cmap=cmap, vmin=vmin, vmax=vmax,
                   extent=(-0.5, n_cols - 0.5, n_rows - 0.5, -0.5))
    rows = list(matrix.index)
    cols = list(matrix.columns)
    # Separators: thick between t_o groups and between f groups, thin between D sub-bands.
    for start, _, _ in _groups([c[0] for c in cols])[1:]:
        ax.plot([start - 0.5] * 2, [-0.5, n_rows - 0.5], color="white", lw=1.4)
    for start, _, _ in _groups([c[:2] for c in cols])[1:]:
        ax.plot([start - 0.5] * 2, [-0.5, n_rows - 0.5], color="white", lw=0.35, alpha=0.8)
    for start, _, _ in _groups([r[0] for r in rows])[1:]:
        ax.plot([-0.5, n_cols - 0.5], [start - 0.5] * 2, color="white", lw=1.0)
    strip = max(1.2, 0.045 * n_rows)  # strip thickness in rows, so that it is visible on a short block
    left = -0.5
    bottom = n_rows - 0.5
    if key_strips:
        patches, colours = [], []
        for c, lab in enumerate(cols):
            patches.append(Rectangle((c - 0.5, bottom + 0.15 * strip), 1, strip))
            colours.append(_D_COLOURS.get(str(lab[1]), "0.5"))
            patches.append(Rectangle((c - 0.5, bottom + 1.15 * strip), 1, strip))
            colours.append(_W_COLOURS.get(_w_key(lab[2]), "0.5"))
        fps = list(dict.fromkeys(r[1] for r in rows))
        width = max(1.6, 0.02 * n_cols)  # in columns: about as thick on paper as the column strips
        for r, lab in enumerate(rows):
            patches.append(Rectangle((-0.5 - 1.15 * width, r - 0.5), width, 1))
            colours.append(_FP_GREYS[fps.index(lab[1]) % len(_FP_GREYS)])
        ax.add_collection(PatchCollection(patches, facecolors=colours, edgecolors="none", zorder=1))
        bottom += 2.25 * strip
        left -= 1.3 * width
    ax.set_xlim(left, n_cols - 0.5)
    ax.set_ylim(bottom, -0.5)
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    if row_labels:
        fg = _groups([r[0] for r in rows])
        ax.set_yticks([(a + b - 1) / 2 for a, b, _ in fg], [lab for _, _, lab in fg])
        ax.tick_params(axis="y", length=0, pad=1.5)
        ax.set_ylabel("f (× f')")
    else:
        ax.set_yticks([])
    tg = _groups([c[0] for c in cols])
    ax.set_xticks([(a + b - 1) / 2 for a, b, _ in tg], [f"$t_o$ = {lab}" for _, _, lab in tg] if col_labels else [])
    ax.tick_params(axis="x", length=0, pad=1.5)
    if mark_best and np.isfinite(values).any():
        r, c = np.unravel_index(np.nanargmax(values), values.shape)
        ax.add_patch(Rectangle((c - 0.5, r - 0.5), 1, 1, fill=False, ec=_BEST_COLOR, lw=1.0, zorder=4,
                               clip_on=False))
        ax.plot([c], [-0.5], marker="v", ms=4, color=_BEST_COLOR, mec="black", mew=0.3, clip_on=False, zorder=5)
    ax.set_title(title, pad=4)
    return im


def heatmap_key(fig_or_ax, *, best: bool = True, **kwargs):
    """The legend of :func:`plot_blob_heatmap`'s key strips and best-cell marker; ``kwargs`` go to ``legend``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(fc=c, ec="none") for c in _D_COLOURS.values()]
    handles += [Patch(fc=g, ec="0.5", lw=0.3) for g in (*_W_COLOURS.values(), *_FP_GREYS)]
    labels = [*_D_COLOURS, *(f"W = {W_LABELS[w]}" for w in _W_COLOURS), *(f"f' = {fp}" for fp in (1, 3, 5))]
    if best:
        handles.append(Line2D([], [], ls="", marker="s", mfc="none", mec=_BEST_COLOR, ms=6, mew=1.0))
        labels.append("best setup of the block")
    return fig_or_ax.legend(handles, labels, **kwargs)


def plot_blob_bands(ax, row, *, title: str = "", ylim=None, legend: bool = True):
    """Per-parameter mAP bands of Fig. 6 for one (f, f') ``row`` of
    :func:`~ctxmatch_lib.report.blob.heatmap_matrix`: t_o groups, D sub-bands (colours), W (markers, legend
    with ``legend``)."""
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
    d_groups = _groups([c[:2] for c in labels])
    for a, b, (_, d) in d_groups:
        colour = _D_COLOURS.get(d, "k")
        ax.plot(x[a:b], y[a:b], "-", color=colour, lw=0.9, zorder=2)
        for k in range(a, b):
            ax.plot(x[k], y[k], _W_MARKERS.get(labels[k][2], "o"), color=colour, ms=3, zorder=3)
    ax.set_xlim(-0.5, len(y) - 0.5)
    ax.set_xticks([(a + b - 1) / 2 for a, b, _ in d_groups], [d for _, _, (_, d) in d_groups], fontsize=7)
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
