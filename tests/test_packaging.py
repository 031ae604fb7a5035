"""Packaging a user can trust: licence, one version, ``ctxmatch --version``, ``import ctxmatch_lib.dtm.boundary``,
and a numpydoc Parameters section on every public function with several arguments."""

import importlib
import importlib.metadata
import inspect
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import ctxmatch_lib

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def pyproject():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_license(pyproject):
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License") and "the ctxmatch developers" in text
    assert pyproject["project"]["license"] == "BSD-3-Clause"  # SPDX expression, not the deprecated table
    assert pyproject["project"]["license-files"] == ["LICENSE"]


def test_one_version(pyproject, capsys):
    project = pyproject["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert pyproject["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "ctxmatch_lib.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+(\S*)", ctxmatch_lib.__version__)
    assert importlib.metadata.version("ctxmatch") == ctxmatch_lib.__version__
    from ctxmatch_lib.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"ctxmatch {ctxmatch_lib.__version__}"


def test_extras(pyproject):
    extras = pyproject["project"]["optional-dependencies"]
    assert "torch==2.13.0" in extras["kornia"] and any(r.startswith("kornia") for r in extras["kornia"])
    assert any(r.startswith("h5py") for r in extras["export"])
    assert any(r.startswith("pdoc") for r in extras["docs"])


def test_dtm_subpackage_is_importable():
    """``ctxmatch_lib.dtm`` is the subpackage, not the function that used to shadow it."""
    code = ("import ctxmatch_lib.dtm.boundary as b, ctxmatch_lib.dtm.triangulation as t, ctxmatch_lib; "
            "import types; assert isinstance(ctxmatch_lib.dtm, types.ModuleType); "
            "assert callable(ctxmatch_lib.dtm.dtm) and b.dtm_boundary is ctxmatch_lib.dtm_boundary; print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_import_does_not_need_torch_or_h5py():
    code = ("import sys, ctxmatch_lib, ctxmatch_lib.io.interop, ctxmatch_lib.io.export, ctxmatch_lib.match; "
            "print(sorted(m for m in ('torch', 'kornia', 'h5py', 'pycolmap') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr


# Public functions whose docstrings live in modules owned elsewhere and still lack a Parameters section. Strict:
# the test fails as soon as one is fixed, so that it is removed from here.


def _public_functions():
    for modname in ("ctxmatch_lib", "ctxmatch_lib.io.interop", "ctxmatch_lib.io.export", "ctxmatch_lib.match"):
        mod = importlib.import_module(modname)
        for name in mod.__all__:
            obj = getattr(mod, name)
            if inspect.isfunction(obj):
                params = [p for p in inspect.signature(obj).parameters.values()
                          if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
                if len(params) >= 2:
                    yield pytest.param(obj, id=f"{modname}.{name}")


@pytest.mark.parametrize("func", list(_public_functions()))
def test_numpydoc_parameters_section(func):
    doc = inspect.getdoc(func) or ""
    assert re.search(r"^Parameters\n-{10}", doc, re.M), f"{func.__module__}.{func.__name__} has no Parameters section"
    # Every argument is named in the section (alone, in a "a, b : ..." group or as **kwargs).
    section = re.split(r"^(?:Returns|Yields|Raises|Notes|References|Examples|See Also)\n-{4,}", doc.split("Parameters\n", 1)[1],
                       flags=re.M)[0]
    named = set(re.findall(r"\w+", section))
    missing = [p.name for p in inspect.signature(func).parameters.values() if p.name not in named]
    assert not missing, f"{func.__name__}: parameters not in its Parameters section: {missing}"


def test_make_docs_target():
    text = (ROOT / "Makefile").read_text()
    assert re.search(r"^docs:", text, re.M) and "pdoc --docformat numpy" in text and "build/docs" in text
