"""Figure I/O and the paper style: output paths, :func:`save_figure` (PNG + vector PDF with provenance), the
IEEE column sizes, and the toy example of Fig. 1a."""

from __future__ import annotations

import functools
import io
import json
import os
import subprocess
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from ..cache import atomic_path, repo_root

__all__ = ["COLUMN_WIDTHS", "MIN_FONT_PT", "PAPER_RC", "paper_style", "figsize", "min_font_size",
           "check_paper_figure", "SOURCE_PATHS", "source_commit", "provenance", "default_figure_dir", "figure_path",
           "written", "save_figure", "plot_toy_matrix", "plot_toy_table"]

#: Figure widths in inches of one and two columns of an IEEE journal page (IEEEtran: 3.5 in and 7.16 in).
COLUMN_WIDTHS = {1: 3.5, 2: 7.16}
#: Smallest font size, in points, that a paper figure may use at its printed size.
MIN_FONT_PT = 7.0
#: Matplotlib settings of the paper figures: 7-8 pt text, thin lines, embedded TrueType fonts (publishers
#: reject Type-3), constrained layout.
PAPER_RC = {
    "font.size": 7.5, "axes.titlesize": 7.5, "axes.labelsize": 7.5, "xtick.labelsize": 7, "ytick.labelsize": 7,
    "legend.fontsize": 7, "legend.title_fontsize": 7, "figure.titlesize": 8,
    "axes.linewidth": 0.6, "lines.linewidth": 1.0, "lines.markersize": 4, "grid.linewidth": 0.4,
    "xtick.major.width": 0.6, "ytick.major.width": 0.6, "xtick.major.size": 2.5, "ytick.major.size": 2.5,
    "legend.frameon": False, "figure.constrained_layout.use": True, "figure.constrained_layout.h_pad": 0.02,
    "figure.constrained_layout.w_pad": 0.02, "pdf.fonttype": 42, "ps.fonttype": 42,
}


def paper_style() -> None:
    """Switch matplotlib to :data:`PAPER_RC` (for the rest of the session, as notebooks want)."""
    plt.rcParams.update(PAPER_RC)


def figsize(columns: int = 2, height: float | None = None, *, aspect: float = 0.62) -> tuple[float, float]:
    """``(width, height)`` in inches of a figure ``columns`` (1 or 2) IEEE columns wide; ``height`` defaults
    to ``aspect`` × width.

    Examples
    --------
    >>> figsize(1, 2.0)
    (3.5, 2.0)
    """
    if columns not in COLUMN_WIDTHS:
        raise ValueError(f"columns must be 1 or 2, got {columns!r}")
    width = COLUMN_WIDTHS[columns]
    return (width, float(height) if height is not None else round(aspect * width, 3))


def _texts(fig):
    from matplotlib.text import Text

    return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]


def min_font_size(fig) -> float:
    """The smallest font size (points) among the visible texts of ``fig`` (``inf`` without text)."""
    sizes = [t.get_fontsize() for t in _texts(fig)]
    return min(sizes) if sizes else float("inf")


def check_paper_figure(fig, columns: int) -> None:
    """Raise ``ValueError`` unless ``fig`` fits ``columns`` IEEE columns and no text is under 7 pt there."""
    width = fig.get_size_inches()[0]
    if width > COLUMN_WIDTHS[columns] + 1e-3:
        raise ValueError(f"figure is {width:.2f} in wide, more than {columns} column(s) ({COLUMN_WIDTHS[columns]} in)")
    small = sorted({(round(t.get_fontsize(), 2), t.get_text()[:30]) for t in _texts(fig)
                    if t.get_fontsize() < MIN_FONT_PT - 1e-9})
    if small:
        raise ValueError(f"texts under {MIN_FONT_PT:g} pt at the printed size: {small[:5]}")


#: The paths whose content makes the figures: a commit touching none of them leaves the provenance unchanged.
SOURCE_PATHS = ("ctxmatch_lib", "notebooks", "pyproject.toml", "environment.txt")


@functools.lru_cache(maxsize=1)
def source_commit() -> str:
    """The last commit that changed the figures' sources (:data:`SOURCE_PATHS`), 12 hex digits, with
    ``-dirty`` when tracked files among them differ from it; ``""`` outside a git checkout. Not ``HEAD``,
    which committing the regenerated figures would change."""
    root = repo_root()
    if root is None or not (root / ".git").exists():
        return ""
    run = functools.partial(subprocess.run, cwd=root, capture_output=True, text=True, timeout=10)
    try:
        head = run(["git", "log", "-1", "--format=%H", "--", *SOURCE_PATHS]).stdout.strip()[:12]
        dirty = run(["git", "status", "--porcelain", "--untracked-files=no", "--", *SOURCE_PATHS]).stdout
    except (OSError, subprocess.SubprocessError):
        return ""
    return f"{head}-dirty" if head and dirty.strip() else head


def provenance(**fields) -> dict:
    """What produced a figure or table: ``version``, ``git_commit`` (:func:`source_commit`) and ``fields``
    (lists joined with ", "; a ``None`` left out, never an empty value). No date or time, so a rerun with the
    same numbers writes the same record.

    Examples
    --------
    >>> sorted(provenance(dataset="embedded", blob=["paper-best", "baseline"]))
    ['blob', 'dataset', 'git_commit', 'version']
    >>> provenance(blob=["paper-best", "baseline"])["blob"]
    'paper-best, baseline'
    >>> "max_keypoints" in provenance(max_keypoints=None)
    False
    """
    from .. import __version__

    out = {"version": __version__, "git_commit": source_commit()}
    for key, value in fields.items():
        if isinstance(value, (list, tuple)):
            value = ", ".join(map(str, value))
        if value is not None:
            out[key] = str(value)
    return out


_provenance = provenance  # save_figure's argument of the same name shadows it


def default_figure_dir() -> Path:
    """Where figures go without ``output_dir``: ``$CTXMATCH_FIGURES``, else the checkout's ``build/figures``
    (never the tracked ``figures/``), else ``./ctxmatch-figures``."""
    env = os.environ.get("CTXMATCH_FIGURES")
    if env:
        return Path(env).expanduser()
    root = repo_root()
    return root / "build" / "figures" if root is not None else Path.cwd() / "ctxmatch-figures"


def figure_path(name: str, output_dir: str | os.PathLike | None = None) -> Path:
    """Path of ``name`` in ``output_dir`` (default :func:`default_figure_dir`), the folder created."""
    base = Path(output_dir).expanduser() if output_dir else default_figure_dir()
    path = base / name
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def written(*paths) -> str:
    """``"wrote a, b"``: the line a notebook prints after writing ``paths``, each relative to the checkout when
    inside it, else absolute.

    Examples
    --------
    >>> written("/tmp/x/tables.csv", "/tmp/x/tables.md")
    'wrote /tmp/x/tables.csv, /tmp/x/tables.md'
    """
    root = repo_root()
    shown = []
    for path in paths:
        path = Path(path).expanduser().absolute()
        if root is not None and path.is_relative_to(root):
            path = path.relative_to(root)
        shown.append(path.as_posix())
    return "wrote " + ", ".join(shown)


def _in_notebook() -> bool:
    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover - IPython is a dependency of the notebooks only
        return False
    shell = get_ipython()
    return shell is not None and hasattr(shell, "kernel")


def _figure_colors(fig, limit: int = 96) -> list:
    """The distinct opaque RGB colours (0-255) that the artists of ``fig`` are drawn with, most used first."""
    from collections import Counter

    from matplotlib.collections import Collection
    from matplotlib.colors import to_rgba_array
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.text import Text

    seen = Counter()

    def add(colours):
        try:
            arr = to_rgba_array(colours)
        except (TypeError, ValueError):
            return
        for r, g, b, a in arr:
            if a > 0:
                seen[(round(r * 255), round(g * 255), round(b * 255))] += 1

    for art in fig.findobj():
        if isinstance(art, Line2D):
            add(art.get_color())
            add(art.get_markerfacecolor())
        elif isinstance(art, (Collection, Patch)):
            add(art.get_edgecolor())
            add(art.get_facecolor())
        elif isinstance(art, Text):
            add(art.get_color())
    return [c for c, _ in seen.most_common(limit)]


def _quantize_png(path: Path, colors: int, meta: dict, keep=()) -> None:
    """Rewrite the PNG ``path`` with ``colors`` colours: ``keep`` (the figure's drawing colours, so a rare legend
    colour survives) plus an adaptive palette; text chunks and dpi are kept."""
    from PIL import Image, PngImagePlugin

    if not 2 <= colors <= 256:
        raise ValueError(f"png_colors must be in [2, 256], got {colors}")
    with Image.open(path) as im:
        dpi = im.info.get("dpi")
        rgb = im.convert("RGB")
    keep = list(dict.fromkeys(tuple(int(v) for v in c) for c in keep))[: colors // 2]
    adaptive = rgb.quantize(colors=colors - len(keep), method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    flat = adaptive.getpalette()[: 3 * (colors - len(keep))]
    flat += [v for c in keep for v in c]
    pal = Image.new("P", (1, 1))
    pal.putpalette(flat + flat[:3] * (256 - len(flat) // 3))
    out = rgb.quantize(palette=pal, dither=Image.Dither.NONE)
    info = PngImagePlugin.PngInfo()
    for key, value in meta.items():
        info.add_text(key, value)
    out.save(path, format="png", optimize=True, pnginfo=info, dpi=dpi)


def save_figure(fig, name: str, output_dir: str | os.PathLike | None = None, *, dpi: int = 300,
                formats=("png", "pdf"), provenance: dict | None = None, columns: int | None = None,
                show: bool | None = None, png_colors: int | None = None) -> Path:
    """Show ``fig`` (in a notebook), write ``<output_dir>/<name>.png`` and a vector ``.pdf`` atomically, close it,
    and say where (in a notebook: one line, :func:`written`).

    Parameters
    ----------
    name : str
        File stem (a suffix is dropped).
    output_dir : path, optional
        See :func:`figure_path`.
    dpi : int
        Resolution of the PNG and of images embedded in the PDF.
    formats : sequence of str
        Formats written; the first one's path is returned.
    provenance : dict, optional
        Merged into :func:`provenance`; stored as JSON in the PNG chunk ``ctxmatch:provenance`` and the PDF
        ``Subject``.
    columns : {1, 2}, optional
        A paper figure: checked by :func:`check_paper_figure`, saved at its exact size.
    show : bool, optional
        Display before saving and print the paths written; default: in a Jupyter kernel.
    png_colors : int, optional
        An adaptive PNG palette of this many colours (≤ 256), for photo figures; the PDF keeps full colour.
    """
    if columns is not None:
        check_paper_figure(fig, columns)
    record = _provenance(**(provenance or {}))
    record["figure"] = Path(name).stem
    text = json.dumps(record, sort_keys=True)
    show = show if show is not None else _in_notebook()
    bbox = None if columns is not None else "tight"
    if show:
        from IPython.display import Image, display

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, bbox_inches=bbox)
        display(Image(data=buf.getvalue()))
    creator = f"ctxmatch {record['version']} ({record['git_commit']})"
    paths = []
    for fmt in formats:
        path = figure_path(f"{Path(name).stem}.{fmt}", output_dir)
        if fmt == "png":
            meta = {"Title": path.stem, "Software": creator, "ctxmatch:provenance": text}
        elif fmt == "pdf":
            # No CreationDate: matplotlib would write the clock (and honours SOURCE_DATE_EPOCH only).
            meta = {"Title": path.stem, "Creator": creator, "Subject": text, "Keywords": "ctxmatch provenance",
                    "CreationDate": None}
        else:
            meta = None
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches=bbox, pad_inches=0.02, format=fmt, metadata=meta)
            if fmt == "png" and png_colors:
                _quantize_png(tmp, png_colors, meta, keep=_figure_colors(fig))
        paths.append(path)
    plt.close(fig)
    if show:
        print(written(*paths))
    return paths[0]


def plot_toy_matrix(ax, D: np.ndarray, matches=(), *, title: str = "D", fontsize: float = 7.5) -> None:
    """Draw the distance matrix ``D`` (rows: image-1 keypoints) as a table, circling ``matches`` (1-based
    (row, col) pairs)."""
    from matplotlib.colors import Normalize

    D = np.asarray(D, np.float64)
    n, m = D.shape
    cmap = plt.get_cmap("Blues_r")
    norm = Normalize(vmin=D.min(), vmax=D.max() * 1.6)
    ax.imshow(D, cmap=cmap, norm=norm)
    for i in range(n):
        for j in range(m):
            r, g, b, _ = cmap(norm(D[i, j]))
            dark = 0.2126 * r + 0.7152 * g + 0.0722 * b < 0.45
            ax.text(j, i, f"{D[i, j]:g}", ha="center", va="center", fontsize=fontsize,
                    color="white" if dark else "black")
    for i, j in matches:
        ax.add_patch(plt.Circle((j - 1, i - 1), 0.42, fill=False, color="#D55E00", lw=1.2))
    ax.set_xticks(range(m), [str(j + 1) for j in range(m)])
    ax.set_yticks(range(n), [str(i + 1) for i in range(n)])
    ax.set_xlabel("keypoint j of image 2 (columns)")
    ax.set_ylabel("keypoint i of image 1 (rows)")
    ax.set_title(title)


def plot_toy_table(ax, table, *, fontsize: float = 7.0) -> None:
    """Render the table of Fig. 1a (:func:`ctxmatch_lib.blob.toy.toy_table`); G lists 1-based (i, j) pairs."""
    ax.axis("off")
    cells = [[r.setup, ", ".join(f"({i},{j})" for i, j in r.computed), "✓" if r.agrees else "✗"]
             for r in table.itertuples()]
    tab = ax.table(cellText=cells, colLabels=["setup", "G: (i, j) computed by ctxmatch_lib", "= paper"],
                   loc="center", cellLoc="left", colLoc="left", colWidths=[0.24, 0.64, 0.12])
    tab.auto_set_font_size(False)
    tab.set_fontsize(fontsize)
    tab.scale(1, 1.35)
    for cell in tab.get_celld().values():
        cell.set_linewidth(0.4)
