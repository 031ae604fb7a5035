"""The shape of the code, the executable picture of ``docs/architecture.md``: data flows one way through six
layers, a private name stays inside its package, and no module or function grows past a size a reader can hold.

The import graph is read from the source with ``ast`` (every ``import`` and ``from ... import``, those inside
functions included), so it sees what a run would import on any path. Imports of packages outside
``ctxmatch_lib`` are not edges: only the library's own modules are.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent / "ctxmatch_lib"
# A module does one job and a function fits on a screen or two; the caps catch runaway growth, they are not a
# reason to split a module that does one job.
MAX_MODULE_LINES = 800
MAX_FUNCTION_LINES = 100


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(ROOT.rglob("*.py"))}


def _resolve(module: str, is_package: bool, node) -> list[str]:
    """The ``ctxmatch_lib`` modules an import node brings in (a submodule when the name is one).

    ``from ctxmatch_lib import __version__`` (the provenance helpers do it inside functions) is not an edge:
    the package binds that constant on its first line, before it imports any submodule, so the statement
    runs nothing.
    """
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "ctxmatch_lib"]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - node.level + 1]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    if target.split(".")[0] != "ctxmatch_lib":
        return []
    if target == "ctxmatch_lib" and [a.name for a in node.names] == ["__version__"]:
        return []
    out = []
    for a in node.names:
        sub = f"{target}.{a.name}"
        out.append(sub if sub in MODULES else target)
    return out


def _graph() -> dict[str, set[str]]:
    graph = {}
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        edges = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                edges.update(t for t in _resolve(name, is_package, node) if t != name)
        graph[name] = {t for t in edges if t in MODULES}
    return graph


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out



#: The layers, lowest first: a module belongs to the layer of the longest prefix that names it.
LAYERS = {
    # 0. the base: fixed-order numerics, argument checks, score types, the cache folder
    "ctxmatch_lib._numerics": 0, "ctxmatch_lib.cache": 0,
    # 1. the methods: features, blob matching, DTM and the filters, models, ground truth, metrics, datasets,
    #    and the drawing primitives (images and matches, LightGlue's viz2d)
    "ctxmatch_lib.features": 1, "ctxmatch_lib.blob": 1, "ctxmatch_lib.dtm": 1, "ctxmatch_lib.filters": 1,
    "ctxmatch_lib.geometry": 1, "ctxmatch_lib.groundtruth": 1, "ctxmatch_lib.metrics": 1,
    "ctxmatch_lib.geometry_metrics": 1, "ctxmatch_lib.opencv_matchers": 1, "ctxmatch_lib.datasets": 1,
    "ctxmatch_lib.testing": 1, "ctxmatch_lib.plots.palette": 1, "ctxmatch_lib.plots.viz2d": 1,
    # 2. the per-pair chain (the steps every entry point calls) and what reads and writes its results
    "ctxmatch_lib.evaluation.steps": 2, "ctxmatch_lib.match": 2, "ctxmatch_lib.io": 2,
    # 3. the evaluation engine and its thin per-pair face
    "ctxmatch_lib.evaluation": 3, "ctxmatch_lib.pipeline": 3,
    # 4. tables, reports, plots and the training sets built on the engine
    "ctxmatch_lib.report": 4, "ctxmatch_lib.plots": 4, "ctxmatch_lib.training": 4,
    # 5. the command line and the package's front door
    "ctxmatch_lib.cli": 5, "ctxmatch_lib.__main__": 5, "ctxmatch_lib": 5,
}


def layer(module: str) -> int:
    parts = module.split(".")
    for i in range(len(parts), 0, -1):
        if ".".join(parts[:i]) in LAYERS:
            return LAYERS[".".join(parts[:i])]
    raise KeyError(module)


def test_every_module_has_a_layer():
    for name in MODULES:
        layer(name)


def test_drawing_primitives_import_only_each_other():
    primitives = ("ctxmatch_lib.plots.palette", "ctxmatch_lib.plots.viz2d")
    graph = _graph()
    for name in primitives:
        assert graph[name] <= set(primitives), (name, graph[name])


def test_the_graph_sees_imports_inside_functions():
    graph = _graph()
    # evaluation.unit imports the feature extractor inside a function, pipeline imports the engine at the top.
    assert "ctxmatch_lib.features" in graph["ctxmatch_lib.evaluation.unit"]
    assert "ctxmatch_lib.evaluation.run" in graph["ctxmatch_lib.pipeline"]
    assert len(graph) > 50


def test_no_import_cycle_inside_the_library():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_data_flows_one_way():
    """A lower layer never imports a higher one, not even inside a function."""
    graph = _graph()
    bad = [f"{a} (layer {layer(a)}) imports {b} (layer {layer(b)})"
           for a in sorted(graph) for b in sorted(graph[a]) if layer(b) > layer(a)]
    assert not bad, "\n".join(bad)


def _private_imports(modules=None):
    """``(module, line, name)`` of every import of a private name (a leading underscore, dunders aside) from
    outside the package that owns it. A private module ``p._m`` belongs to package ``p`` and everything below
    it; a private name ``_x`` of a module of package ``p`` belongs to the modules of ``p`` alone."""
    modules = MODULES if modules is None else modules
    out = []
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        package = name if is_package else name.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "ctxmatch_lib":
                continue
            for alias in node.names:
                chain = f"{target}.{alias.name}".split(".")
                for i, part in enumerate(chain):
                    if not part.startswith("_") or part.startswith("__"):
                        continue
                    owner = ".".join(chain[:i])
                    if ".".join(chain[: i + 1]) in modules:  # a private module: its package and below
                        ok = name == owner or name.startswith(owner + ".")
                    else:  # a private name of a module: that module's own package only
                        if owner in modules and modules[owner].name != "__init__.py":
                            owner = owner.rsplit(".", 1)[0]
                        ok = package == owner
                    if not ok:
                        out.append((name, node.lineno, ".".join(chain)))
    return out


def test_no_module_imports_a_private_name_of_another_package():
    """What a package shares with another is a public name of that package (``geometry.transfer_errors``),
    never an underscore import; ``ctxmatch_lib._numerics`` is the root package's own, so every module uses it."""
    bad = _private_imports()
    assert not bad, "\n".join(f"{m}:{line} imports {n}" for m, line, n in bad)


def test_the_private_name_check_sees_a_crossing(tmp_path):
    """The rule on a made-up tree: a sibling's private name is caught, one's own package's and the root's
    private modules are not."""
    files = {
        "ctxmatch_lib/__init__.py": "",
        "ctxmatch_lib/_base.py": "def helper(): pass\n",
        "ctxmatch_lib/geometry/__init__.py": "from .models import _epipolar\n",
        "ctxmatch_lib/geometry/models.py": "def _epipolar(): pass\n",
        "ctxmatch_lib/dtm/__init__.py": "",
        "ctxmatch_lib/dtm/core.py": "from ..geometry import _epipolar\nfrom .._base import helper\n",
        "ctxmatch_lib/match.py": "def _filters(): pass\n",
        "ctxmatch_lib/cli/__init__.py": "from ..match import _filters\n",
    }
    modules = {}
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        parts = list(Path(rel).with_suffix("").parts)
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    assert sorted(_private_imports(modules)) == [("ctxmatch_lib.cli", 1, "ctxmatch_lib.match._filters"),
                                                 ("ctxmatch_lib.dtm.core", 1, "ctxmatch_lib.geometry._epipolar")]


def test_no_history_in_the_package():
    """Docstrings and comments describe the code as it is: history is git's."""
    import re

    pattern = re.compile(r"\b[Ii]ssue [0-9]|\b[Ee]arlier version\b|\b[Pp]reviously\b")
    bad = [f"{p.relative_to(ROOT.parent)}:{i}" for p in sorted(ROOT.rglob("*.py"))
           for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not bad, bad


def test_module_sizes():
    long = {name: n for name, p in MODULES.items() if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def _code_lines(node) -> int:
    """Lines of a function's body, its docstring aside (blank lines and comments count: they are read)."""
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    if not body:
        return 0
    return body[-1].end_lineno - body[0].lineno + 1


def test_function_sizes():
    long = {}
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = _code_lines(node)
                if n > MAX_FUNCTION_LINES:
                    long[f"{name}.{node.name}"] = n
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines of code: {long}"


def test_the_filters_room_never_imports_the_engine():
    """Filters sit under the evaluation engine (data flows one way): no module of ``ctxmatch_lib.filters``
    imports ``ctxmatch_lib.evaluation``, not even its per-pair steps."""
    graph = _graph()
    bad = sorted(f"{a} imports {b}" for a in graph if a.startswith("ctxmatch_lib.filters")
                 for b in graph[a] if b.startswith("ctxmatch_lib.evaluation"))
    assert not bad, bad


@pytest.mark.parametrize("statement", [
    "from ctxmatch_lib.pipeline import evaluate_pair, evaluate_dataset, summary_table, pair_features, "
    "blob_candidates, label_candidates, run_filter, run_model, ROW_COLUMNS",
    "from ctxmatch_lib.evaluation import run_sweep, run_units, plan_units, evaluate_cached, SWEEP_COLUMNS",
    "from ctxmatch_lib.report.blob import blob_map, heatmap_matrix",
    "from ctxmatch_lib.report import method_table, markdown_table",
    "from ctxmatch_lib.io.export import export_results",
    "from ctxmatch_lib.cache import cache_dir, cache_usage, clear_cache",
    "from ctxmatch_lib.geometry import transfer_errors, epipolar_errors, hartley_normalise",
])
def test_public_names_keep_working(statement):
    exec(statement, {})


@pytest.mark.parametrize("old, new", [("ctxmatch_lib.export", "ctxmatch_lib.io.export"),
                                      ("ctxmatch_lib.interop", "ctxmatch_lib.io.interop"),
                                      ("ctxmatch_lib.usercache", "ctxmatch_lib.cache"),
                                      ("ctxmatch_lib.report_blob", "ctxmatch_lib.report.blob"),
                                      ("ctxmatch_lib.report_paper", "ctxmatch_lib.report.paper")])
def test_modules_the_docs_named_before_the_move_still_import_with_a_warning(old, new, monkeypatch):
    import importlib
    import sys

    monkeypatch.delitem(sys.modules, old, raising=False)
    with pytest.warns(FutureWarning, match=rf"{old} moved to {new}"):
        module = importlib.import_module(old)
    assert module is importlib.import_module(new) and module.__spec__.name == new


def test_removed_faces_are_gone():
    import importlib

    for name in ("ctxmatch_lib.sweep", "ctxmatch_lib.evalcache"):
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(name)


def test_names_moved_out_of_report_paper_still_resolve_with_a_warning():
    from ctxmatch_lib.report import claims, paper

    with pytest.warns(FutureWarning, match="moved to ctxmatch_lib.report.claims"):
        assert paper.check_claims is claims.check_claims
    with pytest.raises(AttributeError):
        paper.no_such_name
