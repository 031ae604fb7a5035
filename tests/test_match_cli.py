"""``ctxmatch match`` end to end on two embedded images, folder mode resumed after a SIGKILL, and the library
side (:mod:`ctxmatch_lib.match`)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ctxmatch_lib.cli import main
from ctxmatch_lib.match import load_result, match_images, read_pairs, resolve_blob

# The planted homography between the two test images (image 1 -> image 2).
H12 = np.array([[0.95, 0.08, 12.0], [-0.06, 0.97, 8.0], [1e-4, 0.0, 1.0]])


def _write_pair(folder: Path, name1="a.png", name2="b.png", *, crop=0):
    """Two images from scikit-image's bundled astronaut photo: image 2 is image 1 warped by H12."""
    import cv2
    from skimage.data import astronaut

    img = cv2.cvtColor(astronaut(), cv2.COLOR_RGB2BGR)[::2, ::2][crop:, crop:]
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / name1), img)
    cv2.imwrite(str(folder / name2), cv2.warpPerspective(img, H12, (240, 220)))
    return folder / name1, folder / name2


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    return _write_pair(tmp_path_factory.mktemp("imgs"))


def test_match_cli_end_to_end(pair, tmp_path, capsys):
    out, pic = tmp_path / "m.npz", tmp_path / "m.png"
    rc = main(["match", str(pair[0]), str(pair[1]), "--out", str(out), "--plot", str(pic),
               "--max-keypoints", "500", "--no-cache"])
    assert rc == 0
    with np.load(out) as z:
        keys = set(z.files)
        d = {k: z[k] for k in z.files}
    assert {"kpts1", "kpts2", "matches", "scores", "image_size1", "image_size2", "settings"} <= keys
    m = d["matches"]
    assert m.dtype == np.int64 and m.ndim == 2 and m.shape[1] == 2 and len(m) > 50
    assert d["scores"].shape == (len(m),) and np.all(np.diff(d["scores"]) >= 0)
    # Sizes come from the files: 256 x 256 and 240 x 220.
    assert d["image_size1"].tolist() == [256, 256] and d["image_size2"].tolist() == [240, 220]
    settings = json.loads(str(d["settings"]))
    assert settings["filters"] == ["dtm"] and settings["blob"]["f"] == 10 and settings["features"]["max_keypoints"] == 500
    # Most kept matches agree with the planted homography (DTM keeps the consistent ones; blob matches are
    # many-to-many, so neighbouring keypoints within a few pixels count too).
    p1 = np.c_[d["kpts1"][m[:, 0]], np.ones(len(m))] @ H12.T
    err = np.linalg.norm(p1[:, :2] / p1[:, 2:] - d["kpts2"][m[:, 1]], axis=1)
    assert np.mean(err < 15) > 0.8  # the paper's ground-truth tolerance (Sec. 5.1)
    assert pic.is_file() and pic.stat().st_size > 10_000
    assert "matches kept" in capsys.readouterr().out


def test_match_cli_filters_model_and_errors(pair, tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert main(["match", str(pair[0]), str(pair[1]), "--out", str(out), "--max-keypoints", "400", "--no-cache",
                 "--filter", "dtm,gms", "--model", "1sac", "--model-kind", "H"]) == 0
    d = load_result(out)
    assert d["settings"]["filters"] == ["dtm", "gms"] and d["settings"]["model"] == "1sac" and "model" in d
    assert main(["match", str(pair[0]), str(pair[1]), "--out", str(out), "--max-keypoints", "400", "--no-cache",
                 "--filter", "none", "--model", "magsac", "--model-kind", "H"]) == 0
    assert load_result(out)["settings"]["model"] == "magsac"
    assert main(["match", str(pair[0]), "--out", str(out)]) == 2
    assert main(["match", str(pair[0]), str(pair[1]), "--filter", "nope"]) == 2
    assert main(["match", str(pair[0]), str(pair[1]), "--blob", "paper-best:zz=1"]) == 2
    assert main(["match", str(pair[0]), str(tmp_path / "missing.png"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "unknown filter 'nope'" in err and "zz=1" in err and "missing.png" in err


def test_match_images_library(pair):
    res = match_images(pair[0], pair[1], max_keypoints=400, cache_dir=False, filters=None)
    assert len(res.matches) == len(res.candidates) and res.keep.all()
    res2 = match_images(pair[0], pair[1], max_keypoints=400, cache_dir=False, filters="dtm")
    np.testing.assert_array_equal(res2.candidates, res.candidates)
    np.testing.assert_array_equal(res2.matches, res.candidates[res2.keep])
    assert 0 < len(res2.matches) < len(res.matches)
    # A blank image has no keypoints: an empty result, not an error.
    empty = match_images(np.zeros((64, 64), np.uint8), pair[1], cache_dir=False)
    assert empty.matches.shape == (0, 2) and empty.matches.dtype == np.int64 and empty.scores.shape == (0,)
    with pytest.raises(ValueError, match="model must be"):
        match_images(pair[0], pair[1], model="magic", cache_dir=False)


def test_resolve_blob_and_pairs(tmp_path):
    assert resolve_blob("baseline").f == "omega"
    cfg = resolve_blob("f=3,prefilter=cap,t_o=none")
    assert (cfg.f, cfg.prefilter, cfg.t_o, cfg.ratio) == (3, "cap", None, "D+")
    assert resolve_blob({"f_prime": 1}).f_prime == 1
    with pytest.raises(ValueError, match="unknown blob preset"):
        resolve_blob("best")
    p = tmp_path / "pairs.txt"
    p.write_text("# hloc pairs\na.png b.png\n\na.png b.png\nsub/c.png a.png  # comment\n")
    assert read_pairs(p) == [("a.png", "b.png"), ("sub/c.png", "a.png")]
    p.write_text("a.png\n")
    with pytest.raises(ValueError, match="line 1"):
        read_pairs(p)


def test_folder_mode_resumes_after_sigkill(tmp_path, monkeypatch, capsys):
    imgs = tmp_path / "images"
    _write_pair(imgs, "a.png", "b.png")
    _write_pair(imgs, "c.png", "d.png", crop=6)
    names = ["a.png", "b.png", "c.png", "d.png"]
    pairs = [(x, y) for i, x in enumerate(names) for y in names[i + 1:]]  # 6 pairs
    (tmp_path / "pairs.txt").write_text("".join(f"{x} {y}\n" for x, y in pairs))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "ctxmatch_lib.cli", "match", "--pairs", str(tmp_path / "pairs.txt"),
           "--images", str(imgs), "--out", str(out), "--max-keypoints", "300", "--no-progress"]
    env = {**os.environ, "CTXMATCH_CACHE": str(tmp_path / "cache")}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not list(out.glob("*.npz")):
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.glob("*.npz")}
    assert 0 < len(before) < 6, "the kill must land after the first pair and before the last"
    for p in out.glob("*.npz"):  # what is there is complete
        assert len(load_result(p)["matches"]) > 0
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert f"{len(before)} already done" in done.stdout
    files = sorted(p.name for p in out.glob("*.npz"))
    assert len(files) == 6
    for name, (mtime, data) in before.items():  # finished pairs were not recomputed
        assert (out / name).stat().st_mtime_ns == mtime and (out / name).read_bytes() == data
    # In process from here on (faster): nothing left to do; other settings are recomputed, not mistaken
    # for finished pairs.
    monkeypatch.setenv("CTXMATCH_CACHE", env["CTXMATCH_CACHE"])
    assert main(cmd[3:]) == 0
    assert "0 matched, 6 already done" in capsys.readouterr().out
    assert main(cmd[3:] + ["--filter", "none"]) == 0
    assert "6 matched, 0 already done" in capsys.readouterr().out


def _six_pairs(tmp_path):
    imgs = tmp_path / "images"
    _write_pair(imgs, "a.png", "b.png")
    _write_pair(imgs, "c.png", "d.png", crop=6)
    names = ["a.png", "b.png", "c.png", "d.png"]
    pairs = [(x, y) for i, x in enumerate(names) for y in names[i + 1:]]
    (tmp_path / "pairs.txt").write_text("".join(f"{x} {y}\n" for x, y in pairs))
    return ["match", "--pairs", str(tmp_path / "pairs.txt"), "--images", str(imgs), "--out", str(tmp_path / "out"),
            "--max-keypoints", "300", "--no-progress"]


def test_ctrl_c_prints_one_line_and_the_rerun_resumes(tmp_path, monkeypatch, capsys):
    # Ctrl-C in the third pair: status 130, one line instead of a traceback; the rerun does only the rest.
    import ctxmatch_lib.match as match

    args = _six_pairs(tmp_path)
    monkeypatch.setenv("CTXMATCH_CACHE", str(tmp_path / "cache"))
    real, calls = match._match_features, []  # the folder mode's step after the features, once per pair

    def interrupted_third(*a, **k):
        calls.append(a)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(match, "_match_features", interrupted_third)
    assert main(args) == 130
    err = capsys.readouterr().err.strip()
    assert err == ("ctxmatch match: interrupted; rerun the same command to resume (finished work is kept, "
                   "nothing half-written)")
    out = tmp_path / "out"
    before = {p.name: p.read_bytes() for p in out.glob("*.npz")}
    assert len(before) == 2 and not list(out.glob(".*"))  # no temporary file left
    monkeypatch.setattr(match, "_match_features", real)
    assert main(args) == 0
    assert "4 matched, 2 already done" in capsys.readouterr().out
    assert len(list(out.glob("*.npz"))) == 6
    assert all((out / name).read_bytes() == data for name, data in before.items())


def test_sigint_in_a_real_process_has_no_traceback(tmp_path):
    out = tmp_path / "out"
    # Each pair made to last at least 0.3 s, so that the signal lands between the first and the last pair
    # (with warm caches a pair of these small images takes milliseconds: all six could finish first).
    slow = ("import sys, time; import ctxmatch_lib.match as m; real = m._match_features; "
            "m._match_features = lambda *a, **k: (time.sleep(0.3), real(*a, **k))[1]; "
            "from ctxmatch_lib.cli import main; sys.exit(main(sys.argv[1:]))")
    cmd = [sys.executable, "-c", slow] + _six_pairs(tmp_path)
    env = {**os.environ, "CTXMATCH_CACHE": str(tmp_path / "cache")}
    # SIGINT as a terminal delivers it: a test run started in the background by a non-interactive shell (CI)
    # inherits SIGINT ignored, and so would the child, which would then finish all six pairs.
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not list(out.glob("*.npz")):
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    n = len(list(out.glob("*.npz")))
    assert 0 < n < 6, "the signal must land after the first pair and before the last"
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.strip().splitlines() == [
        "ctxmatch match: interrupted; rerun the same command to resume (finished work is kept, nothing "
        "half-written)"]


def test_folder_mode_equals_one_pair_at_a_time(tmp_path):
    # The folder mode extracts the images ahead in threads and keeps an image's features for its next pairs:
    # each pair's file holds what match_images gives for that pair alone.
    from ctxmatch_lib.match import PairFeatures, match_pairs

    args = _six_pairs(tmp_path)
    imgs = Path(args[args.index("--images") + 1])
    pairs = read_pairs(tmp_path / "pairs.txt")
    summary = match_pairs(pairs, imgs, tmp_path / "out", progress=False, max_keypoints=300, cache_dir=False)
    assert summary["done"] == len(pairs) == 6
    for (a, b), path in summary["files"].items():
        alone = match_images(imgs / a, imgs / b, max_keypoints=300, cache_dir=False)
        started = PairFeatures(imgs / a, imgs / b, max_keypoints=300, cache_dir=False).match()
        saved = load_result(path)
        for res in (alone, started):
            np.testing.assert_array_equal(saved["matches"], res.matches)
            np.testing.assert_array_equal(saved["kpts1"], res.kpts1)
            np.testing.assert_array_equal(saved["kpts2"], res.kpts2)


def test_pair_features_report_a_bad_image_by_its_argument(tmp_path):
    from ctxmatch_lib.match import PairFeatures

    with pytest.raises(FileNotFoundError, match="image2"):
        PairFeatures(np.zeros((40, 40), np.uint8), tmp_path / "missing.png")


def test_kernels_ready_and_warmup(tmp_path, monkeypatch, capsys):
    # With an empty numba cache the kernels are not ready (ctxmatch match says it compiles them); the suite's
    # cache has them after a match, and `ctxmatch warmup` loads (or compiles) them.
    from ctxmatch_lib.match import kernels_ready

    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "ctxmatch warmup: done in" in out
    assert kernels_ready()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    assert not kernels_ready()


def test_match_says_when_it_compiles_the_kernels(pair, tmp_path, monkeypatch, capsys):
    import ctxmatch_lib.match as match

    args = ["match", str(pair[0]), str(pair[1]), "--out", str(tmp_path / "m.npz"), "--max-keypoints", "300",
            "--no-cache", "--no-progress"]
    monkeypatch.setattr(match, "kernels_ready", lambda: False)
    assert main(args) == 0
    assert "compiling the kernels of matching, once per machine" in capsys.readouterr().err
    monkeypatch.setattr(match, "kernels_ready", lambda: True)
    assert main(args) == 0
    assert "compiling" not in capsys.readouterr().err


def test_a_users_filter_sees_only_the_real_pair(monkeypatch):
    # While the features are extracted, the library's own steps run on a small pair to load their kernels; a
    # filter registered from outside the library is never called on it.
    from ctxmatch_lib.filters import FILTERS, register_filter

    seen = []

    def mine(kpts1, kpts2, matches, scores, **kwargs):
        seen.append(len(matches))
        return np.ones(len(matches), bool)

    monkeypatch.setitem(FILTERS._loaded, "test-mine", mine)
    assert FILTERS["test-mine"] is mine and callable(register_filter)
    from skimage.data import camera

    img = np.ascontiguousarray(camera()[::2, ::2])
    res = match_images(img, np.ascontiguousarray(img[10:, 12:]), filters=("dtm", "test-mine"), max_keypoints=300,
                       cache_dir=False)
    assert seen and set(seen) == {len(res.matches)}
    import ctxmatch_lib.match as match

    seen.clear()
    match._load_kernels(match._checked(filters=("dtm", "test-mine")))  # the small pair itself
    assert seen == []
