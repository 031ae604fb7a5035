"""``ctxmatch cache`` and :mod:`ctxmatch_lib.cache`: the size of each part, clearing a part or what is older
than an age, and never reaching outside the cache folder (links not followed, unmarked folders refused)."""

import os
import time
from pathlib import Path

import pytest

from ctxmatch_lib.cache import CACHE_MARKER, cache_dir, is_marked_cache, mark_cache
from ctxmatch_lib.cli import main
from ctxmatch_lib.cache import CACHE_PARTS, IN_PROGRESS_GRACE, cache_usage, clear_cache, parse_age, part_of

DAY = 86400.0

# One file per part: relative path -> size in bytes.
FILES = {
    "datasets/embedded-v1/images/a.png": 1000,
    "data/hpatches/v_x/1.ppm": 500,
    "features/opencv-4/sift/ab/ab12.e2.npz": 2000,
    "sweep/results/u1.parquet": 300,
    "sweep/candidates/c1.npz": 4000,
    "sweep/overlap/o1.npz": 40,
    "numba/kernels/k.nbi": 70,
    "weights/model.npz": 9,
    "learned-sets/s.npz": 11,
}
PART_BYTES = {"datasets": 1500, "features": 2000, "evaluations": 300, "sweeps": 4040, "numba": 70,
              "weights": 9, "other": 11}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A marked cache folder, ``CTXMATCH_CACHE``, holding :data:`FILES`."""
    root = tmp_path / "cache"
    monkeypatch.setenv("CTXMATCH_CACHE", str(root))
    assert cache_dir() == root and is_marked_cache(root)  # the cache marks the folder it creates
    for rel, size in FILES.items():
        _write(root / rel, size)
    return root


def _write(path: Path, size: int, age: float = 0.0) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    if age:
        t = time.time() - age
        os.utime(path, (t, t), follow_symlinks=False)
    return path


def _files(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file() or p.is_symlink()}


def test_usage_gives_each_part_its_size(cache, capsys):
    usage = cache_usage()
    assert usage.root == cache and usage.exists and usage.clearable
    assert {p.name: p.bytes for p in usage.parts} == PART_BYTES
    assert usage.bytes == sum(FILES.values()) and usage.files == len(FILES)
    assert [p.name for p in usage.parts] == list(CACHE_PARTS)
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert str(cache) in out
    rows = {line.split()[0]: line.split()[1:4] for line in out.splitlines()[2:]}
    assert rows["features"] == ["2.0", "kB", "1"] and rows["sweeps"] == ["4.0", "kB", "2"]
    assert rows["evaluations"] == ["300", "B", "1"] and rows["total"][2] == str(len(FILES))


def test_usage_of_a_missing_folder_creates_nothing(tmp_path):
    usage = cache_usage(tmp_path / "none")
    assert not usage.exists and usage.bytes == 0 and not (tmp_path / "none").exists()


def test_part_of_maps_folders_to_parts():
    assert part_of("sweep/results/x.parquet") == "evaluations"
    assert part_of("sweep/filters/a/b.npz") == "sweeps"
    assert part_of("sweep/other.txt") == part_of("ablation/x") == part_of("sweepy/x") == "other"
    assert part_of("data/x") == part_of("datasets") == "datasets"


def test_clear_a_part_removes_only_that_part(cache, capsys):
    assert main(["cache", "clear", "features", "evaluations"]) == 0
    out = capsys.readouterr().out
    assert "removed 2.3 kB in 2 files" in out and "features" in out and "evaluations" in out
    left = _files(cache)
    assert left == {CACHE_MARKER} | {r for r in FILES if not r.startswith(("features/", "sweep/results/"))}
    # The parts' own folders stay (running processes may hold them); the emptied folders below them go.
    assert (cache / "features").is_dir() and not any((cache / "features").iterdir())
    assert (cache / "sweep" / "results").is_dir()


def test_clear_all_leaves_only_the_marker(cache):
    result = clear_cache("all")
    assert result.bytes == sum(FILES.values()) and result.files == len(FILES)
    assert _files(cache) == {CACHE_MARKER} and is_marked_cache(cache)
    assert not (cache / "learned-sets").exists()  # an emptied folder of no part's own goes
    assert cache_usage().bytes == 0


def test_clear_by_age(cache, capsys):
    old = _write(cache / "features/opencv-4/sift/cd/old.npz", 700, age=10 * DAY)
    old_link = cache / "numba" / "old-link"
    os.symlink("kernels/k.nbi", old_link)
    t = time.time() - 10 * DAY
    os.utime(old_link, (t, t), follow_symlinks=False)
    assert main(["cache", "clear", "--older-than", "7d"]) == 0  # no part: every part
    assert "removed 713 B in 2 files" in capsys.readouterr().out  # a link weighs its target's name
    assert not old.exists() and not os.path.lexists(old_link)
    assert not (cache / "features/opencv-4/sift/cd").exists()  # emptied by the clear
    assert _files(cache) == {CACHE_MARKER, *FILES}
    # An age in hours, on one part: the files just written are younger.
    assert clear_cache(["features"], older_than="12h").files == 0
    assert clear_cache(["features"], older_than=0).files == 1


def test_links_are_removed_as_links_never_followed(cache, tmp_path):
    outside = tmp_path / "outside"
    target = _write(outside / "precious.txt", 5)
    _write(outside / "sub" / "deep.txt", 6)
    os.symlink(outside, cache / "features" / "to-folder")
    os.symlink(target, cache / "features" / "to-file")
    os.symlink(outside, cache / "sweep" / "results" / "old", target_is_directory=True)
    usage = {p.name: p for p in cache_usage().parts}
    assert usage["features"].files == 3  # the links count as (small) files; their targets are not read
    clear_cache("all")
    assert _files(cache) == {CACHE_MARKER}
    assert target.read_bytes() == b"xxxxx" and (outside / "sub" / "deep.txt").is_file()


def test_a_linked_part_folder_is_not_entered(cache, tmp_path):
    outside = tmp_path / "outside"
    kept = _write(outside / "x.npz", 10, age=30 * DAY)
    os.rename(cache / "numba", tmp_path / "numba-moved")
    os.symlink(outside, cache / "numba")
    clear_cache(["numba"], older_than="1d")
    assert kept.is_file() and (cache / "numba").is_symlink()  # too young as a link, never entered
    clear_cache(["numba"])
    assert kept.is_file() and not os.path.lexists(cache / "numba")


def test_an_unmarked_folder_is_refused(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "home"
    mine = _write(folder / "notes.txt", 3)
    _write(folder / "features" / "f.npz", 4)
    monkeypatch.setenv("CTXMATCH_CACHE", str(folder))
    assert main(["cache", "clear", "--all"]) == 1
    err = capsys.readouterr().err
    assert "not a ctxmatch cache folder" in err and CACHE_MARKER in err and "'notes.txt'" in err
    assert mine.is_file() and (folder / "features" / "f.npz").is_file()
    with pytest.raises(ValueError, match="not a ctxmatch cache folder"):
        clear_cache(["features"], dry_run=True)
    assert not cache_usage().clearable
    assert main(["cache"]) == 0 and "refuses" in capsys.readouterr().out
    # A marker written by another program does not make the folder ctxmatch's.
    (folder / CACHE_MARKER).write_text("Signature: 8a477f597d28d172789f06886806bc55\n# other tool\n")
    assert not is_marked_cache(folder) and main(["cache", "clear", "--all"]) == 1


def test_a_cache_made_before_the_marker_is_adopted(tmp_path, monkeypatch):
    # Only the cache's own sub-folders: clearly the cache of an earlier version; the marker is written.
    folder = tmp_path / "old-cache"
    _write(folder / "sweep" / "results" / "u.parquet", 8)
    _write(folder / "numba" / "k.nbi", 2)
    assert not is_marked_cache(folder)
    assert clear_cache(["evaluations"], root=folder).files == 1
    assert is_marked_cache(folder) and (folder / "numba" / "k.nbi").is_file()
    # A file of the user's beside them, or a link in place of a sub-folder, is not clearly ours.
    other = tmp_path / "mixed"
    _write(other / "features" / "f.npz", 1)
    os.symlink(tmp_path, other / "sweep")
    assert not mark_cache(other) and not (other / CACHE_MARKER).exists()


def test_dry_run_removes_nothing(cache, capsys):
    before = {p: p.stat().st_mtime for p in cache.rglob("*")}
    assert main(["cache", "clear", "--all", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"would remove 7.9 kB in {len(FILES)} files") and "nothing removed" in out
    assert {p: p.stat().st_mtime for p in cache.rglob("*")} == before
    assert clear_cache(["sweeps"], dry_run=True).bytes == PART_BYTES["sweeps"]
    assert _files(cache) == {CACHE_MARKER, *FILES}


def test_files_being_written_are_kept(cache, capsys):
    young = _write(cache / "features" / ".f.npz.x1y2.tmp", 50)  # atomic_path's temporary name
    numba_tmp = _write(cache / "numba" / "kernels" / "k.nbi.tmp.1234", 5)
    stale = _write(cache / "sweep" / "results" / ".u.parquet.ab.tmp", 7, age=IN_PROGRESS_GRACE + 60)
    assert main(["cache", "clear", "--all"]) == 0
    assert "kept 2 files being written" in capsys.readouterr().out
    assert young.is_file() and numba_tmp.is_file() and not stale.exists()
    assert clear_cache(["features"], older_than="1s").kept_in_progress == 1


@pytest.mark.parametrize("age", ["7", "7days", "-1d", "d", "1.5y", ""])
def test_a_bad_age_names_the_argument(cache, capsys, age):
    assert main(["cache", "clear", f"--older-than={age}"]) == 2
    err = capsys.readouterr().err
    assert "--older-than" in err and repr(age) in err
    with pytest.raises(ValueError, match="older_than"):
        clear_cache("all", older_than=age)
    assert _files(cache) == {CACHE_MARKER, *FILES}


def test_ages_and_bad_parts():
    assert parse_age("30m") == 1800 and parse_age("12h") == 43200 and parse_age("2w") == 14 * DAY
    assert parse_age("7D") == 7 * DAY and parse_age(90) == 90.0
    with pytest.raises(ValueError, match="parts must name parts of the cache"):
        clear_cache(["featurez"])
    with pytest.raises(ValueError, match="parts must name"):
        clear_cache([])


def test_cli_argument_errors(cache, capsys):
    assert main(["cache", "clear"]) == 2
    assert "name the parts to clear" in capsys.readouterr().err
    assert main(["cache", "clear", "featurez"]) == 2
    assert "unknown part 'featurez'" in capsys.readouterr().err
    assert main(["cache", "clear", "features", "--all"]) == 2
    assert "not both" in capsys.readouterr().err
    assert _files(cache) == {CACHE_MARKER, *FILES}


def test_a_missing_cache_folder_has_nothing_to_clear(tmp_path):
    result = clear_cache("all", root=tmp_path / "none")
    assert result.files == 0 and not (tmp_path / "none").exists()
