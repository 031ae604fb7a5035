"""The committed notebooks: stripped of outputs, typed parameters, paths that never depend on the kernel's
working directory, and paper figures written through ``save_figure`` (PNG + PDF with provenance)."""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _cells(path):
    return json.loads(path.read_text())["cells"]


def test_there_are_notebooks():
    assert len(NOTEBOOKS) >= 9


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_committed_without_outputs(path):
    for k, cell in enumerate(_cells(path)):
        if cell["cell_type"] == "code":
            assert cell.get("outputs", []) == [], f"{path.name} cell {k} has outputs: strip them before committing"
            assert cell.get("execution_count") is None, f"{path.name} cell {k} has an execution count"


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
