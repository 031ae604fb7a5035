"""Drawing images, keypoints and matches on an ``ax``, after LightGlue's ``viz2d``. Keypoints, (x, y)
pixels with (0, 0) the centre of the top-left pixel, are drawn unshifted; image-2 points of a pair shift by
the offset :func:`plot_image_pair` returns. Match colours: :data:`MATCH_COLORS` (the paper's four roles).
"""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from .palette import OKABE_ITO

__all__ = ["MATCH_COLORS", "match_colors", "plot_image", "plot_image_pair", "plot_keypoints", "plot_matches",
           "plot_flow", "add_text", "color_legend", "plot_scored_matches", "plot_match_result"]

#: The four-colour code of the paper's match figures, colour-blind safe (the paper's colour in comments).
MATCH_COLORS = {
    "correct": OKABE_ITO["sky_blue"],                # kept, correct (green)
    "wrong": OKABE_ITO["vermillion"],                # kept, wrong (red)
    "correct_dropped": OKABE_ITO["yellow"],          # dropped, correct (yellow)
    "wrong_dropped": OKABE_ITO["reddish_purple"],    # dropped, wrong (light red)
}


def match_colors(correct, kept=None) -> np.ndarray:
    """``(K, 4)`` RGBA colours (:data:`MATCH_COLORS`) of matches from their ground-truth label ``correct`` and
    whether a later step (a DTM iteration, 1SAC) ``kept`` them (default all).

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
    """Draw two images side by side in one axes, ``gap`` pixels apart, tops aligned; returns the (x, y) offset
    to add to image-2 points."""
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
    """Lines from ``kpts1[k]`` to ``kpts2[k] + offset`` (``(K, 2)`` pixels); ``color``: one or one per match
    (e.g. :func:`match_colors`); ``ps`` > 0 also marks the endpoints."""
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
    """Flow vectors on one image (Fig. 3 style): a segment from each keypoint ``kpts_from[k]`` to its match's
    position ``kpts_to[k]`` in the other image, with a dot at the keypoint."""
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


#: How :func:`plot_match_result` draws the matches the model step rejected: thin, dashed, under the kept ones.
REJECTED_STYLE = {"color": OKABE_ITO["vermillion"], "lw": 0.5, "linestyle": (0, (2.0, 1.5)), "alpha": 0.8}


def plot_scored_matches(ax, kpts1, kpts2, scores, *, offset=(0.0, 0.0), cmap="viridis_r", norm=None,
                        lw: float = 0.7, ps: float = 2.0, zorder: float = 3):
    """Match lines coloured by ``scores`` (lower is better), the best drawn on top; ``kpts2`` is shifted by
    ``offset``, ``norm`` defaults to the scores' range. Returns a ``ScalarMappable`` for a colour bar."""
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
    """The picture of ``ctxmatch match --plot`` for a :func:`ctxmatch_lib.match.match_images` ``result``: the
    images side by side, kept matches coloured by blob score (colour bar; lower is better) and, after a model
    step, those it rejected dashed (:data:`REJECTED_STYLE`). ``ax`` default: a new figure; ``title`` default:
    the counts, filters and model. Returns the Figure.
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
        plot_matches(ax, k1[r[:, 0]], k2[r[:, 1]], **REJECTED_STYLE, offset=offset, zorder=2)
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
