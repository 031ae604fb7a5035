"""Plot helpers for the notebooks, one module per figure family: each draws on an ``ax`` (or returns a figure)
and never calls ``plt.show()``; :func:`save_figure` shows and writes it (``plots.base``)."""

from .base import (figsize, figure_path, paper_style, plot_toy_matrix, plot_toy_table, provenance, save_figure,
                   written)

__all__ = ["figsize", "figure_path", "paper_style", "plot_toy_matrix", "plot_toy_table", "provenance",
           "save_figure", "written"]
