"""Tests for the plot helpers: ctxmatch_lib.plots.viz2d, .dtm and .eval (tiny synthetic inputs, Agg backend)."""

import json
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from matplotlib.collections import LineCollection, PathCollection  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from ctxmatch_lib.dtm import dtm, dtm_boundary  # noqa: E402
from ctxmatch_lib.plots import dtm as pdtm  # noqa: E402
from ctxmatch_lib.plots import eval as peval  # noqa: E402
from ctxmatch_lib.plots import viz2d  # noqa: E402
from ctxmatch_lib.testing import planted_homography_matches  # noqa: E402


@pytest.fixture
def ax():
    fig, ax = plt.subplots()
    yield ax
    plt.close(fig)


def _segments(ax):
    return sum(len(c.get_segments()) for c in ax.collections if isinstance(c, LineCollection))


# ------------------------------------------------------------------------------------------- viz2d


def test_match_colors_four_colour_code():
    c = viz2d.match_colors([True, False, True, False], [True, True, False, False])
    expected = [viz2d.MATCH_COLORS[k] for k in ("correct", "wrong", "correct_dropped", "wrong_dropped")]
    assert c.shape == (4, 4)
    assert [tuple(row) for row in c] == [to_rgba(e) for e in expected]
    assert [tuple(r) for r in viz2d.match_colors([True])] == [to_rgba(viz2d.MATCH_COLORS["correct"])]
    assert viz2d.match_colors([]).shape == (0, 4)
    with pytest.raises(ValueError, match="same length"):
        viz2d.match_colors([True, False], [True])


def test_plot_image_pixel_centres(ax):
    viz2d.plot_image(ax, np.zeros((4, 6), np.uint8), offset=(10, 0))
    assert ax.images[0].get_extent() == [9.5, 15.5, 3.5, -0.5]


def test_plot_image_pair_and_matches(ax):
    img1, img2 = np.zeros((30, 40), np.uint8), np.full((20, 50, 3), 200, np.uint8)
    off = viz2d.plot_image_pair(ax, img1, img2, gap=5)
    assert off.tolist() == [45.0, 0.0]
    assert ax.get_xlim() == (-0.5, 94.5) and ax.get_ylim() == (29.5, -0.5)
    p1 = np.array([[1.0, 2.0], [3.0, 4.0]])
    viz2d.plot_matches(ax, p1, p1, offset=off, color=viz2d.match_colors([True, False]), ps=2)
    seg = [c for c in ax.collections if isinstance(c, LineCollection)][0].get_segments()
    assert np.allclose(seg[0], [[1, 2], [46, 2]]) and len(seg) == 2
    with pytest.raises(ValueError, match="same length"):
        viz2d.plot_matches(ax, p1, p1[:1])


def test_plot_matches_and_flow_empty(ax):
    viz2d.plot_matches(ax, np.empty((0, 2)), np.empty((0, 2)))
    viz2d.plot_flow(ax, np.empty((0, 2)), np.empty((0, 2)))
    assert _segments(ax) == 0


def test_plot_flow_draws_vectors_and_dots(ax):
    viz2d.plot_flow(ax, [[0, 0], [5, 5]], [[1, 0], [5, 9]], color="r", ps=3)
    assert _segments(ax) == 2
    assert sum(isinstance(c, PathCollection) for c in ax.collections) == 1


def test_add_text_and_legend(ax):
    viz2d.add_text(ax, "hello")
    leg = viz2d.color_legend(ax, {"a": "red", "b": "blue"})
    assert ax.texts[0].get_text() == "hello"
    assert [t.get_text() for t in leg.get_texts()] == ["a", "b"]


# ------------------------------------------------------------------------------------------- dtm plots


def test_triangulation_edges_exact():
    assert pdtm.triangulation_edges([[0, 1, 2], [1, 2, 3]]).tolist() == [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]
    assert pdtm.triangulation_edges(np.empty((0, 3), int)).shape == (0, 2)


def test_plot_triangulation_splits_keypoint_edges(ax):
    pts = np.array([[0, 0], [1, 0], [0, 1], [5, 5]], float)
    simplices = np.array([[0, 1, 2], [1, 2, 3]])
    pdtm.plot_triangulation(ax, pts, simplices, n_vertices=3, keypoint_color="g")
    lc = [c for c in ax.collections if isinstance(c, LineCollection)]
    # Edges among the first three points (keypoints): 3; edges touching point 3 (boundary): 2.
    assert sorted(len(c.get_segments()) for c in lc) == [2, 3]
    green = [c for c in lc if tuple(c.get_colors()[0][:3]) == to_rgba("g")[:3]][0]
    assert len(green.get_segments()) == 3


def test_plot_triangulation_degenerate(ax):
    pdtm.plot_triangulation(ax, np.zeros((2, 2)), np.empty((0, 3), int))
    assert _segments(ax) == 0


GRID = np.stack(np.meshgrid(np.arange(100, 301, 40.0), np.arange(100, 261, 40.0)), -1).reshape(-1, 2)


@pytest.mark.parametrize("method", ["alpha", "convex", "canvas", "corners"])
def test_plot_boundary_steps_and_mesh(method):
    b = dtm_boundary(GRID, (640, 480), method)
    fig, (a1, a2) = plt.subplots(1, 2)
    pdtm.plot_canvas(a1, (640, 480))
    pdtm.plot_boundary_steps(a1, b)
    pdtm.plot_boundary_mesh(a2, b)
    # The view holds every vertex and boundary point.
    (x0, x1), (y1, y0) = a2.get_xlim(), a2.get_ylim()
    allpts = np.vstack([GRID, b.points])
    assert (allpts[:, 0] >= x0).all() and (allpts[:, 0] <= x1).all()
    assert (allpts[:, 1] >= y0).all() and (allpts[:, 1] <= y1).all()
    assert _segments(a2) > len(GRID)
    if method in ("alpha", "convex"):
        assert _segments(a1) >= len(b.shape_edges) + len(b.hull_edges)
    plt.close(fig)


def test_plot_boundary_single_vertex(ax):
    b = dtm_boundary(np.array([[50.0, 50.0]]), (200, 100))
    pdtm.plot_boundary_steps(ax, b)
    pdtm.plot_boundary_mesh(ax, b)
    assert ax.lines  # the circle contour


@pytest.fixture(scope="module")
def traced():
    p = planted_homography_matches(300, 0.5, rng=1)
    res = dtm(p.kpts1, p.kpts2, p.matches, p.scores, image_size1=p.image_size, image_size2=p.image_size, trace=True)
    return p, res, p.kpts1[p.matches[:, 0]], p.kpts2[p.matches[:, 1]]


def test_plot_dtm_iteration_flow_and_clusters(traced, ax):
    p, res, p1, p2 = traced
    it = res.trace.iterations[0]
    pdtm.plot_dtm_iteration_flow(ax, it, p1, p2, p.is_inlier)
    lc = [c for c in ax.collections if isinstance(c, LineCollection)]
    # Triangulation, then removed flows, then kept flows.
    assert len(lc[-1].get_segments()) == len(it.kept)
    assert len(lc[-2].get_segments()) == len(it.active) - len(it.kept)
    fig, ax2 = plt.subplots()
    pdtm.plot_dtm_clusters(ax2, it, p1, p2)
    lc2 = [c for c in ax2.collections if isinstance(c, LineCollection)]
    assert len(lc2[-1].get_segments()) == len(it.cluster_members)
    plt.close(fig)


def test_plot_dtm_final(traced):
    p, res, p1, p2 = traced
    fig, (a1, a2) = plt.subplots(1, 2)
    pdtm.plot_dtm_final(a1, res, p1, p2, p.is_inlier, stage=1)
    pdtm.plot_dtm_final(a2, res, p1, p2, p.is_inlier, stage=2, image=2)
    kept1 = [c for c in a1.collections if isinstance(c, LineCollection)][-1]
    assert len(kept1.get_segments()) == int((res.removed_at == 0).sum())
    added = [c for c in a2.collections if isinstance(c, LineCollection)][-1]
    assert len(added.get_segments()) == int((res.readded_at > 0).sum())
    plt.close(fig)


# ------------------------------------------------------------------------------------------- eval plots


def _pr_table():
    idx = pd.MultiIndex.from_product([["none", "1sac"], ["blob", "dtm2", "th"]], names=["model", "method"])
    return pd.DataFrame({"precision (%)": [20, 80, 90, 90, 95, 96], "recall (%)": [100, 85, 60, 90, 80, 55]}, index=idx)


def test_plot_pr_scatter_hollow_without_model_filled_with_1sac(ax):
    t = _pr_table()
    pts = peval.plot_pr_scatter(ax, t, title="x")
    scatters = [c for c in ax.collections if isinstance(c, PathCollection)]
    assert len(scatters) == len(pts) == 6
    assert np.allclose(scatters[0].get_offsets(), [[100, 20]])  # blob, no model: (recall, precision)
    colour = to_rgba(peval.method_style("blob")[0])
    assert len(scatters[0].get_facecolors()) == 0 and tuple(scatters[0].get_edgecolors()[0]) == colour  # hollow
    assert tuple(scatters[3].get_facecolors()[0]) == colour  # blob after 1SAC: the same marker, filled
    assert not ax.texts  # no per-point labels: the legend names the methods
    assert ax.get_xlabel() == "recall (%)" and ax.get_title() == "x"


def test_plot_pr_scatter_accepts_kind_level(ax):
    t = pd.concat({"planar": _pr_table()}, names=["kind"])
    peval.plot_pr_scatter(ax, t, connect=True)
    assert len([c for c in ax.collections if isinstance(c, PathCollection)]) == 6
    assert len(ax.lines) == 3  # the no-model -> 1SAC links


def test_pr_scatter_axes_show_every_point(ax):
    rng = np.random.default_rng(0)
    methods = ["blob", "th", "dtm1", "dtm2", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam"]
    idx = pd.MultiIndex.from_product([["none", "1sac"], methods], names=["model", "method"])
    prec = np.clip(np.r_[13, 88 + 6 * rng.random(10), 97 + 3 * rng.random(11)], 0, 100)
    rec = np.clip(np.r_[100, 80 + 15 * rng.random(10), 25 + 30 * rng.random(11)], 0, 100)
    t = pd.DataFrame({"precision (%)": prec, "recall (%)": rec}, index=idx)
    peval.plot_pr_scatter(ax, t)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 < rec.min() and x1 > rec.max() and y0 < prec.min() and y1 > prec.max()  # nothing pinned
    assert x1 <= 102 and y1 <= 102
    assert max(ax.get_yticks()) <= 100


def test_pr_legend_one_entry_per_method_with_both_fills(ax):
    leg = peval.pr_legend(ax, ["th", "dtm2", "blob"])
    assert [t.get_text() for t in leg.get_texts()] == ["blob", "th", "DTM$_2$"]
    assert "hollow: no model" in leg.get_title().get_text() and "filled: 1SAC" in leg.get_title().get_text()
    leg = peval.pr_legend(ax, ["dtm2"], times={"dtm2": "0.1 s"})
    assert [t.get_text() for t in leg.get_texts()] == ["DTM$_2$ (0.1 s)"]


def test_method_styles_unique_and_stable():
    paper = ["blob", "th", "dtm1", "dtm2", "lmr", "lpm", "glpm", "gms", "vfc", "llt", "rfm_scan", "adalam",
             "oanet", "acne", "pfm", "pgm", "scv", "bm"]
    styles = [peval.method_style(m) for m in paper]
    assert len(set(styles)) == len(paper)  # no two methods share colour and marker
    for a, b in zip(styles, styles[1:]):  # neighbours in the paper's order differ in both
        assert a[0] != b[0] and a[1] != b[1]
    assert all(c in peval.METHOD_COLORS and m in peval.METHOD_MARKERS for c, m in styles)
    # A name outside the paper's gets the same style in any process (no salted str hash).
    import subprocess
    import sys

    code = "from ctxmatch_lib.plots.eval import method_style; print(method_style('somefilter'))"
    other = {seed: subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                  env={**os.environ, "PYTHONHASHSEED": seed}).stdout.strip() for seed in ("1", "2")}
    assert other["1"] == other["2"] == str(peval.method_style("somefilter"))
    assert peval.OKABE_ITO["yellow"] not in peval.METHOD_COLORS


def _bin_table():
    bins, models, methods = ["0-10 %", "10-50 %", "50-100 %"], ["none", "1sac"], ["blob", "dtm2"]
    idx = pd.MultiIndex.from_product([bins, models, methods], names=["bin", "model", "method"])
    n = np.array([2, 0, 3]).repeat(4)
    prec = np.where(n > 0, 50.0, np.nan)
    share = np.array([40.0, 0.0, 60.0]).repeat(4)
    return pd.DataFrame({"precision (%)": prec, "recall (%)": prec, "n": n, "share (%)": share}, index=idx)


def test_plot_inlier_method_one_bar_per_metric_and_model(ax):
    t = _bin_table()
    peval.plot_inlier_method(ax, t, "dtm2")
    assert len(ax.patches) == 2 * 4  # the empty middle bin is dropped; P/R x none/1SAC per bin
    assert not ax.texts  # no "no pairs" text
    faces = {tuple(p.get_facecolor()) for p in ax.patches}
    assert to_rgba(peval.METRIC_COLORS["precision (%)"]) in faces and to_rgba("white") in faces  # filled, hollow
    assert all(to_rgba(c) in {to_rgba(v) for v in peval.OKABE_ITO.values()} for c in peval.METRIC_COLORS.values())
    # Bins not consecutive after the drop: named under their centres.
    assert [lbl.get_text() for lbl in ax.get_xticklabels()] == ["0–10", "50–100"]
    fig, (a1, a2) = plt.subplots(1, 2)
    peval.plot_inlier_method(a1, t, "blob", bins=["0-10 %", "10-50 %", "50-100 %"])
    assert [lbl.get_text() for lbl in a1.get_xticklabels()] == ["0", "10", "50", "100"]  # edges
    peval.plot_pair_share(a2, t)
    assert [round(p.get_height()) for p in a2.patches] == [40, 60]
    assert [x.get_text() for x in a2.texts] == ["2", "3"]
    leg = peval.inlier_legend(a2, empty=False)
    assert len(leg.get_texts()) == 4
    assert len(peval.inlier_legend(a2).get_texts()) == 5  # and the mark of a bin without a value
    plt.close(fig)


def test_inlier_panel_tells_an_empty_bin_from_a_zero(ax):
    """A bin without a value (NaN) gets a grey cross per bar, a true 0 % a stroke on the axis: neither is a bare
    gap that reads as the other."""
    from matplotlib.collections import LineCollection

    t = _bin_table()
    t.loc[("50-100 %", "none", "dtm2"), "precision (%)"] = 0.0
    peval.plot_inlier_method(ax, t, "dtm2", bins=["0-10 %", "10-50 %", "50-100 %"])
    crosses = [c for c in ax.collections if isinstance(c, PathCollection)]
    assert sum(len(c.get_offsets()) for c in crosses) == 4  # the middle bin: P/R x none/1SAC
    assert all(np.allclose(c.get_offsets()[:, 0], c.get_offsets()[:, 0].clip(0.5, 1.5)) for c in crosses)
    strokes = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(strokes) == 1 and len(strokes[0].get_segments()) == 1
    assert np.allclose(strokes[0].get_segments()[0][:, 1], 0.0)


def test_bin_axis_label_says_when_bins_are_unequal():
    assert peval.bin_axis_label([0, 0.1, 0.2, 0.3, 0.5, 1.0]).endswith("unequal bins drawn equally wide")
    assert "unequal" not in peval.bin_axis_label([0, 0.25, 0.5, 0.75, 1.0])


def test_shared_bins_are_the_same_in_every_column():
    a = _bin_table()  # bins 0-10 and 50-100 populated
    b = a.copy()
    b["n"] = np.array([0, 4, 0]).repeat(4)  # only the middle bin populated
    common = peval.shared_bins([a, b])
    assert common == ["0-10 %", "10-50 %", "50-100 %"]
    assert peval.shared_bins([a], drop_empty=True) == ["0-10 %", "50-100 %"]


# ------------------------------------------------------------------------------------------- pr scatter layout


def test_fit_limits():
    assert peval.fit_limits([80, 95, 100]) == (78.8, 101.2)
    lo, hi = peval.fit_limits([50.0, 50.0])
    assert hi - lo >= 10 and lo < 50 < hi
    assert peval.fit_limits([np.nan]) == (0.0, 100.0)
    assert 100 < peval.fit_limits([99.5, 100])[1] <= 102.0  # room for the marker, never far beyond 100 %
    lo, hi = peval.fit_limits([13, 99])
    assert lo < 13 and hi > 99  # every value inside


# ------------------------------------------------------------------------------------------- blob plots


def test_blob_heatmap_scale_per_block():
    from ctxmatch_lib.plots import blob as pblob

    cols = pd.MultiIndex.from_product([["∞", "50%"], ["D≥", "D+"], ["a", "harmonic"]], names=["t_o", "D", "W"])
    rows = pd.MultiIndex.from_product([["1∪", "Ω"], [1, 3, 5]], names=["f", "f'"])
    fig, (a1, a2) = plt.subplots(2, 1)
    for ax, base in ((a1, 20.0), (a2, 80.0)):
        m = pd.DataFrame(base + np.arange(48.0).reshape(6, 8) / 10, index=rows, columns=cols)
        im = pblob.plot_blob_heatmap(ax, m)
        assert im.get_clim() == (base, base + 4.7)  # its own range, not a shared one
    assert [t.get_text() for t in a1.get_yticklabels()] == ["1∪", "Ω"]  # one label per f group
    # The best cell (last row, last column) is outlined inside the axes limits (nothing clipped), no text covers
    # the map, and the key strips give each column its D colour and W grey and each row its f' grey.
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Rectangle

    best = [p for p in a2.patches if isinstance(p, Rectangle) and not p.get_fill()]
    assert len(best) == 1 and best[0].get_xy() == (7 - 0.5, 5 - 0.5)
    (x0, x1), (y1, y0) = a2.get_xlim(), a2.get_ylim()
    assert x0 <= 6.5 and 7.5 <= x1 and y0 <= 4.5 and 5.5 <= y1
    assert not a2.texts
    strips = [c for c in a2.collections if isinstance(c, PatchCollection)]
    assert len(strips) == 1 and len(strips[0].get_paths()) == 2 * 8 + 6
    faces = [tuple(f) for f in strips[0].get_facecolors()]
    assert faces[0] == to_rgba(pblob._D_COLOURS["D≥"]) and faces[2 * 2] == to_rgba(pblob._D_COLOURS["D+"])
    assert faces[1] == to_rgba(pblob._W_COLOURS["a"]) and faces[3] == to_rgba(pblob._W_COLOURS["harmonic"])
    # The five W colours stay apart at print size, also with a red-green deficiency (five greys did not).
    from itertools import combinations

    from ctxmatch_lib.plots.palette import delta_e

    assert min(delta_e(a, b, cvd) for a, b in combinations(pblob._W_COLOURS.values(), 2)
               for cvd in (None, "deuteranopia", "protanopia")) > 20
    assert faces[16] == to_rgba(pblob._FP_GREYS[0]) and faces[18] == to_rgba(pblob._FP_GREYS[2])
    leg = pblob.heatmap_key(a1)
    assert len(leg.get_texts()) == 3 + 5 + 3 + 1
    plt.close(fig)


def test_toy_matrix_axis_labels_and_contrast(ax):
    from ctxmatch_lib.blob.toy import FIG1A_D
    from ctxmatch_lib.plots.base import plot_toy_matrix

    plot_toy_matrix(ax, FIG1A_D, [(2, 2)])
    assert "image 1" in ax.get_ylabel() and "image 2" in ax.get_xlabel()
    colours = {t.get_text(): t.get_color() for t in ax.texts}
    assert colours["0.5"] == "white" and colours["6.1"] == "black"  # darkest and lightest cells


# ------------------------------------------------------------------------------------------- palette


def test_cvd_simulation_and_delta_e_reference_values():
    from ctxmatch_lib.plots.palette import delta_e, simulate_cvd

    # Machado et al. rows sum to 1: greys are unchanged; black-white is ΔE 100.
    assert np.allclose(simulate_cvd(["#808080", "#ffffff", "#000000"]), [[128 / 255] * 3, [1] * 3, [0] * 3], atol=2e-3)
    assert delta_e("black", "white") == pytest.approx(100.0, abs=1e-3)
    assert delta_e("#22c02c", "#22c02c", cvd="deuteranopia") == 0.0
    # The measurement: the paper's green / red fall to ΔE ≈ 12 for a deuteranope.
    assert delta_e("#22c02c", "#e8211d", cvd="deuteranopia") == pytest.approx(12.2, abs=0.1)
    with pytest.raises(ValueError, match="kind"):
        simulate_cvd("red", "achromatopsia")


@pytest.mark.parametrize("cvd", ["deuteranopia", "protanopia", "tritanopia", None])
def test_match_palette_is_colour_blind_safe(cvd):
    from itertools import combinations

    from ctxmatch_lib.plots.palette import delta_e

    c = viz2d.MATCH_COLORS
    assert delta_e(c["correct"], c["wrong"], cvd=cvd) > 60  # five times the ≈ 12 of green / red
    assert min(delta_e(c[a], c[b], cvd=cvd) for a, b in combinations(c, 2)) > 20
    p, r = peval.METRIC_COLORS["precision (%)"], peval.METRIC_COLORS["recall (%)"]
    assert delta_e(p, r, cvd=cvd) > 40  # the two bar colours of the inlier histograms


# ------------------------------------------------------------------------------------------- save_figure


def test_figsize_and_paper_check():
    from ctxmatch_lib.plots import base

    assert base.figsize(1, 2.0) == (3.5, 2.0) and base.figsize(2)[0] == 7.16
    with pytest.raises(ValueError, match="columns"):
        base.figsize(3)
    with plt.rc_context(base.PAPER_RC):
        fig, ax = plt.subplots(figsize=base.figsize(1))
        ax.set_title("t")
        ax.set_xlabel("x")
        assert base.min_font_size(fig) >= base.MIN_FONT_PT
        base.check_paper_figure(fig, 1)
        ax.text(0, 0, "tiny", fontsize=5)
        with pytest.raises(ValueError, match="under 7 pt"):
            base.check_paper_figure(fig, 1)
        plt.close(fig)
        fig = plt.figure(figsize=(9, 3))
        with pytest.raises(ValueError, match="wide"):
            base.check_paper_figure(fig, 2)
        plt.close(fig)


def test_save_figure_png_pdf_with_provenance(tmp_path, monkeypatch):
    from PIL import Image

    from ctxmatch_lib.plots import base

    monkeypatch.setenv("CTXMATCH_FIGURES", str(tmp_path / "env"))
    with plt.rc_context(base.PAPER_RC):
        fig, ax = plt.subplots(figsize=base.figsize(1, 2.0))
        ax.plot([0, 1], [0, 1])
        path = base.save_figure(fig, "demo", tmp_path / "out", columns=1,
                                provenance={"dataset": "embedded", "features": "sift-rootsift", "blob": ["a", "b"]})
    assert path == tmp_path / "out" / "demo.png"  # an explicit folder beats the environment
    assert not plt.fignum_exists(fig.number)
    png = Image.open(path)
    assert png.size == (1050, 600)  # exactly one column (3.5 in) at 300 dpi: no tight bounding box
    record = json.loads(png.text["ctxmatch:provenance"])
    assert record["dataset"] == "embedded" and record["blob"] == "a, b" and record["figure"] == "demo"
    assert record["version"] and "git_commit" in record
    assert "date" not in record  # provenance from the source, never the clock
    pdf = (tmp_path / "out" / "demo.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and b"sift-rootsift" in pdf and b"/Subject" in pdf
    assert b"/Type3" not in pdf  # TrueType fonts (pdf.fonttype 42), as publishers require


def test_figure_folder_never_the_tracked_one(tmp_path, monkeypatch):
    from ctxmatch_lib.cache import repo_root
    from ctxmatch_lib.plots import base

    monkeypatch.delenv("CTXMATCH_FIGURES", raising=False)
    monkeypatch.chdir(tmp_path)  # the kernel's working directory does not matter
    default = base.default_figure_dir()
    if repo_root() is not None:
        assert default == repo_root() / "build" / "figures"
    assert default != (repo_root() or tmp_path) / "figures"
    monkeypatch.setenv("CTXMATCH_FIGURES", str(tmp_path / "f"))
    assert base.figure_path("x.png") == tmp_path / "f" / "x.png"
    assert base.figure_path("x.png", tmp_path / "g") == tmp_path / "g" / "x.png"


def test_save_figure_shows_before_closing(tmp_path, monkeypatch):
    import IPython.display

    from ctxmatch_lib.plots import base

    shown = []
    monkeypatch.setattr(IPython.display, "display", lambda obj: shown.append(obj))
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    base.save_figure(fig, "shown", tmp_path, formats=("png",), show=True)
    assert len(shown) == 1 and shown[0].data[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (tmp_path / "shown.pdf").exists()


def test_save_figure_says_where_it_wrote(tmp_path, monkeypatch, capsys):
    """In a notebook (``show``) one line names every file written, relative to the checkout when inside it;
    outside a notebook nothing is printed."""
    import IPython.display

    from ctxmatch_lib.cache import repo_root
    from ctxmatch_lib.plots import base

    monkeypatch.setattr(IPython.display, "display", lambda obj: None)
    fig, ax = plt.subplots()
    base.save_figure(fig, "said", tmp_path, show=True)
    assert capsys.readouterr().out == f"wrote {tmp_path / 'said.png'}, {tmp_path / 'said.pdf'}\n"
    fig, ax = plt.subplots()
    base.save_figure(fig, "quiet", tmp_path, formats=("png",), show=False)
    assert capsys.readouterr().out == ""
    if repo_root() is not None:
        assert base.written(repo_root() / "figures" / "tables.csv") == "wrote figures/tables.csv"


def test_parquet_carries_provenance(tmp_path):
    import pyarrow.parquet as pq

    from ctxmatch_lib.cache import write_parquet_atomic

    path = write_parquet_atomic(pd.DataFrame({"a": [1, 2]}), tmp_path / "x.parquet", {"dataset": "embedded"})
    meta = pq.read_schema(path).metadata
    assert json.loads(meta[b"ctxmatch"]) == {"dataset": "embedded"}
    prov = json.loads(meta[b"ctxmatch_provenance"])
    assert set(prov) == {"version", "git_commit", "date"}
    assert pd.read_parquet(path)["a"].tolist() == [1, 2]


# ------------------------------------------------------------------------------------------- the gallery

_FIGURES = Path(__file__).resolve().parents[1] / "figures"
# The embedded-default gallery (make figures) and the paper-scale figures on the real data (figures/paper).
GALLERY = sorted(_FIGURES.glob("fig_*.png")) + sorted((_FIGURES / "paper").glob("fig_*.png"))


@pytest.mark.parametrize("png", GALLERY, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_committed_figures_small_vector_and_traceable(png):
    from PIL import Image

    assert png.stat().st_size < 2_000_000, f"{png.name} is {png.stat().st_size / 1e6:.1f} MB"
    assert png.with_suffix(".pdf").exists(), f"no vector PDF beside {png.name}"
    record = json.loads(Image.open(png).text["ctxmatch:provenance"])
    assert {"version", "git_commit", "dataset"} <= set(record)
    # The inputs: the feature and blob setups, or the named configurations that fix both (fig_geometry).
    from ctxmatch_lib.report import SETUPS

    setups = record.get("setups", "").split(", ")  # lists are stored joined
    assert {"features", "blob"} <= set(record) or all(s in SETUPS and s != "global" for s in setups), record
    if png.parent == _FIGURES:  # the gallery of make figures (figures/paper is made by hand, at paper scale)
        assert "date" not in record, "regenerate the gallery: its provenance carries the clock"
    img = Image.open(png)
    width_in = img.size[0] / img.info["dpi"][0]  # matplotlib records its dpi in the pHYs chunk
    assert width_in == pytest.approx(3.5, abs=0.01) or width_in == pytest.approx(7.16, abs=0.01), width_in


def test_png_palette_keeps_the_drawing_colours(tmp_path):
    """A colour drawn on few pixels (a legend entry) survives the 256-colour palette of a photo figure."""
    from PIL import Image

    from ctxmatch_lib.plots import base

    rng = np.random.default_rng(0)
    fig, ax = plt.subplots(figsize=(3.5, 2.5))
    ax.imshow(rng.random((200, 300, 3)), interpolation="nearest")  # a noisy photograph
    ax.plot([10, 60], [10, 10], color=viz2d.MATCH_COLORS["correct_dropped"], lw=1.5)
    path = base.save_figure(fig, "pal", tmp_path, dpi=100, formats=("png",), png_colors=64)
    im = Image.open(path)
    assert im.mode == "P" and "ctxmatch:provenance" in im.text
    yellow = tuple(round(255 * v) for v in to_rgba(viz2d.MATCH_COLORS["correct_dropped"])[:3])
    assert yellow in {c for _, c in im.convert("RGB").getcolors(1 << 16)}


@pytest.mark.parametrize("png", [p for p in GALLERY if p.stem.startswith(("fig_match_examples", "fig_boundary",
                                                                          "fig_pr_scatter", "fig_inlier_hist",
                                                                          "fig_dtm_steps", "fig_gt_methods"))
                                 or p.parent == _FIGURES and p.stem == "fig_blob_heatmap"],
                         ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_gallery_pages_fit_a_journal_page(png):
    """At most 9.5 in tall (an IEEE page's text height is about 9.6 in), so that a figure prints unscaled."""
    from PIL import Image

    img = Image.open(png)
    assert img.size[1] / img.info["dpi"][1] <= 9.5 + 0.01, f"{png.name} is too tall: split it into pages"


# ------------------------------------------------------------------------------------------- ctxmatch match --plot


class _Result:  # the fields of a MatchResult that the picture reads
    def __init__(self, model_input):
        self.kpts1 = np.array([[5.0, 5.0], [20.0, 10.0], [30.0, 25.0], [10.0, 30.0]])
        self.kpts2 = self.kpts1 + 2.0
        self.candidates = np.array([[0, 0], [1, 1], [2, 2], [3, 3]])
        self.candidate_scores = np.array([0.1, 0.4, 0.7, 0.9])
        self.keep = np.array([True, True, False, False])
        self.model_input = model_input
        self.settings = {"filters": ["dtm"], "model": "1sac" if model_input is not None else "none"}


def test_match_picture_colours_by_score_and_shows_the_rejected():
    img = np.zeros((40, 40), np.uint8)
    fig = viz2d.plot_match_result(_Result(np.array([True, True, True, False])), img, img)
    ax = fig.axes[0]
    lines = [c for c in ax.collections if isinstance(c, LineCollection)]
    rejected, kept = lines
    assert len(rejected.get_segments()) == 1 and len(kept.get_segments()) == 2  # candidate 3 was never offered
    assert tuple(rejected.get_colors()[0][:3]) == to_rgba(viz2d.REJECTED_STYLE["color"])[:3]
    cols = kept.get_colors()
    assert not np.allclose(cols[0], cols[1])  # two scores, two colours; best (0.1) drawn last, on top
    best = matplotlib.colormaps["viridis_r"](0.0)
    assert np.allclose(cols[-1], best)
    texts = [t.get_text() for t in ax.get_legend().get_texts()]
    assert texts == ["kept by 1SAC (2), colour = score", "rejected by 1SAC (1)"]
    assert any("score" in a.get_ylabel() for a in fig.axes[1:])  # the colour bar
    plt.close(fig)
    fig = viz2d.plot_match_result(_Result(None), img, img)
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["kept (2), colour = score"]
    plt.close(fig)
    with pytest.raises(ValueError, match="same length"):
        viz2d.plot_scored_matches(plt.gca(), np.zeros((2, 2)), np.zeros((2, 2)), [0.1])
    plt.close("all")


def test_ellipse_polylines_trace_each_ellipse_and_drop_nan_rows():
    from ctxmatch_lib.plots.groundtruth import ellipse_polylines

    centres = np.array([[1.0, 2.0], [np.nan, 0.0], [0.0, 0.0]])
    shapes = np.stack([3 * np.eye(2), np.eye(2), np.diag([2.0, 0.5])])
    lines = ellipse_polylines(centres, shapes, n=8)
    assert lines.shape == (2, 9, 2)
    np.testing.assert_allclose(np.hypot(*(lines[0] - [1.0, 2.0]).T), 3.0)
    np.testing.assert_allclose(lines[1][[0, 2, 4]], [[2.0, 0.0], [0.0, 0.5], [-2.0, 0.0]], atol=1e-12)
