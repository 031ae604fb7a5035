"""The bad-input corpus of issue 23, case by case: each bad input fails at once with an error naming the
argument or the flag, before any work; nothing is silently accepted."""

from __future__ import annotations

import pickle

import pytest


# ------------------------------------------------------------------------------------ preset mappings
@pytest.mark.parametrize("module, name, what", [
    ("ctxmatch_lib.blob", "BLOB_PRESETS", "blob preset"),
    ("ctxmatch_lib.features", "FEATURE_PRESETS", "feature preset"),
    ("ctxmatch_lib.filters", "FILTERS", "filter"),
])
def test_unknown_preset_lists_the_known_names(module, name, what):
    import importlib

    presets = getattr(importlib.import_module(module), name)
    with pytest.raises(KeyError) as info:
        presets["best"]
    message = str(info.value)
    assert f"unknown {what} 'best'" in message
    assert all(known in message for known in presets)
    # Still a read-only-use Mapping: membership, get, iteration as before.
    assert "best" not in presets and presets.get("best") is None and len(list(presets)) == len(presets)


@pytest.mark.parametrize("name", ["BLOB_PRESETS", "FEATURE_PRESETS"])
def test_preset_dicts_stay_dicts(name):
    import ctxmatch_lib.blob as blob
    import ctxmatch_lib.features as features

    presets = getattr(blob, name, None) or getattr(features, name)
    assert isinstance(presets, dict) and dict(presets) == presets
    again = pickle.loads(pickle.dumps(presets))  # Dask ships them to workers
    assert again == presets and again.what == presets.what
