"""Plot helpers for the notebooks: each takes an ``ax`` (or builds a figure) and never calls ``plt.show``."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from .._paths import atomic_path

__all__ = ["save_figure", "figure_path", "plot_toy_matrix", "plot_toy_table"]


def figure_path(name: str, output_dir: str | os.PathLike | None = None) -> Path:
    """Where figure ``name`` goes: ``$CTXMATCH_FIGURES`` if set (tests use it to keep the tracked
    figures untouched), else ``output_dir``, else ``figures/`` of the current folder."""
    base = os.environ.get("CTXMATCH_FIGURES") or output_dir or "figures"
    path = Path(base) / name
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def save_figure(fig, name: str, output_dir: str | os.PathLike | None = None, *, dpi: int = 150) -> Path:
    """Write ``fig`` as ``<output_dir>/<name>`` (``.png`` added when missing), tight bounding box; the
    file is written to a temporary name first and moved into place, so an interrupted run leaves no
    half-written figure. Returns the path."""
    if not Path(name).suffix:
        name = f"{name}.png"
    path = figure_path(name, output_dir)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=path.suffix[1:])
    plt.close(fig)
    return path


def plot_toy_matrix(ax, D: np.ndarray, matches=(), *, title: str = "D") -> None:
    """Draw the distance matrix ``D`` as a table, circling ``matches`` (1-based (row, col) pairs)."""
    n, m = D.shape
    ax.imshow(D, cmap="Blues_r", vmin=D.min(), vmax=D.max() * 1.6)
    for i in range(n):
        for j in range(m):
            ax.text(j, i, f"{D[i, j]:g}", ha="center", va="center", fontsize=9)
    for i, j in matches:
        ax.add_patch(plt.Circle((j - 1, i - 1), 0.42, fill=False, color="tab:red", lw=1.5))
    ax.set_xticks(range(m), [str(j + 1) for j in range(m)])
    ax.set_yticks(range(n), [str(i + 1) for i in range(n)])
    ax.set_title(title)


def plot_toy_table(ax, table) -> None:
    """Render the table of Fig. 1a (a :func:`ctxmatch_lib.blob.toy.toy_table` frame) as text."""
    ax.axis("off")
    cells = [[r.setup, ", ".join(f"({i},{j})" for i, j in r.computed), "✓" if r.agrees else "✗"]
             for r in table.itertuples()]
    tab = ax.table(cellText=cells, colLabels=["setup", "G (computed by ctxmatch_lib)", "= paper"],
                   loc="center", cellLoc="left", colLoc="left", colWidths=[0.22, 0.66, 0.12])
    tab.auto_set_font_size(False)
    tab.set_fontsize(8)
    tab.scale(1, 1.4)
