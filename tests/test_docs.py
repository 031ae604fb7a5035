"""Every code block of README.md and docs/*.md runs, and every link between the pages resolves.

A ```python block is executed in a working folder shared by the pages, with ``CTXMATCH_CACHE`` pointing at a cache
shared by this module (the embedded dataset is generated into it once); the python blocks of one page share a
namespace, in page order, so that a block may continue an earlier one (a block run alone first runs the blocks
before it). A ```bash block runs under ``bash -e`` in the same folder, with the test's virtual environment first
on ``PATH`` (``ctxmatch``, ``python``) and ``.venv/bin/`` read as that environment's ``bin/``.

An HTML comment on the line before a block changes how it runs:

- ``<!-- test: skip (reason) -->``: not run (``make ...``, benchmarks, long runs); reported as skipped.
- ``<!-- test: needs CTXMATCH_DATA (reason) -->``: a real-data command; reported as skipped.
- ``<!-- test: requires MODULE[, MODULE] -->``: run when the optional modules import, skipped otherwise.
- ``<!-- test: run in the checkout (reason) -->``: run with the repository as the working folder (read-only
  commands that read tracked files such as ``figures/``).
- ``<!-- test: slow -->``: run, marked ``slow``; it combines with another: ``requires torch; slow``.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
README_MAX_LINES = 250

_FENCE = re.compile(r"^```(\w*)\s*$")
_DIRECTIVE = re.compile(r"^<!--\s*test:\s*(.*?)\s*-->\s*$")
_KINDS = ("skip", "needs", "requires", "run in the checkout", "slow")


@dataclass(frozen=True)
class Block:
    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    code: str
    directive: str | None

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    @property
    def slow(self) -> bool:
        return self.directive is not None and (self.directive == "slow" or self.directive.endswith("; slow"))

    @property
    def mode(self) -> str | None:
        """The directive without "slow": skip, needs, requires or run in the checkout (or None)."""
        d = self.directive
        if d is None or d == "slow":
            return None
        return d.removesuffix("; slow")

    @property
    def in_checkout(self) -> bool:
        return (self.mode or "").startswith("run in the checkout")


def _blocks(page: Path) -> list[Block]:
    lines = page.read_text(encoding="utf-8").split("\n")
    out, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        start, lang = i, m.group(1)
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        prev = next((lines[k] for k in range(start - 1, -1, -1) if lines[k].strip()), "")
        d = _DIRECTIVE.match(prev)
        out.append(Block(page, start + 1, lang, "\n".join(lines[start + 1:j]) + "\n", d.group(1) if d else None))
        i = j + 1
    return out


ALL_BLOCKS = [b for page in PAGES for b in _blocks(page)]
CODE_BLOCKS = [b for b in ALL_BLOCKS if b.lang in ("python", "bash")]


def _param(block: Block):
    marks = [pytest.mark.slow] if block.slow else []
    return pytest.param(block, id=block.id, marks=marks)


# ------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def docs_env(tmp_path_factory):
    """Working folders per page and one cache for the whole module (CTXMATCH_CACHE), holding the embedded
    dataset of the user's cache when it is there (generating it is the 10 s the README announces, run by
    ``test_datasets.py``; here the examples are the test)."""
    import shutil

    from ctxmatch_lib.cache import cache_dir
    from ctxmatch_lib.datasets.embedded import EMBEDDED_VERSION

    base = tmp_path_factory.mktemp("docs")
    cache = base / "cache"
    cache.mkdir()
    made = cache_dir("datasets") / f"embedded-v{EMBEDDED_VERSION}"
    if (made / "pairs.csv").is_file():
        shutil.copytree(made, cache / "datasets" / made.name)
    return {"base": base, "cache": cache, "namespaces": {}, "done": {}}


def _workdir(env, page: Path) -> Path:
    # One folder for every page: what one page's commands write (data/embedded-v3 from `ctxmatch data
    # embedded --root data`) is reused by the next, as in a user's shell; each page also runs alone.
    d = env["base"] / "work"
    d.mkdir(exist_ok=True)
    return d


def _skip_reason(block: Block) -> str | None:
    d = block.mode
    if d is None or block.in_checkout:
        return None
    if d.startswith("skip"):
        return f"{block.id}: {d[len('skip'):].strip(' ()') or 'marked skip'}"
    if d.startswith("needs"):
        return f"{block.id}: {d}"
    if d.startswith("requires"):
        missing = [m.strip() for m in d[len("requires"):].split(",")
                   if m.strip() and importlib.util.find_spec(m.strip()) is None]
        return f"{block.id}: needs {', '.join(missing)} (not installed)" if missing else None
    raise AssertionError(f"{block.id}: unknown test directive {d!r}")


def _run_python(block: Block, env, monkeypatch) -> None:
    page = block.page
    ns = env["namespaces"].setdefault(page, {"__name__": f"docs:{page.name}"})
    done = env["done"].setdefault(page, set())
    earlier = [b for b in CODE_BLOCKS if b.page == page and b.lang == "python" and b.line < block.line
               and b.line not in done and _skip_reason(b) is None]
    monkeypatch.chdir(ROOT if block.in_checkout else _workdir(env, page))
    monkeypatch.setenv("CTXMATCH_CACHE", str(env["cache"]))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for b in [*earlier, block]:
        exec(compile(b.code, b.id, "exec"), ns)
        done.add(b.line)


def _run_bash(block: Block, env) -> subprocess.CompletedProcess:
    bindir = Path(sys.executable).parent
    code = block.code.replace(".venv/bin/", f"{bindir}/")
    cwd = ROOT if block.in_checkout else _workdir(env, block.page)
    run_env = dict(os.environ, CTXMATCH_CACHE=str(env["cache"]), MPLBACKEND="Agg",
                   PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    return subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=cwd, env=run_env,
                          capture_output=True, text=True, timeout=600, check=False)


# --------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("block", [_param(b) for b in CODE_BLOCKS])
def test_code_block_runs(block, docs_env, monkeypatch):
    reason = _skip_reason(block)
    if reason:
        pytest.skip(reason)
    if block.lang == "python":
        _run_python(block, docs_env, monkeypatch)
    else:
        proc = _run_bash(block, docs_env)
        assert proc.returncode == 0, (
            f"{block.id} exited with {proc.returncode}\n--- stdout\n{proc.stdout[-3000:]}\n--- stderr\n"
            f"{proc.stderr[-3000:]}")


def test_blocks_are_found_and_directives_are_known():
    # The parser sees the blocks (a broken fence would hide them) and every directive is one of the kinds.
    assert len([b for b in CODE_BLOCKS if b.page.name == "README.md"]) >= 4
    assert {b.page.name for b in CODE_BLOCKS} >= {"README.md", "dtm.md", "interop.md", "evaluation.md"}
    for b in ALL_BLOCKS:
        assert b.lang in ("python", "bash"), f"{b.id}: a code block needs a language, python or bash: {b.lang!r}"
        assert b.mode is None or b.mode.startswith(_KINDS), f"{b.id}: unknown directive {b.directive!r}"


def test_commands_that_cannot_run_here_are_marked():
    # make targets, benchmarks and real-data commands must say why they do not run, not fail or run for minutes.
    for b in CODE_BLOCKS:
        if b.lang == "bash" and re.search(r"^\s*(make\b|CTXMATCH_DATA=|export CTXMATCH_DATA)|benchmarks/", b.code, re.M):
            assert (b.mode or "").startswith(("skip", "needs")), f"{b.id} needs a skip directive"


def test_readme_is_short_and_links_the_guide():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.split("\n")) < README_MAX_LINES
    guide = [p for p in PAGES if p.parent.name == "docs"]
    assert len(guide) >= 10
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    for page in guide:
        if page.name != "index.md":
            assert f"({page.name})" in index, f"docs/index.md does not link {page.name}"
            assert f"(docs/{page.name}" in readme, f"README.md does not link docs/{page.name}"


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"`", "", heading.strip()).lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = page.read_text(encoding="utf-8")
    text = re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, re.M)}


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_links_resolve(page):
    # Every relative link (files, figures, and #anchors on the guide's pages) points at something that exists.
    text = re.sub(r"^```.*?^```", "", page.read_text(encoding="utf-8"), flags=re.M | re.S)
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    assert links, f"{page.name} links nothing"
    for link in links:
        if re.match(r"[a-z]+:", link):
            continue
        target, _, anchor = link.partition("#")
        path = (page.parent / target).resolve() if target else page
        assert path.exists(), f"{page.name}: broken link {link}"
        if anchor and path.suffix == ".md":
            assert anchor in _anchors(path), f"{page.name}: no heading for #{anchor} in {path.name}"


def test_make_docs_renders_every_page_with_working_links(tmp_path):
    # `make docs` runs docs/render_guide.py on pdoc's output: every page becomes HTML, links between pages
    # and their anchors resolve in the rendered files, shown figures are copied, and the index links the guide.
    spec = importlib.util.spec_from_file_location("render_guide", ROOT / "docs" / "render_guide.py")
    render_guide = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(render_guide)
    (tmp_path / "ctxmatch_lib").mkdir()
    (tmp_path / "ctxmatch_lib" / "pipeline.html").write_text("<html></html>")
    (tmp_path / "ctxmatch_lib.html").write_text('<nav class="pdoc"><input type="search"></nav>')
    guide = render_guide.render(tmp_path)
    rendered = {p.name: p.read_text(encoding="utf-8") for p in guide.glob("*.html")}
    assert set(rendered) == {"readme.html", *(p.stem + ".html" for p in PAGES if p.parent.name == "docs")}
    assert 'href="guide/index.html"' in (tmp_path / "index.html").read_text()
    assert 'href="guide/index.html"' in (tmp_path / "ctxmatch_lib.html").read_text()
    for name, text in rendered.items():
        assert "<table" in text or name not in ("paper-scale.html", "blob-matching.html")
        for target in re.findall(r'(?:href|src)="([^"]+)"', text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            assert not path.endswith(".md") or path.startswith(("figures/", "../")), f"{name}: {target}"
            file = (guide / path).resolve() if path else guide / name
            assert file.exists(), f"{name}: broken link {target}"
            if anchor and file.suffix == ".html" and file.parent == guide:
                assert f'id="{anchor}"' in file.read_text(encoding="utf-8"), f"{name}: no #{anchor}"
    assert (guide / "figures" / "paper" / "fig_blob_heatmap.png").is_file()
    assert ('<a href="../ctxmatch_lib/pipeline.html#evaluate_pair"><code>ctxmatch_lib.pipeline.evaluate_pair</code></a>'
            in rendered["evaluation.html"])  # inline code naming a documented member links to its API page
