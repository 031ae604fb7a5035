"""The bad-input corpus, case by case: each bad input fails at once with an error naming the
argument or the flag, before any work; nothing is silently accepted."""

from __future__ import annotations

import pickle
from pathlib import Path

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
    """Make any matching fail the test: the error must come before it (the two images' features may have
    started, in the background)."""
    import ctxmatch_lib.match as match

    def boom(*args, **kwargs):
        raise AssertionError("matching ran before the bad output path was reported")

    monkeypatch.setattr(match, "match_images", boom)
    monkeypatch.setattr(match.PairFeatures, "match", boom)


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


# ------------------------------------------------------------- degenerate ground truth (cases 6 and 7)
def _custom_folder(tmp_path, gt_text, *, kind="planar", f_text=None):
    import cv2
    import numpy as np

    cv2.imwrite(str(tmp_path / "a.png"), np.random.default_rng(0).integers(0, 255, (48, 64), np.uint8))
    (tmp_path / "gt.txt").write_text(gt_text)
    header, f_col = "pair_id,image1,image2,kind,gt", ""
    if f_text is not None:
        (tmp_path / "F.txt").write_text(f_text)
        header, f_col = header + ",F", ",F.txt"
    (tmp_path / "pairs.csv").write_text(f"{header}\nmine,a.png,a.png,{kind},gt.txt{f_col}\n")
    return tmp_path


@pytest.mark.parametrize("h_text, reason", [
    ("0 0 0\n0 0 0\n0 0 0\n", "all zeros"),                                 # case 6
    ("1 2 3\n2 4 6\n3 6 9\n", "rank 1"),                                    # case 7
    ("1 0 5\n0 1 7\n0 0 0\n", "rank 2"),
    ("1 0 nan\n0 1 0\n0 0 1\n", "NaN or infinite"),
    ("1 0 inf\n0 1 0\n0 0 1\n", "NaN or infinite"),
])
def test_custom_degenerate_homography_fails_naming_file_and_pair(tmp_path, h_text, reason):
    from ctxmatch_lib.datasets import load_dataset

    folder = _custom_folder(tmp_path, h_text)
    with pytest.raises(ValueError, match=reason) as info:
        load_dataset(folder)
    assert "gt.txt" in str(info.value) and "'mine'" in str(info.value)


def test_degenerate_homography_fails_the_eval_command_before_any_work(tmp_path, capsys):
    # The corpus ran `ctxmatch eval --dataset DIR`: rc 0 and a "failed" pair. Now an error naming the file.
    from ctxmatch_lib.cli import main

    folder = _custom_folder(tmp_path, "0 0 0\n0 0 0\n0 0 0\n")
    rc = main(["eval", "--dataset", str(folder), "--out", str(tmp_path / "r.parquet")])
    err = capsys.readouterr().err
    assert rc != 0 and "gt.txt" in err and "all zeros" in err and "Traceback" not in err
    assert not (tmp_path / "r.parquet").exists()


@pytest.mark.parametrize("f_text, reason", [
    ("0 0 0\n0 0 0\n0 0 0\n", "all zeros"),
    ("1 2 3\n2 4 6\n3 6 9\n", "rank 1"),
    ("0 0 0\n0 0 -1\n0 inf 0\n", "NaN or infinite"),
])
def test_custom_degenerate_fundamental_file_fails_naming_it(tmp_path, f_text, reason):
    import numpy as np

    from ctxmatch_lib.datasets import load_dataset

    pts = np.random.default_rng(1).uniform(0, 60, (8, 4))
    folder = _custom_folder(tmp_path, "\n".join(" ".join(map(str, r)) for r in pts), kind="nonplanar",
                            f_text=f_text)
    with pytest.raises(ValueError, match=reason) as info:
        load_dataset(folder)
    assert "F.txt" in str(info.value) and "'mine'" in str(info.value)


def test_custom_coincident_hand_points_fail_naming_the_file(tmp_path):
    from ctxmatch_lib.datasets import load_dataset

    folder = _custom_folder(tmp_path, "5 5 6 6\n" * 8, kind="nonplanar")
    with pytest.raises(ValueError, match="gt.txt: cannot fit F.*degenerate") as info:
        load_dataset(folder)
    assert "'mine'" in str(info.value)


def test_custom_flow_without_any_known_pixel_fails(tmp_path):
    import numpy as np

    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.datasets.custom import read_flow

    folder = _custom_folder(tmp_path, "")
    np.savez(folder / "flow.npz", flow12=np.full((48, 64, 2), np.nan))
    (folder / "pairs.csv").write_text("pair_id,image1,image2,kind,gt\nmine,a.png,a.png,depth,flow.npz\n")
    with pytest.raises(ValueError, match="flow.npz.*no known pixel"):
        load_dataset(folder)
    np.savez(folder / "inf.npz", flow12=np.full((48, 64, 2), np.inf))
    with pytest.raises(ValueError, match="inf.npz.*infinite"):
        read_flow(folder / "inf.npz")


@pytest.mark.parametrize("make", [
    lambda np, gt: gt.HomographyGT(np.zeros((3, 3))),
    lambda np, gt: gt.HomographyGT(np.outer([1, 2, 3], [1, 1, 1.0])),
    lambda np, gt: gt.HomographyGT(np.eye(3), np.zeros((2, 2))),                    # pts2 missing
    lambda np, gt: gt.EpipolarGT(np.zeros((3, 3)), np.zeros((1, 2)), np.zeros((1, 2))),
    lambda np, gt: gt.EpipolarGT(np.outer([1, 2, 3], [1, 0, 0.0]), np.zeros((1, 2)), np.zeros((1, 2))),
    lambda np, gt: gt.EpipolarGT(np.diag([1.0, 1, 0]), np.zeros((2, 2)), np.zeros((3, 2))),
    lambda np, gt: gt.FlowGT(np.full((4, 4, 2), np.nan)),
    lambda np, gt: gt.FlowGT(np.zeros((4, 4))),
], ids=["H-zeros", "H-rank1", "H-half-points", "F-zeros", "F-rank1", "F-points-length", "flow-all-nan",
        "flow-shape"])
def test_ground_truth_objects_refuse_degenerate_input(make):
    # Whatever builds them (a loader, user code), a ground truth that cannot label anything is an error.
    import numpy as np

    from ctxmatch_lib.datasets import base as gt

    with pytest.raises(ValueError):
        make(np, gt)
    # The valid ones still build.
    gt.HomographyGT(np.eye(3)), gt.EpipolarGT(np.diag([1.0, 1, 0]), np.zeros((2, 2)), np.zeros((2, 2)))
    gt.FlowGT(np.zeros((4, 4, 2)))


# ----------------------------------------------------------------------------------- ctxmatch train
def _fake_training(monkeypatch):
    """Replace the training by a recorder: the CLI's own checks and paths are what is tested here."""
    import types

    import ctxmatch_lib.filters.learned as learned

    calls = []

    def fake(arch, **kwargs):
        calls.append(kwargs)
        return types.SimpleNamespace(losses=[0.5], seconds=0.0, path=kwargs["output"],
                                     validation={"inlier_ratio": 0.4, "precision": 1.0, "recall": 1.0})

    monkeypatch.setattr(learned, "train_learned_filter", fake)
    monkeypatch.setattr(learned, "torch_available", lambda: True)
    return calls


def test_train_default_output_is_the_cache_not_the_shipped_weights(tmp_path, monkeypatch, capsys):
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.filters.learned import shipped_weights

    calls = _fake_training(monkeypatch)
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    assert main(["train", "oanet", "--no-progress"]) == 0
    assert main(["train", "acne", "--seed", "3", "--steps", "10", "--no-progress"]) == 0
    outputs = [c["output"] for c in calls]
    assert outputs == [tmp_path / "cache" / "weights" / "oanet_trained_here_seed0.npz",
                       tmp_path / "cache" / "weights" / "acne_trained_here_seed3_steps10.npz"]
    assert all(o != shipped_weights(a) for o, a in zip(outputs, ("oanet", "acne")))
    out = capsys.readouterr().out
    assert "weights=" in out and str(outputs[1]) in out


@pytest.mark.parametrize("flags, named", [
    (["--steps", "0"], "--steps"), (["--batch-size", "0"], "--batch-size"), (["--k-min", "0"], "--k-min"),
    (["--k-min", "900", "--k-max", "800"], "--k-min must be <= --k-max"), (["--lr", "0"], "--lr"),
    (["--lr", "nan"], "--lr"), (["--threads", "0"], "--threads"), (["--max-images", "0"], "--max-images"),
    (["--output", "file/w.npz"], "--output"), (["--output", "."], "--output"),
])
def test_train_bad_flags_fail_before_training(tmp_path, monkeypatch, capsys, flags, named):
    from ctxmatch_lib.cli import main

    calls = _fake_training(monkeypatch)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("a regular file")
    assert main(["train", "acne", *flags]) == 2
    assert calls == [] and named in capsys.readouterr().err


def test_train_without_torch_says_what_to_install(monkeypatch, capsys, tmp_path):
    import ctxmatch_lib.filters.learned as learned
    from ctxmatch_lib.cli import main

    _fake_training(monkeypatch)
    monkeypatch.setattr(learned, "torch_available", lambda: False)
    assert main(["train", "acne", "--output", str(tmp_path / "w.npz")]) == 2
    assert "pip install" in capsys.readouterr().err


def test_train_tiny_run_writes_the_cache_and_loads_with_weights(tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch", reason="training needs torch (pip install 'ctxmatch[torch]')")
    import numpy as np

    from ctxmatch_lib.cli import main
    from ctxmatch_lib.filters import FILTERS
    from ctxmatch_lib.filters.learned import shipped_weights

    shipped = shipped_weights("acne").read_bytes()
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    assert main(["train", "acne", "--steps", "2", "--batch-size", "1", "--k-min", "32", "--k-max", "32",
                 "--max-images", "2", "--no-progress"]) == 0
    path = tmp_path / "cache" / "weights" / "acne_trained_here_seed0_steps2.npz"
    assert path.is_file() and shipped_weights("acne").read_bytes() == shipped
    rng = np.random.default_rng(0)
    k = rng.uniform(0, 60, (40, 2))
    m = np.c_[np.arange(40), np.arange(40)]
    keep = FILTERS["acne"](k, k + 1, m, np.linspace(0, 1, 40), image_size1=(64, 64), image_size2=(64, 64),
                           weights=path)
    assert keep.shape == (40,) and keep.dtype == bool


@pytest.mark.parametrize("flags, message", [
    (["--model-threshold", "-1"], "--model-threshold must be a positive number of pixels, got -1.0"),
    (["--model-threshold", "nan"], "--model-threshold must be a positive"),
    (["--features", "best"], "--features: unknown feature preset 'best'; known presets: sift-rootsift"),
    (["--blob", "best"], "--blob: unknown blob preset 'best'; known presets: paper-best"),
    (["--blob", "paper-best:zz=1"], "--blob: blob override 'zz=1'"),
    (["--filter", "best"], "--filter: unknown filter 'best'; known filters:"),
    (["--max-keypoints", "-1"], "--max-keypoints must be >= 0"),
])
def test_match_setting_errors_name_the_flag(images, tmp_path, monkeypatch, capsys, flags, message):
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    assert main(["match", str(images / "a.png"), str(images / "b.png"), "--out", str(tmp_path / "m.npz"),
                 *flags]) == 2
    assert message in capsys.readouterr().err


def test_match_images_are_checked_before_matching(images, tmp_path, monkeypatch, capsys):
    from ctxmatch_lib.cli import main

    _no_work(monkeypatch)
    assert main(["match", str(images), str(images / "b.png"), "--out", str(tmp_path / "m.npz")]) == 2
    assert f"IMAGE: {images} is not a file" in capsys.readouterr().err
    assert main(["match", str(images / "a.png"), str(tmp_path / "nope.png"), "--out", str(tmp_path / "m.npz")]) == 2
    assert "IMAGE: file not found" in capsys.readouterr().err and not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("bad, error, message", [
    ("zeros-5x5x5", ValueError, "image2: image must be a path"),
    ("nope.png", FileNotFoundError, "image2: image file not found"),
    ("zeros-0x4", ValueError, "image2 must be a non-empty 2-D image"),
])
def test_match_images_names_the_bad_image(bad, error, message):
    import numpy as np

    from ctxmatch_lib.match import match_images

    arrays = {"zeros-5x5x5": np.zeros((5, 5, 5)), "zeros-0x4": np.zeros((0, 4))}
    with pytest.raises(error, match=message):
        match_images(np.zeros((50, 50), np.uint8), arrays.get(bad, bad), cache_dir=False)


def test_match_missing_optional_dependency_is_one_line(images, tmp_path, monkeypatch, capsys):
    # A deep feature preset without kornia: the install hint, not a traceback.
    import ctxmatch_lib.match as match
    from ctxmatch_lib.cli import main

    def no_kornia(*args, **kwargs):
        raise ImportError("the deep descriptors need kornia: pip install 'ctxmatch[kornia]'")

    monkeypatch.setattr(match, "match_images", no_kornia)
    monkeypatch.setattr(match.PairFeatures, "match", no_kornia)
    assert main(["match", str(images / "a.png"), str(images / "b.png"), "--out", str(tmp_path / "m.npz"),
                 "--features", "sift-hardnet2"]) == 2
    assert "pip install 'ctxmatch[kornia]'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------- pair ids
def test_unknown_pair_id_names_the_argument_and_lists_valid_ids():
    """A pair id the dataset lacks is a ValueError naming ``pair_ids`` and the valid ids closest to it (as a bad
    dataset name lists the names), not a bare KeyError."""
    from ctxmatch_lib.evaluation import select_pairs

    with pytest.raises(ValueError) as info:
        select_pairs("embedded", pair_ids=["nonplanar/nosuch"])
    message = str(info.value)
    assert "pair_ids" in message and "'nonplanar/nosuch'" in message
    assert "nonplanar/cards" in message and "(20 in all)" in message  # the non-planar ids come first
    with pytest.raises(ValueError, match="holds no pair"):
        select_pairs("embedded", pair_ids=["planar/lab/1-2"], kinds=["calibrated"])
    assert [p.pair_id for p in select_pairs("embedded", pair_ids=["nonplanar/cards"])] == ["nonplanar/cards"]


def test_notebook_with_an_unknown_pair_id_fails_naming_it(tmp_path):
    """The notebooks look their pairs up with select_pairs: a bad ``pair_id`` parameter stops the run with the
    same ValueError, before any feature is computed."""
    papermill = pytest.importorskip("papermill")
    notebook = Path(__file__).resolve().parents[1] / "notebooks" / "fig_boundary.ipynb"
    with pytest.raises(papermill.PapermillExecutionError) as info:
        papermill.execute_notebook(str(notebook), str(tmp_path / "out.ipynb"), kernel_name="python3",
                                   parameters={"pair_id": "nonplanar/nosuch", "output_dir": str(tmp_path)},
                                   progress_bar=False)
    assert info.value.ename == "ValueError" and "pair_ids" in info.value.evalue
    assert "nonplanar/cards" in info.value.evalue
