"""The geometry plots on hand-built rows: what is drawn, where."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from ctxmatch_lib.geometry_metrics import geometry_table  # noqa: E402
from ctxmatch_lib.plots.geometry import (  # noqa: E402
    accuracy_column,
    geometry_legend,
    method_name,
    plot_accuracy_vs_time,
    plot_cumulative_errors,
)


def _rows():
    base = dict(dataset="d", features="f", blob="b", error="", kind="planar", model="magsac", model_inliers=9.0,
                epi_share_mean=np.nan)
    rows = []
    for i, (e_blob, e_dtm) in enumerate([(0.5, 0.2), (3.0, 1.5), (np.inf, 4.0), (20.0, np.inf)]):
        pid = f"p{i}"
        rows += [dict(base, pair_id=pid, method="blob", time_s=1.0, model_time_s=1.0, corner_error=e_blob),
                 dict(base, pair_id=pid, method="dtm", time_s=0.5, model_time_s=0.5, corner_error=e_dtm),
                 dict(base, pair_id=pid, method="opencv_ratio", time_s=0.1, model_time_s=0.1, corner_error=1.0)]
    return pd.DataFrame(rows)


def test_accuracy_vs_time_draws_one_point_per_method():
    table = geometry_table(_rows(), by=("kind", "method", "model"))
    fig, ax = plt.subplots()
    pts = plot_accuracy_vs_time(ax, table, "planar", model="magsac", auc_px=5.0)
    at = {m: (x, y) for m, x, y in pts}
    assert set(at) == {"blob", "dtm", "opencv_ratio"}
    assert at["blob"][0] == 2.0 and at["dtm"][0] == 1.0 + 0.5 + 0.5  # DTM's time adds the blob time
    # Every pair at 1 px: SuperGlue's curve rises from (0, 0) to (1, 1/4), jumps to 1, stays: (1/8 + 4) / 5.
    assert at["opencv_ratio"] == (0.2, 82.5)
    assert ax.get_xscale() == "log" and ax.get_ylabel() == accuracy_column("planar")[1]
    geometry_legend(fig, [m for m, _, _ in pts])
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["blob", "DTM", "OpenCV ratio 0.8"]
    plt.close(fig)


def test_cumulative_errors_share_below_the_limit():
    fig, ax = plt.subplots()
    shares = plot_cumulative_errors(ax, _rows(), ["blob", "dtm", "opencv_ratio", "gms"], model="magsac", max_px=10)
    assert shares == {"blob": 0.5, "dtm": 0.75, "opencv_ratio": 1.0}  # no gms rows: no curve
    assert len(ax.lines) == 3
    x, y = ax.lines[0].get_data()
    np.testing.assert_array_equal(x, [0.0, 0.5, 3.0, 10.0])
    np.testing.assert_array_equal(y, [0.0, 25.0, 50.0, 50.0])
    plt.close(fig)


def test_names_and_columns():
    assert method_name("opencv_mnn") == "OpenCV MNN" and method_name("dtm2") == "DTM$_2$"
    assert accuracy_column("nonplanar")[0] == "epi_share_mean_pct"
    assert accuracy_column("planar", 10)[0] == "auc_10px_pct"


def test_accuracy_by_method_sorts_by_auc_and_names_pairs_without_a_model():
    from ctxmatch_lib.plots.geometry import plot_accuracy_by_method

    rows = _rows()
    rows.loc[np.isinf(rows.corner_error), "model_inliers"] = 0  # the estimator returned no model
    table = geometry_table(rows, by=("kind", "method", "model"))
    fig, ax = plt.subplots()
    order = plot_accuracy_by_method(ax, table, "planar", model="magsac")
    # Top to bottom by AUC at 5 px: OpenCV (every pair at 1 px), DTM (0.2, 1.5, 4, failure), blob.
    assert order == ["opencv_ratio", "dtm", "blob"]
    labels = [t.get_text() for t in ax.get_yticklabels()][::-1]
    assert labels == ["OpenCV ratio 0.8", "DTM (1 of 4 w/o model)", "blob (1 of 4 w/o model)"]
    plt.close(fig)


def test_geometry_markdown_leaves_the_times_out():
    from ctxmatch_lib.report import geometry_markdown

    table = geometry_table(_rows(), by=("kind", "method", "model"))
    text = geometry_markdown(table, title="t", provenance={"dataset": "d"})
    assert "geometry_time" not in text and "| planar | DTM | MAGSAC | 4 |" in text
    assert text == geometry_markdown(table, title="t", provenance={"dataset": "d"})


def test_geometry_markdown_keeps_the_times_when_asked():
    from ctxmatch_lib.report import GEOMETRY_TIME_COLUMNS, geometry_markdown

    table = geometry_table(_rows(), by=("kind", "method", "model"))
    times = table[["pairs", *GEOMETRY_TIME_COLUMNS]]
    text = geometry_markdown(times, title="t", provenance={"dataset": "d"}, keep_times=True)
    header = next(line for line in text.splitlines() if line.startswith("| kind"))
    assert header == "| kind | method | model | pairs | geometry_time_s | geometry_time_median_s |"
    row = next(line for line in text.splitlines() if line.startswith("| planar | DTM |"))
    cells = row.strip("|").split("|")
    assert len(cells) == 6 and cells[3].strip() == "4"
    value = float(times.loc[("planar", "dtm", "magsac"), "geometry_time_s"])
    assert cells[4].strip() == f"{value:.3f}"
