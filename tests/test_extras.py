"""A missing optional dependency names the extra that installs it: ``pip install 'ctxmatch[<extra>]'``.

Each case hides one optional module (``sys.modules[name] = None`` makes ``import name`` fail), calls an entry
point that needs it and reads the error. The package is scanned with ``ast`` for the imports of the optional
modules (the packages of the extras in ``pyproject.toml``): every one goes through
:func:`ctxmatch_lib._numerics.extras.require`, names an extra that installs the module, and has a case here.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import os
import re
import subprocess
import sys
import tomllib
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "ctxmatch_lib"


def _extra_packages() -> dict[str, set[str]]:
    """The import names each extra installs: ``{extra: {top-level module, ...}}``."""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    out = {}
    for extra, requirements in extras.items():
        names = set()
        for req in requirements:
            name, brackets = re.match(r"\s*([A-Za-z0-9_.-]+)\s*(?:\[([^\]]*)\])?", req).groups()
            names.add(name.lower().replace("-", "_"))
            # dask[distributed] installs the distributed package as well
            names.update(b.strip().lower().replace("-", "_") for b in (brackets or "").split(",") if b.strip())
        out[extra] = names
    return out


EXTRAS = _extra_packages()
OPTIONAL = set().union(*EXTRAS.values())


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _constant(node) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _scan():
    """``(sites, bare, eager)`` of the package's imports of optional modules.

    ``sites``: ``{(module, optional package): [(line, extra), ...]}`` of the ``require(...)`` calls;
    ``bare``: ``[(module, line, imported name)]`` of the import statements and ``import_module`` /
    ``__import__`` calls of an optional package that bypass ``require``; ``eager``: the modules with a
    ``require`` outside any function (they need the module to be imported at all).
    """
    sites, bare, eager = {}, [], set()
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module_name(path)
        tree = ast.parse(path.read_text(), filename=str(path))
        in_function = set()
        for fn in ast.walk(tree):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                in_function.update(id(n) for n in ast.walk(fn) if n is not fn)
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module]
            elif isinstance(node, ast.Call):
                callee = getattr(node.func, "attr", getattr(node.func, "id", None))
                first = _constant(node.args[0]) if node.args else None
                if callee == "require":
                    extra = _constant(node.args[1]) if len(node.args) > 1 else None
                    assert first and extra, f"{module}:{node.lineno}: require(module, extra, ...) takes literals"
                    sites.setdefault((module, first.split(".")[0]), []).append((node.lineno, extra))
                    if id(node) not in in_function:
                        eager.add(module)
                elif callee in ("import_module", "__import__") and first:
                    names = [first]
            bare += [(module, node.lineno, n) for n in names if n.split(".")[0] in OPTIONAL]
    return sites, bare, eager


SITES, BARE, EAGER = _scan()

#: The modules that import an optional package when they are imported (reached through a lazy public face).
IMPORT_TORCH = {"ctxmatch_lib.filters.learned.nets", "ctxmatch_lib.filters.learned.checkpoints",
                "ctxmatch_lib.filters.learned.training"}


# ------------------------------------------------------------------------------------------------ the cases
def _raises(call) -> tuple[str, str]:
    """``(caller, message)`` of the ``ImportError`` that ``call()`` raises: the module that called ``require``
    and the message, checked to be chained from the import's own error."""
    with pytest.raises(ImportError) as info:
        call()
    assert isinstance(info.value.__cause__, ImportError), "chained from the import's own error"
    frames = [f.f_globals.get("__name__") for f, _ in traceback.walk_tb(info.value.__traceback__)]
    assert frames[-1] == "ctxmatch_lib._numerics.extras", frames
    return frames[-2], str(info.value)


def _fresh_import(module: str):
    """Import ``module`` anew (its cached copy dropped for the test; the modules it imports stay loaded)."""
    def call(monkeypatch, tmp_path):
        monkeypatch.delitem(sys.modules, module, raising=False)
        return [_raises(lambda: importlib.import_module(module))]
    return call


def _pair():
    kpts = np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 7.0]])
    return kpts, kpts + 1.0, np.array([[0, 0], [1, 1], [2, 2]]), np.array([0.1, 0.2, 0.3])


def _gray():
    return np.zeros((64, 64), np.uint8)


def _deep_calls(monkeypatch, tmp_path):
    from ctxmatch_lib.features import deep

    (tmp_path / "x.pth").write_bytes(b"0")
    kpts, shapes = np.array([[32.0, 32.0]]), np.eye(2)[None] * 2.0
    calls = [lambda: deep.describe_patches(np.zeros((1, 32, 32)), "hardnet2", backend="torch"),
             lambda: deep.deep_descriptors(_gray(), kpts, shapes, descriptor="sosnet", backend="torch"),
             lambda: deep.orinet_angles(_gray(), kpts, shapes, weights=None),
             lambda: deep.load_descriptor_net("hardnet2"),
             lambda: deep.load_orinet(),
             lambda: deep.load_numpy_net(tmp_path / "x.pth", "tfeat"),
             lambda: deep.export_npz(tmp_path / "x.pth", tmp_path / "x.npz", "tfeat")]
    raised = [_raises(c) for c in calls]
    assert not (tmp_path / "x.npz").exists()
    return raised


def _export_calls(monkeypatch, tmp_path):
    from ctxmatch_lib.io.export import check_export_paths, read_hloc, write_hloc

    (tmp_path / "h5").mkdir()
    (tmp_path / "h5" / "features.h5").write_bytes(b"not empty")
    raised = [_raises(lambda: write_hloc(tmp_path / "f.h5", tmp_path / "m.h5", "a.png", "b.png", *_pair()[:3])),
              _raises(lambda: read_hloc(tmp_path / "f.h5", tmp_path / "m.h5", "a.png", "b.png")),
              _raises(lambda: check_export_paths(h5_dir=tmp_path / "h5"))]
    assert not (tmp_path / "f.h5").exists() and not (tmp_path / "m.h5").exists()
    return raised


def _cli_export_h5(monkeypatch, tmp_path, capsys):
    import cv2

    from ctxmatch_lib.cli import main

    for name in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / name), np.random.default_rng(0).integers(0, 255, (40, 50), np.uint8))
    rc = main(["match", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--out", str(tmp_path / "m.npz"),
               "--export-h5", str(tmp_path / "h5")])
    err = capsys.readouterr().err
    assert rc == 2 and not (tmp_path / "m.npz").exists() and "Traceback" not in err
    return [(None, err)]


def _interop_calls(monkeypatch, tmp_path):
    from ctxmatch_lib.io.interop import match_blob, to_kornia_lafs

    kpts, _, _, _ = _pair()
    return [_raises(lambda: to_kornia_lafs(kpts, np.tile(np.eye(2), (3, 1, 1)), mr_size=6.0)),
            _raises(lambda: match_blob(np.eye(3, 8), np.eye(3, 8), blob="baseline"))]


def _learned_calls(monkeypatch, tmp_path):
    from ctxmatch_lib.filters.learned import (learned_logits, load_learned_model, oanet_filter,
                                              train_learned_filter)

    kpts1, kpts2, matches, scores = _pair()
    size = dict(image_size1=(64, 64), image_size2=(64, 64))
    (tmp_path / "x.pt").write_bytes(b"not read")
    raised = [_raises(lambda: train_learned_filter("acne", steps=1, output=tmp_path / "w.npz", progress=False)),
              _raises(lambda: load_learned_model("oanet")),
              _raises(lambda: learned_logits("acne", kpts1, kpts2, matches, scores, backend="torch", **size))]
    checkpoint = _raises(lambda: oanet_filter(kpts1, kpts2, matches, scores, weights=tmp_path / "x.pt", **size))
    assert "convert it once to .npz" in checkpoint[1], checkpoint
    assert not (tmp_path / "w.npz").exists()
    return [*raised, checkpoint]


def _cli_train(monkeypatch, tmp_path, capsys):
    from ctxmatch_lib.cli import main

    rc = main(["train", "acne", "--steps", "1", "--output", str(tmp_path / "w.npz"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and not (tmp_path / "w.npz").exists() and "Traceback" not in err
    return [(None, err)]


def _dask_run(monkeypatch, tmp_path):
    from ctxmatch_lib.evaluation import run_sweep

    return [_raises(lambda: run_sweep("embedded", pairs=1, blobs="paper-best", max_keypoints=50, progress=False,
                                      cache_dir=tmp_path, dask="tcp://127.0.0.1:9"))]


@dataclass(frozen=True)
class Case:
    """An optional import ``site`` (module, package), the packages hidden, the extra named, and ``run``: the
    entry points that reach the site, returning ``(caller of require, message)`` of each error (``caller``
    ``None``: a command's stderr). ``preload``: modules imported before hiding, so that the site is reached."""

    site: tuple[str, str]
    hide: tuple[str, ...]
    extra: str
    run: Callable
    cli: bool = False
    preload: tuple[str, ...] = ()


CASES = [
    Case(("ctxmatch_lib.io.export", "h5py"), ("h5py",), "export", _export_calls),
    Case(("ctxmatch_lib.cli.match", "h5py"), ("h5py",), "export", _cli_export_h5, cli=True),
    Case(("ctxmatch_lib.io.interop", "torch"), ("torch",), "kornia", _interop_calls),
    Case(("ctxmatch_lib.features.deep", "torch"), ("torch",), "kornia", _deep_calls),
    Case(("ctxmatch_lib.features.deep", "kornia"), ("kornia",), "kornia", _deep_calls),
    Case(("ctxmatch_lib.filters.learned.filters", "torch"), ("torch",), "torch", _learned_calls),
    Case(("ctxmatch_lib.filters.learned.filters", "torch"), ("torch",), "torch", _cli_train, cli=True),
    Case(("ctxmatch_lib.filters.learned.nets", "torch"), ("torch",), "torch",
         _fresh_import("ctxmatch_lib.filters.learned.nets")),
    Case(("ctxmatch_lib.filters.learned.checkpoints", "torch"), ("torch",), "torch",
         _fresh_import("ctxmatch_lib.filters.learned.checkpoints"), preload=("ctxmatch_lib.filters.learned.nets",)),
    Case(("ctxmatch_lib.filters.learned.training", "torch"), ("torch",), "torch",
         _fresh_import("ctxmatch_lib.filters.learned.training"),
         preload=("ctxmatch_lib.filters.learned.checkpoints",)),
    Case(("ctxmatch_lib.evaluation.run", "distributed"), ("distributed",), "dask", _dask_run),
]


def _hide(monkeypatch, name: str) -> None:
    """Make ``import name`` and the import of any of its submodules fail for the test."""
    for key in [k for k in sys.modules if k == name or k.startswith(name + ".")] + [name]:
        monkeypatch.setitem(sys.modules, key, None)


def _installed(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ValueError:
        return False


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c.site[0].removeprefix('ctxmatch_lib.')}-{c.site[1]}"
                                                      + ("-cli" if c.cli else ""))
def test_a_missing_optional_module_names_its_extra(case, monkeypatch, tmp_path, capsys):
    missing = {n for n in OPTIONAL if not _installed(n)} | set(case.hide)
    preloaded = True
    for module in case.preload:
        try:
            importlib.import_module(module)
        except ImportError:  # the extra is not installed: the preloaded module's own require answers
            preloaded = False
    for name in case.hide:
        _hide(monkeypatch, name)
    raised = case.run(monkeypatch, tmp_path, capsys) if case.cli else case.run(monkeypatch, tmp_path)
    assert raised
    for caller, message in raised:
        assert message.strip() and "\n" not in message.strip(), message
        assert f"pip install 'ctxmatch[{case.extra}]'" in message, message
        named = re.search(r"needs (\w+): pip install", message)
        assert named and named.group(1) in missing, message
        if caller is not None and preloaded and named.group(1) == case.site[1]:
            assert caller == case.site[0], (caller, message)


def test_every_optional_import_has_a_case():
    """The optional imports the package makes, read from its source, each have a case, and no case is stale."""
    cased = {c.site for c in CASES}
    assert set(SITES) == cased, (f"optional imports without a case: {sorted(set(SITES) - cased)}; "
                                 f"cases of no import: {sorted(cased - set(SITES))}")
    assert {name for _, name in SITES} >= {"h5py", "torch", "kornia", "distributed"}


def test_optional_modules_are_imported_through_require():
    assert not BARE, ("import these through ctxmatch_lib._numerics.extras.require(module, extra, purpose): "
                      + ", ".join(f"{m}:{line} {name}" for m, line, name in BARE))


def test_each_require_names_an_extra_that_installs_the_module():
    wrong = [f"{module}:{line} require({name!r}, {extra!r}) (extras: {sorted(EXTRAS)})"
             for (module, name), uses in SITES.items() for line, extra in uses
             if name not in EXTRAS.get(extra, ())]
    assert not wrong, "\n".join(wrong)


def test_the_hint_names_the_package_and_the_extra():
    from ctxmatch_lib._numerics.extras import install_hint, require
    from ctxmatch_lib.filters.learned import TORCH_HINT

    assert install_hint("kornia.feature", "kornia", "X") == "X needs kornia: pip install 'ctxmatch[kornia]'"
    assert TORCH_HINT.endswith("needs torch: pip install 'ctxmatch[torch]'")
    assert require("json", "export", "X") is sys.modules["json"]


def test_modules_import_lazily_without_the_extras(tmp_path):
    """With every optional package blocked, each module imports but those that import torch at the top,
    importing ``ctxmatch_lib`` loads none of them, and ``ctxmatch match`` runs."""
    assert EAGER == IMPORT_TORCH, f"modules that import an optional package at import time: {sorted(EAGER)}"
    lazy = sorted(m for m in map(_module_name, PACKAGE.rglob("*.py")) if m not in EAGER and "__main__" not in m)
    code = f"""
import importlib, sys
BLOCKED = {sorted(OPTIONAL)!r}

class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (blocked)", name=name)

sys.meta_path.insert(0, Block())
import ctxmatch_lib
assert not [m for m in sys.modules if m.split(".")[0] in BLOCKED], "import ctxmatch_lib loaded an extra"
for module in {lazy!r}:
    importlib.import_module(module)
for module in {sorted(EAGER)!r}:
    try:
        importlib.import_module(module)
    except ImportError as exc:
        assert "pip install 'ctxmatch[torch]'" in str(exc), (module, str(exc))
    else:
        raise AssertionError(module + " imported without torch")
import cv2, numpy as np
from skimage.data import camera
from ctxmatch_lib.cli import main
image = camera()[::4, ::4]
cv2.imwrite("a.png", image)
cv2.imwrite("b.png", np.roll(image, 3, axis=1))
assert main(["match", "a.png", "b.png", "--out", "m.npz", "--no-cache"]) == 0
assert not [m for m in sys.modules if m.split(".")[0] in BLOCKED], "ctxmatch match loaded an extra"
print("ok", len({lazy!r}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "CTXMATCH_CACHE": str(tmp_path / "cache")})
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.splitlines()[-1].split() == ["ok", str(len(lazy))], out.stdout
