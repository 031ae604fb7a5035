"""Drawing images, keypoints and matches, after LightGlue's ``viz2d``: each helper draws on a given ``ax``
and never calls ``plt.show()``.

Keypoints are ``(N, 2)`` float arrays of (x, y) pixels with the origin at the centre of the top-left pixel,
which is exactly where ``imshow`` puts pixel ``(0, 0)``, so points are drawn without any shift. An image
pair is drawn side by side in *one* axes (:func:`plot_image_pair`), so that match lines are plain line
segments and a grid of pairs is a plain grid of axes; image-2 points are drawn shifted by the returned
offset.

Match colours keep the meaning of the paper's figures (Fig. 3, the appendix match grids) in a colour-blind-safe
palette (Okabe–Ito, :mod:`ctxmatch_lib.plots.palette`): correct matches that are kept sky blue (the paper: green),
wrong ones kept vermillion (red), correct ones dropped (by a DTM iteration, by 1SAC) yellow, wrong ones dropped
reddish purple (light red) (:data:`MATCH_COLORS`, :func:`match_colors`). The paper's green / red are ΔE ≈ 12 apart
for a deuteranope, sky blue / vermillion ΔE ≈ 100.
"""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from .palette import OKABE_ITO

__all__ = [
    "MATCH_COLORS",
    "match_colors",
    "plot_image",
    "plot_image_pair",
    "plot_keypoints",
    "plot_matches",
    "plot_flow",
    "add_text",
    "color_legend",
    "plot_scored_matches",
    "plot_match_result",
]

#: The four-colour code of the paper's match figures, colour-blind safe (the paper's colour in comments).
MATCH_COLORS = {
    "correct": OKABE_ITO["sky_blue"],                # kept, correct (green)
    "wrong": OKABE_ITO["vermillion"],                # kept, wrong (red)
    "correct_dropped": OKABE_ITO["yellow"],          # dropped, correct (yellow)
    "wrong_dropped": OKABE_ITO["reddish_purple"],    # dropped, wrong (light red)
}


def match_colors(correct, kept=None) -> np.ndarray:
    """RGBA colour per match from its ground-truth label and whether a later step kept it.

    Parameters
    ----------
    correct : array_like of shape (K,) bool
        Ground-truth label of each match.
    kept : array_like of shape (K,) bool, optional
        Whether the match survived the later step (a DTM iteration, 1SAC); all ``True`` by default.

    Returns
    -------
    ndarray of shape (K, 4)
        Colours from :data:`MATCH_COLORS`.

    Examples
    --------
    >>> match_colors([True, False], [True, False]).shape
    (2, 4)
    """
    from matplotlib.colors import to_rgba

    correct = np.asarray(correct, bool).reshape(-1)
    kept = np.ones_like(correct) if kept is None else np.asarray(kept, bool).reshape(-1)
    if kept.shape != correct.shape:
        raise ValueError(f"correct and kept must have the same length, got {len(correct)} and {len(kept)}")
    table = np.array([to_rgba(MATCH_COLORS[k]) for k in ("wrong_dropped", "correct_dropped", "wrong", "correct")])
    return table[2 * kept.astype(int) + correct.astype(int)]


def _as_display(img, dim: float) -> tuple[np.ndarray, dict]:
    img = np.asarray(img)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 1) * 255
    shown = (img.astype(np.float32) * dim / 255.0).clip(0, 1)
    kw = {"cmap": "gray", "vmin": 0, "vmax": 1} if shown.ndim == 2 else {}
    return shown, kw


def plot_image(ax, img, *, title: str | None = None, dim: float = 1.0, alpha: float = 1.0,
               offset=(0.0, 0.0)) -> None:
    """Show ``img`` (``(H, W)`` gray or ``(H, W, 3)`` RGB, uint8 or float in [0, 1]) with pixel ``(r, c)``
    at ``(x, y) = (c, r) + offset``; ``dim`` < 1 darkens it so that coloured matches stand out, ``alpha``
    < 1 fades it towards the background so that dark drawings stand out."""
    shown, kw = _as_display(img, dim)
    h, w = shown.shape[:2]
    ox, oy = offset
    ax.imshow(shown, extent=(ox - 0.5, ox + w - 0.5, oy + h - 0.5, oy - 0.5), interpolation="bilinear",
              alpha=alpha, **kw)
    ax.set_axis_off()
    if title:
        ax.set_title(title)


def plot_image_pair(ax, img1, img2, *, gap: int = 16, dim: float = 1.0, titles=None) -> np.ndarray:
    """Draw two images side by side in one axes, image 2 to the right of image 1 with ``gap`` pixels
    between them, tops aligned.

    Returns
    -------
    ndarray of shape (2,)
        The (x, y) offset to add to image-2 points.
    """
    h1, w1 = np.asarray(img1).shape[:2]
    h2, w2 = np.asarray(img2).shape[:2]
    offset = np.array([w1 + gap, 0.0])
    plot_image(ax, img1, dim=dim)
    plot_image(ax, img2, dim=dim, offset=offset)
    ax.set_xlim(-0.5, offset[0] + w2 - 0.5)
    ax.set_ylim(max(h1, h2) - 0.5, -0.5)
    ax.set_aspect("equal")
    if titles:
        ax.set_title(titles if isinstance(titles, str) else " | ".join(titles))
    return offset


def plot_keypoints(ax, kpts, *, color="lime", ps: float = 4, offset=(0.0, 0.0), **kwargs) -> None:
    """Scatter keypoints ``(N, 2)`` (x, y) pixels, shifted by ``offset``."""
    kpts = np.asarray(kpts, np.float64).reshape(-1, 2) + np.asarray(offset, np.float64)
    ax.scatter(kpts[:, 0], kpts[:, 1], c=color, s=ps, linewidths=0, **kwargs)


def plot_matches(ax, kpts1, kpts2, *, color="lime", lw: float = 0.6, ps: float = 0.0, alpha: float = 1.0,
                 offset=(0.0, 0.0), zorder: float = 2, linestyle="solid") -> None:
    """Lines from ``kpts1[k]`` to ``kpts2[k] + offset`` (both ``(K, 2)`` (x, y) pixels).

    ``color`` is one colour or one per match (``(K, 4)``, e.g. :func:`match_colors`); ``ps`` > 0 also marks
    the endpoints; ``linestyle`` is any matplotlib line style. Use with :func:`plot_image_pair` and its offset.
    """
    p1 = np.asarray(kpts1, np.float64).reshape(-1, 2)
    p2 = np.asarray(kpts2, np.float64).reshape(-1, 2) + np.asarray(offset, np.float64)
    if len(p1) != len(p2):
        raise ValueError(f"kpts1 and kpts2 must have the same length, got {len(p1)} and {len(p2)}")
    if len(p1) == 0:
        return
    lines = LineCollection(np.stack([p1, p2], axis=1), colors=color, linewidths=lw, alpha=alpha, zorder=zorder,
                           linestyles=linestyle)
    ax.add_collection(lines)
    if ps > 0:
        ax.scatter(*p1.T, c=color, s=ps, linewidths=0, zorder=zorder, alpha=alpha)
        ax.scatter(*p2.T, c=color, s=ps, linewidths=0, zorder=zorder, alpha=alpha)


def plot_flow(ax, kpts_from, kpts_to, *, color="lime", lw: float = 0.8, ps: float = 3.0, alpha: float = 1.0,
              zorder: float = 2, linestyle="solid") -> None:
    """Motion-flow vectors drawn on one image: a segment from each keypoint ``kpts_from[k]`` of this
    image to the position ``kpts_to[k]`` of its match in the other image, with a dot at the keypoint
    (the paper's Fig. 3 style). Both are ``(K, 2)`` (x, y) pixels."""
    plot_matches(ax, kpts_from, kpts_to, color=color, lw=lw, alpha=alpha, zorder=zorder, linestyle=linestyle)
    p = np.asarray(kpts_from, np.float64).reshape(-1, 2)
    if ps > 0 and len(p):
        ax.scatter(p[:, 0], p[:, 1], c=color, s=ps, linewidths=0, zorder=zorder, alpha=alpha)


def add_text(ax, text: str, *, pos=(0.01, 0.99), fs: float = 9, color="w", va="top", ha="left") -> None:
    """A text label in axes coordinates on a dark rounded box (readable over any image)."""
    ax.text(*pos, text, transform=ax.transAxes, fontsize=fs, va=va, ha=ha, color=color,
            bbox=dict(boxstyle="round,pad=0.25", fc="black", ec="none", alpha=0.6))


def color_legend(ax_or_fig, labels: dict, **kwargs):
    """A legend of coloured line handles, ``labels`` mapping text -> colour, or -> ``(colour, style)`` where
    style is a line style (``"--"``) or a marker (``"o"``); ``kwargs`` go to ``legend``."""
    from matplotlib.lines import Line2D
    from matplotlib.markers import MarkerStyle

    handles = []
    for value in labels.values():
        colour, style = value if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], str) \
            else (value, "-")
        if style in MarkerStyle.markers and style not in ("", " ", "None"):
            handles.append(Line2D([], [], color=colour, ls="", marker=style, ms=5, mec="black", mew=0.4))
        else:
            handles.append(Line2D([], [], color=colour, lw=1.8, ls=style))
    return ax_or_fig.legend(handles, list(labels), **kwargs)


#: How :func:`plot_match_result` draws the matches that the model step rejected (they are not good matches,
#: and must not look like them): vermillion, thin, dashed, under the kept ones.
REJECTED_STYLE = {"color": OKABE_ITO["vermillion"], "lw": 0.5, "linestyle": (0, (2.0, 1.5)), "alpha": 0.8}


def plot_scored_matches(ax, kpts1, kpts2, scores, *, offset=(0.0, 0.0), cmap="viridis_r", norm=None,
                        lw: float = 0.7, ps: float = 2.0, zorder: float = 3):
    """Match lines coloured by their score (lower is better, as every ctxmatch score): the best on top in the
    bright end of ``cmap``, the worst underneath in its dark end.

    Parameters
    ----------
    kpts1, kpts2 : array_like of shape (K, 2)
        Endpoints, (x, y) pixels; ``kpts2`` is shifted by ``offset`` (:func:`plot_image_pair`).
    scores : array_like of shape (K,)
    norm : matplotlib.colors.Normalize, optional
        Default: the range of ``scores``.

    Returns
    -------
    matplotlib.cm.ScalarMappable
        For a colour bar.
    """
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    scores = np.asarray(scores, np.float64).reshape(-1)
    p1 = np.asarray(kpts1, np.float64).reshape(-1, 2)
    p2 = np.asarray(kpts2, np.float64).reshape(-1, 2)
    if not len(scores) == len(p1) == len(p2):
        raise ValueError(f"kpts1, kpts2 and scores must have the same length, got {len(p1)}, {len(p2)} and "
                         f"{len(scores)}")
    if norm is None:
        lo, hi = (float(scores.min()), float(scores.max())) if len(scores) else (0.0, 1.0)
        norm = Normalize(lo, hi if hi > lo else lo + 1e-9)
    cmap = matplotlib.colormaps[cmap] if isinstance(cmap, str) else cmap
    order = np.argsort(-scores, kind="stable")  # worst first, best drawn last (on top)
    colours = cmap(norm(scores[order]))
    plot_matches(ax, p1[order], p2[order], color=colours, lw=lw, ps=ps, offset=offset, zorder=zorder)
    return ScalarMappable(norm=norm, cmap=cmap)


def plot_match_result(result, image1, image2, *, ax=None, cmap="viridis_r", lw: float = 0.7,
                      title: str | None = None):
    """The picture of ``ctxmatch match --plot``: both images side by side, the kept matches coloured by their
    blob-matching score (colour bar; lower is better) and, after a model step, the matches it rejected dashed in
    vermillion (:data:`REJECTED_STYLE`), with a legend counting both.

    Parameters
    ----------
    result : MatchResult
        Of :func:`ctxmatch_lib.match.match_images`: ``kpts1``, ``kpts2``, ``candidates``,
        ``candidate_scores``, ``keep`` and, when a model step ran, ``model_input`` (the candidates given to it).
    image1, image2 : ndarray
        The two images (``(H, W)`` gray or ``(H, W, 3)`` RGB).
    ax : matplotlib Axes, optional
        Where to draw; a new figure is made when omitted.
    title : str, optional
        Default: the counts and the settings' filters and model.

    Returns
    -------
    matplotlib Figure
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    img1, img2 = np.asarray(image1), np.asarray(image2)
    if ax is None:
        h = max(img1.shape[0], img2.shape[0])
        w = img1.shape[1] + img2.shape[1]
        width = min(14.0, max(6.0, 7.0 * w / max(h, 1) / 2 + 1.5))
        fig, ax = plt.subplots(figsize=(width, width * h / w + 0.9), layout="constrained")
    else:
        fig = ax.figure
    offset = plot_image_pair(ax, img1, img2, dim=0.55)
    cand = np.asarray(result.candidates).reshape(-1, 2)
    cand_scores = np.asarray(result.candidate_scores, np.float64).reshape(-1)
    keep = np.asarray(result.keep, bool).reshape(-1)
    model_input = getattr(result, "model_input", None)
    settings = getattr(result, "settings", {}) or {}
    model = settings.get("model", "none")
    rejected = (np.asarray(model_input, bool) & ~keep) if model_input is not None else np.zeros_like(keep)
    shown = keep | rejected
    lo, hi = (float(cand_scores[shown].min()), float(cand_scores[shown].max())) if shown.any() else (0.0, 1.0)
    norm = Normalize(lo, hi if hi > lo else lo + 1e-9)
    k1, k2 = np.asarray(result.kpts1, np.float64), np.asarray(result.kpts2, np.float64)
    if rejected.any():
        r = cand[rejected]
        plot_matches(ax, k1[r[:, 0]], k2[r[:, 1]], color=REJECTED_STYLE["color"], lw=REJECTED_STYLE["lw"],
                     alpha=REJECTED_STYLE["alpha"], linestyle=REJECTED_STYLE["linestyle"], offset=offset, zorder=2)
    m = cand[keep]
    mappable = plot_scored_matches(ax, k1[m[:, 0]], k2[m[:, 1]], cand_scores[keep], offset=offset, cmap=cmap,
                                   norm=norm, lw=lw)
    cb = fig.colorbar(mappable, ax=ax, fraction=0.03, pad=0.01, shrink=0.9)
    cb.set_label("blob-matching score (lower is better)")
    cb.ax.invert_yaxis()  # better matches up
    step = {"none": "", "1sac": "1SAC", "ransac": "RANSAC", "prosac": "PROSAC"}.get(model, model)
    handles = [Line2D([], [], color=plt.get_cmap(cmap)(0.15), lw=1.5)]
    labels = [f"kept{' by ' + step if step else ''} ({int(keep.sum())}), colour = score"]
    if model_input is not None and model != "none":
        handles.append(Line2D([], [], color=REJECTED_STYLE["color"], lw=1.2, ls=(0, (2.0, 1.5))))
        labels.append(f"rejected by {step} ({int(rejected.sum())})")
    ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=len(handles), frameon=False,
              fontsize=8)
    if title is None:
        filt = "+".join(settings.get("filters", [])) or "no filter"
        title = f"{int(keep.sum())} matches kept of {len(cand)} blob candidates ({filt}{', ' + step if step else ''})"
    ax.set_title(title, fontsize=9)
    return fig
