"""RFM-SCAN's reference for ``bench_filters_ref.py --ref rfm_scan=DIR``: the authors' MATLAB code.

``DIR`` is a checkout of StaRainJ/RFM-SCAN (Jiang et al., TIP 2020), outside this repository, read at run time
and never copied here. The filtering is the one of their ``Demo_main.m``, taken from the checkout when the run
starts: its parameter lines (``gamma``, ``Bound``, ``pct``, ``Mu``), the block that adds the random matches
(from ``N = size(X,1);`` to ``X = NoiseX; Y = NoiseY;``), the two clustering rounds between ``tic`` and ``toc``
(``myDist``, ``GetParamater``, ``DBSCAN`` of the checkout) and the two lines after ``toc`` that keep the real
matches assigned to a cluster (``IDX1=IDX1(1:N); ind=find(IDX1>0);``). The demo's ``rand`` draws the added
matches; the benchmark resets the random state to 0 before each call. ``cpu`` is ``cputime`` around all of it.

The demo needs two functions that are not in GNU Octave's core: ``pdist2`` (Statistics Toolbox; here only the
Euclidean distances between the rows of two matrices) and ``mapminmax`` (Deep Learning Toolbox; here only the
per-row min-max map to ``[ymin, ymax]``, a constant row going to ``ymin``). :func:`compile_mex` writes these two
small stand-ins, written for this benchmark from the functions' documented behaviour, into the run's temp dir.

The image sizes (``info``) are not used: the demo draws its random matches in ``[0, max(X)]`` per coordinate.
"""

from __future__ import annotations

from pathlib import Path

#: bench_filters_ref's shared helpers, set by ``bench_filters_ref.plugin`` before this module runs.
host: object

FILES = ("Demo_main.m", "DBSCAN.m", "GetParamater.m", "myDist.m")
FUNC_FILES = ("DBSCAN.m", "GetParamater.m", "myDist.m")

#: Our keyword -> the demo's variables (set after the demo's own parameter lines).
OPTIONS = {"gamma": ("gamma",), "pct": ("pct",), "min_pts_bounds": ("Bound(1)", "Bound(2)"),
           "mu": ("Mu(1)", "Mu(2)")}

_PARAMS = ("gamma", "Bound", "pct", "Mu")

# Stand-ins for the two toolbox functions the demo calls (Octave core has neither).
_PDIST2 = """function D = pdist2(A, B)
% Euclidean distances between the rows of A and the rows of B (the only use in the RFM-SCAN demo).
D = zeros(size(A, 1), size(B, 1));
for c = 1:size(A, 2)
  D = D + (A(:, c) - B(:, c).').^2;
end
D = sqrt(D);
end
"""

_MAPMINMAX = """function Y = mapminmax(X, ymin, ymax)
% Each row of X mapped linearly from [min, max] of the row to [ymin, ymax]; a constant row goes to ymin.
lo = min(X, [], 2); span = max(X, [], 2) - lo; span(span == 0) = 1;
Y = (X - lo) ./ span .* (ymax - ymin) + ymin;
end
"""


def _lines_from(lines: list[str], start: str, stop: str, *, include_stop: bool, after: int = 0) -> tuple[list[str], int]:
    """Lines from the first one (at or after ``after``) starting with ``start`` (included) up to the next one
    starting with ``stop``, and the index of the stop line (``host.block_bounds``)."""
    try:
        i, j = host.block_bounds(lines, start, stop, after=after)
    except ValueError as err:
        raise ValueError(f"Demo_main.m: {err}") from None
    return lines[i:j + 1 if include_stop else j], j


def demo_parts(demo: str) -> tuple[str, str]:
    """(parameter lines, filtering lines) of the authors' ``Demo_main.m``.

    The filtering lines are the random-match block, the two rounds between ``tic`` and ``toc`` and the lines
    after ``toc`` up to ``ind=find(IDX1>0);`` (the kept real rows, 1-based).
    """
    lines = demo.splitlines()
    params = [ln for ln in lines if ln.strip().split("=")[0].strip() in _PARAMS and "=" in ln]
    if len(params) != len(_PARAMS):
        raise ValueError(f"Demo_main.m: expected one line for each of {', '.join(_PARAMS)}")
    noise, _ = _lines_from(lines, "N ", "X = NoiseX", include_stop=True)
    rounds, toc = _lines_from(lines, "tic", "toc", include_stop=False)
    tail, _ = _lines_from(lines, "IDX1=IDX1(1:N)", "ind=", include_stop=True, after=toc)
    return "\n".join(params), "\n".join(noise + rounds[1:] + tail)


def octave_body(root: Path, params: dict) -> str:
    """The body of ``ref_filter(X, Y, small, info)``: the demo's filtering on ``X``, ``Y``; sets ``keep``, ``cpu``."""
    defaults, block = demo_parts(host.find_reference_file(Path(root), "Demo_main.m").read_text(errors="replace"))
    return (f"{defaults}\n{host.octave_assignments('rfm_scan', params)}\nc0 = cputime;\n{block}\n"
            "cpu = cputime - c0;\nkeep = ind;")


def compile_mex(root: Path, dst: Path) -> None:
    """Nothing to compile: writes the ``pdist2`` / ``mapminmax`` stand-ins into ``dst`` (on Octave's path)."""
    (Path(dst) / "pdist2.m").write_text(_PDIST2)
    (Path(dst) / "mapminmax.m").write_text(_MAPMINMAX)
