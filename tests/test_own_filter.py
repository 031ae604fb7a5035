"""A filter from outside the library: by import path (``module:function``) and by the ``ctxmatch.filters``
entry-point group, with errors that name the path."""

import textwrap

import numpy as np
import pytest

from ctxmatch_lib import filters as registry
from ctxmatch_lib.evaluation.steps import check_filters, resolve_filters
from ctxmatch_lib.filters import ENTRY_POINT_GROUP, FILTERS, load_filter

TOY = textwrap.dedent('''
    import numpy as np

    def keep_even(kpts1, kpts2, matches, scores, *, image_size1, image_size2, shapes1=None, shapes2=None):
        return np.arange(len(matches)) % 2 == 0

    def no_keywords(kpts1, kpts2, matches, scores):
        return np.ones(len(matches), bool)

    NOT_A_FUNCTION = 3
''')


@pytest.fixture
def toy_module(tmp_path, monkeypatch):
    """A module ``owntoy`` in a fresh folder on ``sys.path``, and a registry restored afterwards."""
    import sys

    name = f"owntoy_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(TOY)
    monkeypatch.syspath_prepend(str(tmp_path))
    loaded, by_path = dict(FILTERS._loaded), dict(FILTERS._by_path)
    yield name
    FILTERS._loaded.clear()
    FILTERS._loaded.update(loaded)
    FILTERS._by_path.clear()
    FILTERS._by_path.update(by_path)
    registry._entry_points.cache_clear()
    sys.modules.pop(name, None)


def test_import_path_resolves_and_runs(toy_module):
    f = FILTERS[f"{toy_module}:keep_even"]
    keep = f(np.zeros((4, 2)), np.zeros((4, 2)), np.c_[np.arange(4), np.arange(4)], np.zeros(4),
             image_size1=(8, 8), image_size2=(8, 8))
    assert keep.tolist() == [True, False, True, False]
    assert check_filters(["th", f"{toy_module}:keep_even"]) == ("th", f"{toy_module}:keep_even")
    # A path resolves but is not a registered name: "all" stays the registry's filters.
    assert f"{toy_module}:keep_even" not in resolve_filters("all")
    assert f"{toy_module}:keep_even" not in list(FILTERS)


@pytest.mark.parametrize("attr, message", [
    ("no_keywords", "a filter takes (kpts1, kpts2, matches, scores, *, image_size1"),
    ("NOT_A_FUNCTION", "'NOT_A_FUNCTION' is a int, not a function"),
    ("missing", "has no attribute 'missing'"),
])
def test_bad_attribute_is_an_error_naming_the_path(toy_module, attr, message):
    path = f"{toy_module}:{attr}"
    with pytest.raises(ValueError, match=f"filter '{path}'") as info:
        check_filters([path])
    assert message in str(info.value)
    assert path not in FILTERS


def test_module_that_does_not_import_is_an_error_naming_the_path():
    with pytest.raises(ValueError, match=r"filter 'no_such_module_xyz:f': cannot import 'no_such_module_xyz'"):
        FILTERS["no_such_module_xyz:f"]
    with pytest.raises(ValueError, match="an import path is 'module:function'"):
        load_filter("just_a_module:")
    with pytest.raises(ValueError, match="unknown filter 'nope'"):  # a plain unknown name stays that error
        check_filters(["nope"])


def test_module_in_the_current_folder_is_found(tmp_path, monkeypatch):
    import sys

    name = f"herefilters_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{name}.py").write_text(TOY)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    try:
        assert callable(load_filter(f"{name}:keep_even"))
    finally:
        sys.modules.pop(name, None)


def test_entry_point_group_registers_a_name(toy_module, tmp_path, monkeypatch):
    dist = tmp_path / "owntoy_dist-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: owntoy-dist\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nevens = {toy_module}:keep_even\n")
    registry._entry_points.cache_clear()
    assert "evens" in FILTERS and "evens" in list(FILTERS)
    assert "evens" in resolve_filters("all")
    assert FILTERS["evens"].__name__ == "keep_even"


def test_entry_point_with_a_bad_target_names_both(toy_module, tmp_path):
    dist = tmp_path / "badtoy_dist-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: badtoy-dist\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nbroken = {toy_module}:no_keywords\n")
    registry._entry_points.cache_clear()
    with pytest.raises(ValueError, match=rf"filter 'broken' \({toy_module}:no_keywords\)"):
        check_filters(["broken"])
