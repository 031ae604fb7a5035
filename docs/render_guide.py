"""Render the user guide (docs/*.md and README.md) to HTML beside pdoc's API reference (``make docs``).

Usage: ``python docs/render_guide.py build/docs`` after pdoc has written ``build/docs``. Writes
``build/docs/guide/<page>.html`` (``readme.html`` for the README), copies the figures the pages show or link
into ``build/docs/guide/figures/``, and replaces pdoc's redirecting ``index.html`` by a front page that links
the guide and the API reference; the API's package page gets a link back to the guide.

Markdown is converted with mistune (already in the environment through nbconvert): tables, GitHub-style
heading anchors (so the pages' ``page.md#anchor`` links work), links between pages rewritten to ``.html``,
and inline code naming a documented ``ctxmatch_lib`` module or member linked to its API page.
"""

from __future__ import annotations

import html
import re
import shutil
import sys
from pathlib import Path

import mistune

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

_STYLE = """
body { font: 16px/1.55 system-ui, sans-serif; margin: 0; display: flex; color: #222; }
nav { width: 15rem; padding: 1rem 1.2rem; background: #f6f6f6; min-height: 100vh; box-sizing: border-box;
      flex-shrink: 0; }
nav ul { list-style: none; padding: 0; } nav li { margin: .3rem 0; }
main { max-width: 64rem; padding: 1rem 2.5rem 4rem; overflow-x: auto; }
code, pre { font: 14px/1.4 ui-monospace, monospace; background: #f3f3f3; }
pre { padding: .7rem; overflow-x: auto; } table { border-collapse: collapse; font-size: 14px; }
td, th { border: 1px solid #ccc; padding: .25rem .5rem; vertical-align: top; } img { max-width: 100%; }
a { color: #0b5cad; }
"""


def slug(text: str) -> str:
    """GitHub's anchor of a heading's text: tags and punctuation dropped, lower case, spaces to hyphens."""
    text = html.unescape(re.sub(r"<[^>]+>", "", text)).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


class _Renderer(mistune.HTMLRenderer):
    def heading(self, text: str, level: int, **attrs) -> str:
        return f'<h{level} id="{slug(text)}">{text}</h{level}>\n'


def _pages() -> list[tuple[Path, str]]:
    """(source, output name) of every page: the README, then docs/index.md, then the other pages in order."""
    pages = [(ROOT / "README.md", "readme.html"), (DOCS / "index.md", "index.html")]
    pages += [(p, p.stem + ".html") for p in sorted(DOCS.glob("*.md")) if p.name != "index.md"]
    return pages


def _title(text: str, fallback: str) -> str:
    m = re.search(r"^# (.+)$", text, re.M)
    return re.sub(r"[`*]", "", m.group(1)) if m else fallback


def _api_target(name: str, api: Path) -> str | None:
    """The API page (and anchor) of a dotted ``ctxmatch_lib`` name, relative to the guide folder."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        page = api.joinpath(*parts[:k - 1], parts[k - 1] + ".html") if k > 1 else api / "ctxmatch_lib.html"
        if page.is_file():
            anchor = ".".join(parts[k:])
            return "../" + page.relative_to(api).as_posix() + (f"#{anchor}" if anchor else "")
    return None


def _rewrite_links(body: str, source: Path, names: dict[Path, str], out: Path, api: Path) -> str:
    def link(m: re.Match) -> str:
        attr, target = m.group(1), html.unescape(m.group(2))
        if re.match(r"[a-z]+:|#", target):
            return m.group(0)
        path, _, anchor = target.partition("#")
        resolved = (source.parent / path).resolve()
        if resolved in names:
            new = names[resolved]
        elif resolved.is_file() and ROOT in resolved.parents:
            rel = resolved.relative_to(ROOT)
            if rel.parts[0] == "figures":  # shown or linked figures travel with the guide
                (out / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(resolved, out / rel)
                new = rel.as_posix()
            else:  # any other file of the checkout: where it lies, from build/docs/guide
                new = "../../../" + rel.as_posix()
        elif resolved == DOCS or resolved == DOCS / "":
            new = "index.html"
        else:
            return m.group(0)
        return f'{attr}="{html.escape(new + ("#" + anchor if anchor else ""))}"'

    body = re.sub(r'(href|src)="([^"]+)"', link, body)

    def code(m: re.Match) -> str:
        target = _api_target(m.group(1), api)
        return f'<a href="{target}">{m.group(0)}</a>' if target else m.group(0)

    return re.sub(r"<code>(ctxmatch_lib(?:\.\w+)+)</code>", code, body)


def render(out_root) -> Path:
    """Render the guide into ``out_root/guide`` and link it from ``out_root/index.html``; return the guide folder."""
    api = Path(out_root)
    out = api / "guide"
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    md = mistune.create_markdown(renderer=_Renderer(escape=False), plugins=["table", "strikethrough", "url"])
    pages = _pages()
    names = {src.resolve(): name for src, name in pages}
    titles = {name: _title(src.read_text(encoding="utf-8"), src.stem) for src, name in pages}
    nav = "".join(f'<li><a href="{name}">{html.escape(titles[name])}</a></li>' for _, name in pages)
    nav = f'<nav><p><b>ctxmatch</b></p><ul>{nav}</ul><p><a href="../ctxmatch_lib.html">API reference</a></p></nav>'
    for src, name in pages:
        text = src.read_text(encoding="utf-8")
        body = _rewrite_links(md(text), src, names, out, api)
        (out / name).write_text(
            f'<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(titles[name])} — ctxmatch'
            f"</title><style>{_STYLE}</style></head><body>{nav}<main>{body}</main></body></html>\n",
            encoding="utf-8")
    guide = "".join(f'<li><a href="guide/{name}">{html.escape(titles[name])}</a></li>' for _, name in pages)
    (api / "index.html").write_text(
        f'<!doctype html><html><head><meta charset="utf-8"><title>ctxmatch documentation</title>'
        f"<style>{_STYLE}</style></head><body><main><h1>ctxmatch documentation</h1>"
        f'<h2>User guide</h2><ul>{guide}</ul><h2>API reference</h2><ul><li><a href="ctxmatch_lib.html">'
        f"<code>ctxmatch_lib</code></a>, the package and its modules</li></ul></main></body></html>\n",
        encoding="utf-8")
    package = api / "ctxmatch_lib.html"
    if package.is_file():  # pdoc's package page: a way back to the guide, above its search box
        text = package.read_text(encoding="utf-8")
        marker = '<input type="search"'
        if marker in text and "guide/index.html" not in text:
            text = text.replace(marker, '<p><a href="guide/index.html">User guide</a></p>\n' + marker, 1)
            package.write_text(text, encoding="utf-8")
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python docs/render_guide.py OUTPUT_DIR (pdoc's output, e.g. build/docs)")
    print(f"user guide -> {render(sys.argv[1]) / 'index.html'}")
