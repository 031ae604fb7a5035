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


# ------------------------------------------------------------------- output paths, checked before work
def _no_work(monkeypatch):
    """Make any matching fail the test: the error must come before it."""
    import ctxmatch_lib.match as match

    def boom(*args, **kwargs):
        raise AssertionError("matching ran before the bad output path was reported")

    monkeypatch.setattr(match, "match_images", boom)


@pytest.fixture
def images(tmp_path):
    import cv2
    import numpy as np

    folder = tmp_path / "imgs"
    folder.mkdir()
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(folder / name), np.random.default_rng(0).integers(0, 255, (40, 50), np.uint8))
    (tmp_path / "pairs.txt").write_text("a.png b.png\n")
    (tmp_path / "file").write_text("a regular file")
    return folder


@pytest.mark.parametrize("mode, flag, value", [
    ("single", "--out", "file/x.npz"),            # case 2
    ("single", "--plot", "file/x.png"),           # case 3
    ("single", "--out", "imgs"),                  # a folder where the .npz goes (suffix checked first)
    ("single", "--plot", "imgs"),                 # a folder where the picture goes
    ("single", "--export-h5", "file"),            # a file where the folder goes
    ("single", "--export-h5", "file/hloc"),
    ("single", "--export-colmap", "file/db.db"),
    ("single", "--export-colmap", "file"),        # exists and is not an SQLite database
    ("single", "--export-colmap", "imgs"),
    ("pairs", "--out", "file"),                   # folder mode: --out is a folder
    ("pairs", "--out", "file/matches"),
    ("pairs", "--plot", "file/pics"),
    ("pairs", "--export-h5", "file/hloc"),
    ("pairs", "--export-colmap", "file/db.db"),
])
def test_match_output_paths_fail_before_matching(images, tmp_path, monkeypatch, capsys, mode, flag, value):
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    monkeypatch.chdir(tmp_path)
    args = ["match", "imgs/a.png", "imgs/b.png"] if mode == "single" else ["match", "--pairs", "pairs.txt",
                                                                             "--images", "imgs"]
    if flag != "--out":
        args += ["--out", "out.npz" if mode == "single" else "out"]
    assert main(args + [flag, value, "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("ctxmatch match: error: ") and flag in err and value.split("/")[0] in err
    assert "Traceback" not in err
    assert not (tmp_path / "out.npz").exists() and not (tmp_path / "out").exists()


def test_match_plot_format_is_checked_before_matching(images, tmp_path, monkeypatch, capsys):
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    assert main(["match", str(images / "a.png"), str(images / "b.png"), "--out", str(tmp_path / "m.npz"),
                 "--plot", str(tmp_path / "m.xyz")]) == 2
    err = capsys.readouterr().err
    assert "--plot" in err and "'.xyz'" in err and ".png" in err


def test_match_existing_hdf5_that_is_not_one_fails_first(images, tmp_path, monkeypatch, capsys):
    pytest.importorskip("h5py")
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    (tmp_path / "hloc").mkdir()
    (tmp_path / "hloc" / "matches.h5").write_text("not hdf5")
    assert main(["match", str(images / "a.png"), str(images / "b.png"), "--out", str(tmp_path / "m.npz"),
                 "--export-h5", str(tmp_path / "hloc")]) == 2
    err = capsys.readouterr().err
    assert "--export-h5" in err and "matches.h5" in err and "not an HDF5 file" in err


def test_missing_pairs_file_names_the_flag(images, tmp_path, monkeypatch, capsys):
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    assert main(["match", "--pairs", str(tmp_path / "nope.txt"), "--images", str(images)]) == 2
    err = capsys.readouterr().err
    assert "--pairs: file not found" in err and "nope.txt" in err and "Errno" not in err
    assert main(["match", "--pairs", str(images), "--images", str(images)]) == 2
    assert "--pairs" in capsys.readouterr().err
    assert main(["match", "--pairs", str(tmp_path / "pairs.txt"), "--images", str(tmp_path / "nodir")]) == 2
    assert "--images: folder not found" in capsys.readouterr().err
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00binary")
    assert main(["match", "--pairs", str(tmp_path / "bin.txt"), "--images", str(images)]) == 2
    err = capsys.readouterr().err
    assert "--pairs: pairs file" in err and "not a text file" in err


def test_read_pairs_and_match_pairs_name_their_arguments(images, tmp_path):
    from ctxmatch_lib.match import match_pairs, read_pairs

    with pytest.raises(FileNotFoundError, match="pairs file not found"):
        read_pairs(tmp_path / "nope.txt")
    with pytest.raises(ValueError, match="out_dir: cannot create .*file is a file"):
        match_pairs([("a.png", "b.png")], images, tmp_path / "file" / "out", progress=False)
    (tmp_path / "out" / "a.png__b.png.npz").mkdir(parents=True)
    with pytest.raises(ValueError, match="out_dir: .*a.png__b.png.npz is a folder"):
        match_pairs([("a.png", "b.png")], images, tmp_path / "out", progress=False)
