"""Plot helpers for the notebooks. Each takes an ``ax`` (or returns a figure) and never calls
``plt.show()``; :func:`save_figure` shows the figure in a notebook and writes a PNG and a vector PDF with
their provenance. Topic modules: ``plots.base`` (figure I/O, the IEEE paper style and sizes, the toy
example), ``plots.palette`` (colour-blind-safe colours and their check), and further modules per figure
family, imported from their module."""

from .base import figsize, figure_path, paper_style, plot_toy_matrix, plot_toy_table, provenance, save_figure

__all__ = ["figsize", "figure_path", "paper_style", "plot_toy_matrix", "plot_toy_table", "provenance",
           "save_figure"]
