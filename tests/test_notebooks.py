"""The committed notebooks: stripped of outputs, typed parameters, paths that never depend on the kernel's
working directory, and paper figures written through ``save_figure`` (PNG + PDF with provenance)."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
#: The kernelspec JupyterLab 4 records for the project's kernel (ipykernel's ``python3``).
KERNELSPEC = {"display_name": "Python 3 (ipykernel)", "language": "python", "name": "python3"}


def _cells(path):
    return json.loads(path.read_text())["cells"]


def as_jupyterlab_saves(path: Path) -> str:
    """The text JupyterLab 4 saves for the notebook ``path`` (nbformat 4.5 through ``nbformat.write``: 1-space
    JSON with sorted keys and a final newline), outputs stripped. Every cell gets the id ``<stem>-<position>``
    (stable, never random), the metadata the kernelspec and language_info that the project's kernel reports
    (the Python version: the stored one, else this interpreter's), so that opening the notebook and starting
    its kernel marks nothing modified."""
    import nbformat
    from ipykernel.ipkernel import IPythonKernel

    nb = nbformat.read(path, as_version=4)
    nb.nbformat, nb.nbformat_minor = 4, 5
    info = dict(IPythonKernel.language_info)
    info["version"] = nb.metadata.get("language_info", {}).get("version", info["version"])
    nb.metadata["kernelspec"], nb.metadata["language_info"] = dict(KERNELSPEC), info
    for k, cell in enumerate(nb.cells):
        cell["id"] = f"{path.stem}-{k:02d}"
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    nbformat.validate(nb)
    return nbformat.writes(nb) + "\n"


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 9


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_committed_without_outputs(path):
    for k, cell in enumerate(_cells(path)):
        if cell["cell_type"] == "code":
            assert cell.get("outputs", []) == [], f"{path.name} cell {k} has outputs: strip them before committing"
            assert cell.get("execution_count") is None, f"{path.name} cell {k} has an execution count"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_stored_as_jupyterlab_saves_them(path):
    pytest.importorskip("ipykernel")
    assert path.read_text() == as_jupyterlab_saves(path), \
        f"{path.name} is not stored as JupyterLab saves it: `python tests/test_notebooks.py` rewrites it so"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_parameters_are_documented_above_their_cell(path):
    """A Markdown cell headed "Parameters" right above the parameters cell names every parameter."""
    papermill = pytest.importorskip("papermill")
    cells = _cells(path)
    at = next(k for k, c in enumerate(cells) if "parameters" in c.get("metadata", {}).get("tags", []))
    above = "".join(cells[at - 1]["source"]) if at else ""
    assert cells[at - 1]["cell_type"] == "markdown" and above.lstrip("# ").startswith("Parameters"), path.name
    missing = [name for name in papermill.inspect_notebook(str(path)) if f"`{name}`" not in above]
    assert not missing, f"{path.name}: the Parameters cell does not name {missing}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_pairs_are_looked_up_by_select_pairs(path):
    """A bad pair id is select_pairs' ValueError listing the valid ids, never a KeyError of a notebook's dict."""
    source = "\n".join("".join(c["source"]) for c in _cells(path) if c["cell_type"] == "code")
    assert "p.pair_id: p for" not in source, path.name


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_parameters_are_typed(path):
    papermill = pytest.importorskip("papermill")
    tagged = [c for c in _cells(path) if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(tagged) == 1, f"{path.name}: exactly one cell tagged 'parameters'"
    params = papermill.inspect_notebook(str(path))
    assert "output_dir" in params and params["output_dir"]["default"] == "None"
    untyped = [name for name, p in params.items() if p["inferred_type_name"] in ("None", "")]
    assert not untyped, f"{path.name}: parameters without a type hint: {untyped}"
    # Every assignment of the parameters cell is seen by papermill (an annotation it cannot parse hides it).
    source = "".join(tagged[0]["source"])
    assigned = [line.split("=")[0].split(":")[0].strip() for line in source.splitlines()
                if "=" in line and not line.startswith(("#", " ", "from ", "import "))]
    assert sorted(assigned) == sorted(params), path.name


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_no_path_relative_to_the_kernel(path):
    source = "\n".join("".join(c["source"]) for c in _cells(path) if c["cell_type"] == "code")
    assert "../figures" not in source and "../" not in source.replace("../shared", ""), path.name


@pytest.mark.parametrize("path", [p for p in NOTEBOOKS if p.stem.startswith("fig_")], ids=lambda p: p.stem)
def test_figures_are_paper_sized_with_provenance(path):
    source = "\n".join("".join(c["source"]) for c in _cells(path) if c["cell_type"] == "code")
    assert "paper_style()" in source and "figsize(" in source, path.name
    call = source[source.index("save_figure(fig"):]
    assert "columns=" in call and "provenance=" in call, path.name


# ------------------------------------------------------------------------------------------- reruns


@pytest.mark.slow
def test_a_rerun_of_ctxmatch_figures_writes_the_same_bytes(tmp_path):
    """Two `ctxmatch figures` runs that compute the same numbers, with different running times, write the same
    figure and table bytes (PNG, PDF, CSV, Markdown): what keeps `git status` clean after `make figures` is run
    again. The times go to the untracked executed/ folder, where they differ."""
    pytest.importorskip("papermill")
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.evaluation import evaluate_cached, select_pairs

    df = evaluate_cached(select_pairs("embedded", pair_ids=["planar/lab/1-2", "planar/poster/1-3"]),
                         features=["sift-rootsift"], blobs=["paper-best", "baseline"], filters=["th", "dtm1", "dtm2"],
                         models=["none", "1sac"], cache=False)
    slow = df.copy()
    slow["time_s"] = slow["time_s"] * 1.7 + 0.013  # another machine, the same numbers
    runs = {}
    for name, frame in (("one", df), ("two", slow)):
        frame.to_parquet(tmp_path / "results.parquet")  # one path: the provenance names it
        out = tmp_path / name
        rc = main(["figures", "--only", "tables,fig_pr_scatter", "--output", str(out), "--no-progress",
                   "-p", f"results={tmp_path / 'results.parquet'}"])
        assert rc == 0
        runs[name] = {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
                      if p.is_file() and "executed" not in p.relative_to(out).parts}
    assert sorted(runs["one"]) == ["fig_pr_scatter.pdf", "fig_pr_scatter.png", "tables.csv", "tables.md"]
    assert sorted(runs["one"]) == sorted(runs["two"])
    changed = [name for name in runs["one"] if runs["one"][name] != runs["two"][name]]
    assert not changed, f"a rerun with other running times changed {changed}"
    times = [(tmp_path / name / "executed" / "times.csv").read_text() for name in ("one", "two")]
    assert times[0] != times[1]  # the times are written, apart
    assert "time" not in runs["one"]["tables.csv"].decode().splitlines()[0]


@pytest.mark.slow
def test_ctxmatch_figures_regenerates_the_committed_gallery(tmp_path):
    """`make figures` on a clean checkout writes the committed bytes, so that `git status` stays clean: two
    cheap notebooks of the gallery (the toy table and the DTM boundary on the embedded data) are rerun into a
    temporary folder and compared with the tracked files byte for byte (PNG and PDF, provenance included)."""
    import subprocess

    pytest.importorskip("papermill")
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.plots.base import source_commit

    commit = source_commit()
    if not commit:
        pytest.skip("not a git checkout: the provenance has no commit to compare")
    if commit.endswith("-dirty"):
        pytest.skip("the figures' sources have uncommitted changes: the gallery is regenerated at commit time")
    shallow = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True,
                             text=True).stdout.strip()
    if shallow == "true":
        pytest.skip("a shallow clone cannot name the last commit that changed the sources")
    stems = ("fig_blob_toy", "fig_boundary")
    assert main(["figures", "--only", ",".join(stems), "--output", str(tmp_path), "--no-progress"]) == 0
    changed = [f"{stem}{ext}" for stem in stems for ext in (".png", ".pdf")
               if (tmp_path / f"{stem}{ext}").read_bytes() != (ROOT / "figures" / f"{stem}{ext}").read_bytes()]
    assert not changed, f"ctxmatch figures would change the committed {changed}"


def test_figures_cli_rejects_a_bad_param(capsys):
    pytest.importorskip("papermill")
    from ctxmatch_lib.cli import main

    assert main(["figures", "--only", "tables", "-p", "no_equals_sign"]) == 2
    assert "--param must be KEY=VALUE" in capsys.readouterr().err
    # A key no selected notebook has is an error, not silently dropped.
    assert main(["figures", "--only", "tables", "-p", "max_keypionts=5"]) == 2
    assert "--param max_keypionts: no selected notebook" in capsys.readouterr().err


def test_figures_status_line_survives_braces_in_an_error(capsys):
    """A failing notebook's message may hold a dict repr: it is printed, never used as a format template."""
    from ctxmatch_lib.cli.figures import _Status

    status = _Status(["a"], {}, enabled=False)
    status.begin("a")
    why = "KeyError: {'x': 1}"
    status.end("a", lambda took: f"a: FAILED after {took:.1f} s ({why})")
    out = capsys.readouterr().out
    assert out.startswith("a: FAILED after ") and out.rstrip().endswith("(KeyError: {'x': 1})")


def test_figures_status_line_has_no_time_left_without_previous_durations():
    """A first run (no previous durations) shows elapsed time and notebooks done, not a guessed time left."""
    from ctxmatch_lib.cli.figures import _Status

    status = _Status(["a", "b", "c"], {}, enabled=False)
    status.done["a"] = 5.0
    status.begin("b")
    line = status.line()
    assert "left" not in line and "1 of 3 notebooks done" in line and "elapsed" in line
    status = _Status(["a", "b"], {"a": 10.0, "b": 20.0}, enabled=False)
    status.begin("a")
    assert "left" in status.line() and "(last run 10 s)" in status.line()


def test_figures_schedule_waits_for_the_notebooks_whose_results_it_reads():
    """Two notebooks at once: a reader of fig_agreement's results never runs beside it or before it, the others
    fill the second slot in PRIORITY order, never more than ``jobs`` run at once, and a failed notebook still
    releases its readers."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from ctxmatch_lib.cli import main
    from ctxmatch_lib.cli.figures import AFTER, PRIORITY, _schedule

    stems = sorted(PRIORITY)
    events, lock, live = [], threading.Lock(), set()
    peak = [0]

    def work(stem):
        with lock:
            live.add(stem)
            peak[0] = max(peak[0], len(live))
            events.append(("start", stem, frozenset(live)))
        threading.Event().wait(0.01 if stem != "fig_agreement" else 0.05)
        with lock:
            live.discard(stem)
            events.append(("end", stem, None))
        if stem == "fig_agreement":
            raise RuntimeError("broken")

    finished = []
    with ThreadPoolExecutor(2) as pool:
        _schedule(stems, 2, lambda stem: pool.submit(work, stem), lambda stem, fut: finished.append(stem))
    assert sorted(finished) == stems and peak[0] == 2
    ends = [stem for kind, stem, _ in events if kind == "end"]
    for kind, stem, beside in events:
        if kind == "start":
            for dep in AFTER.get(stem, ()):
                assert dep in ends[: ends.index(stem)] and dep not in beside
    starts = [stem for kind, stem, _ in events if kind == "start"]
    assert starts[:2] == ["fig_agreement", "fig_gt_calibrated"]
    with pytest.raises(SystemExit):
        main(["figures", "--jobs", "x"])
    assert main(["figures", "--only", "tables", "--jobs", "0"]) == 2


def test_paper_parameters_never_write_the_embedded_gallery(tmp_path):
    """`make figures-paper` (``--params paper``) writes figures/paper/, `make figures` figures/."""
    from ctxmatch_lib.cli.figures import output_dir

    assert output_dir("paper", None, tmp_path) == (tmp_path / "figures" / "paper").resolve()
    assert output_dir("default", None, tmp_path) == (tmp_path / "figures").resolve()
    assert output_dir("paper", tmp_path / "x", tmp_path) == (tmp_path / "x").resolve()


def test_provenance_names_the_source_never_the_clock():
    import subprocess

    from ctxmatch_lib import __version__
    from ctxmatch_lib.plots.base import SOURCE_PATHS, provenance

    record = provenance(dataset="embedded")
    assert set(record) == {"version", "git_commit", "dataset"} and record["version"] == __version__
    if (ROOT / ".git").exists():
        last = subprocess.run(["git", "log", "-1", "--format=%H", "--", *SOURCE_PATHS], cwd=ROOT,
                              capture_output=True, text=True).stdout.strip()
        assert record["git_commit"].removesuffix("-dirty") == last[:12]  # not HEAD: committing figures keeps it


def test_paper_scale_runs_share_one_keypoint_budget():
    """Every paper-scale evaluation runs at the calibrated budget "paper" (the same budget for every
    block and figure; the illustrations of one pair, fig_boundary and fig_dtm_steps, excepted)."""
    yaml = pytest.importorskip("yaml")
    from ctxmatch_lib.features import KEYPOINT_BUDGETS, keypoint_budget

    evaluations = ["fig_blob_heatmap", "fig_blob_bands", "fig_gt_methods", "fig_pr_scatter", "fig_inlier_hist",
                   "tables", "fig_match_examples", "fig_agreement", "fig_geometry", "fig_gt_calibrated"]
    for stem in evaluations:
        params = yaml.safe_load((ROOT / "notebooks" / "params" / f"{stem}.yaml").read_text())
        assert keypoint_budget(params["max_keypoints"]) == KEYPOINT_BUDGETS["paper"], stem


if __name__ == "__main__":  # rewrite the notebooks as JupyterLab saves them
    for nb_path in NOTEBOOKS:
        text = as_jupyterlab_saves(nb_path)
        if text != nb_path.read_text():
            nb_path.write_text(text)
            print(f"normalised {nb_path.relative_to(ROOT)}", file=sys.stderr)
