"""Plot helpers for the notebooks. Each takes an ``ax`` (or returns a figure) and never calls
``plt.show()``; :func:`save_figure` writes with a tight bounding box. Topic modules: ``plots.base``
(figure I/O, the toy example), and further modules per figure family, imported from their module."""

from .base import figure_path, plot_toy_matrix, plot_toy_table, save_figure

__all__ = ["figure_path", "plot_toy_matrix", "plot_toy_table", "save_figure"]
