"""The evaluation engine (ctxmatch_lib.evaluation, ctxmatch sweep): exactness against the pipeline, caches, resume
after a kill, joblib/Dask == serial, one surface with ctxmatch eval."""

import os
import pickle
import subprocess
import sys

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ctxmatch_lib import evaluation as sweep
from ctxmatch_lib.report.blob import blob_map, heatmap_matrix
from ctxmatch_lib.evaluation import overlap as ev_overlap
from ctxmatch_lib.evaluation import rows as ev_rows
from ctxmatch_lib.evaluation import run as ev_run
from ctxmatch_lib.evaluation import unit as ev_unit
from ctxmatch_lib.blob import BlobContext, blob_grid, rank_candidates
from ctxmatch_lib.blob.config import GRID_T_O, RATIOS
from ctxmatch_lib.metrics import average_precision, normalised_count
from ctxmatch_lib.pipeline import evaluate_pair, pair_features

KPTS = 300
# 6 candidate sets x all 90 score variants: every code path of the grid, small enough for CI.
SMALL_GRID = [c for c in blob_grid() if c.candidate_key in {(1, "cup", 1), (10, "cup", 5), ("omega", "cup", 1),
                                                              (3, "cap", 3), (5, "cap", 5), ("omega", "cup", 5)}]
KW = dict(blobs=SMALL_GRID, pairs=3, max_keypoints=KPTS, progress=False)
KEYS = ["dataset", "pair_id", "features", "blob", "method", "model"]


def _numbers(df):
    return df.drop(columns=["time_s", "model_time_s"])


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    cache = tmp_path_factory.mktemp("serial")
    return cache, sweep.run_sweep("embedded", cache_dir=cache, **KW)


# ------------------------------------------------------------------------------------------ exactness


@pytest.mark.parametrize("seed", range(5))
def test_ranked_ap_is_bit_identical_to_metrics(seed):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(0, 60))
    m = rng.integers(0, 12, size=(k, 2))
    lab = rng.random(k) < 0.5
    scores = rng.integers(0, 5, size=k).astype(float)  # many ties
    ref = m[lab]
    den = normalised_count(ref)
    expected = average_precision(m, lab, scores, ref)
    got = ev_rows.ranked_ap(m[:, 0], m[:, 1], lab, scores, den, 12, 12)
    assert (np.isnan(expected) and np.isnan(got)) or got == expected
    # Both references of a row from one ranking (the unit's ap and ap_star).
    den_star = normalised_count(m)
    got2 = ev_rows.ranked_aps(m[:, 0], m[:, 1], lab, scores, (den, den_star))
    expected_star = average_precision(m, lab, scores, m)
    assert (np.isnan(expected) and np.isnan(got2[0])) or got2[0] == expected
    assert (np.isnan(expected_star) and np.isnan(got2[1])) or got2[1] == expected_star


def test_tabulated_overlap_context_matches_plain_context():
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    pair = load_dataset("embedded")[16]  # a non-planar scene
    f1, f2 = pair_features(pair, FeatureConfig(max_keypoints=KPTS))
    kw = dict(kpts1=f1.kpts, kpts2=f2.kpts, shapes1=f1.shapes, shapes2=f2.shapes, depth=10)
    plain = BlobContext(f1.desc, f2.desc, **kw)
    tables = (ev_overlap.overlap_table(f1, None), ev_overlap.overlap_table(f2, None))
    ctx = ev_overlap.TabulatedContext(f1.desc, f2.desc, overlap_tables=tables, **kw)
    for key in [(10, "cup", 5), (1, "cap", 1)]:
        m, d = plain.candidates(*key)
        for t_o, kind in GRID_T_O:
            for ratio in RATIOS:
                a, b = rank_candidates(plain, m, d, ratio=ratio, t_o=t_o, t_o_kind=kind)
                a2, b2 = rank_candidates(ctx, m, d, ratio=ratio, t_o=t_o, t_o_kind=kind)
                np.testing.assert_array_equal(a, a2)
                np.testing.assert_array_equal(b, b2)


@pytest.mark.parametrize("index", [0, 19])  # planar, depth
def test_unit_rows_equal_the_pipeline(index):
    from ctxmatch_lib.datasets import load_dataset
    from ctxmatch_lib.features import FeatureConfig

    pair = load_dataset("embedded")[index]
    presets = ["paper-best", "baseline", "paper-best-overlap"]
    unit = sweep.plan_sweep("embedded", blobs=presets, pairs=[pair.pair_id], filters=("th",),
                            models=("none", "1sac"), max_keypoints=KPTS)[0]
    rows = sweep.run_unit(unit, cache_dir=False)
    ev = evaluate_pair(pair, features=FeatureConfig(max_keypoints=KPTS), blobs=presets, filters=("th",),
                       models=("none", "1sac"))
    ref = pd.DataFrame(ev.rows)
    cols = ["method", "model", "precision", "recall", "recall_star", "ap", "correct", "correct_norm", "output",
            "failure", "n_candidates", "n_gt", "n_gt_star"]
    pd.testing.assert_frame_equal(rows[cols].reset_index(drop=True), ref[cols].reset_index(drop=True),
                                  check_dtype=False)
    # The blob-only fast path gives the same numbers as the general path.
    fast = sweep.run_unit(sweep.plan_sweep("embedded", blobs=presets, pairs=[pair.pair_id],
                                           max_keypoints=KPTS)[0], cache_dir=False)
    slow = rows[(rows.method == "blob") & (rows.model == "none")]
    pd.testing.assert_frame_equal(_numbers(fast).reset_index(drop=True), _numbers(slow).reset_index(drop=True))


# ---------------------------------------------------------------------------------------- the sweep


def test_sweep_rows_are_complete_and_unique(serial):
    _, df = serial
    assert list(df.columns) == list(sweep.SWEEP_COLUMNS)
    assert len(df) == 3 * len(SMALL_GRID)
    assert not df.duplicated(KEYS).any()
    assert df["ap"].between(0, 1).all()
    maps = blob_map(df)
    assert len(maps) == len(SMALL_GRID) and (maps["pairs"] == 3).all()
    mat = heatmap_matrix(maps)
    assert mat.shape == (6, 90) and np.isfinite(mat.to_numpy()).all()
    assert list(mat.index[:2]) == [("1∪", 1), ("3∩", 3)]


def test_cache_hits(serial, tmp_path, monkeypatch):
    cache, ref = serial
    for sub in ("results", "candidates", "overlap"):
        assert any((cache / sub).iterdir()), sub
    # Rerun: every unit is a cached part, nothing is recomputed.
    monkeypatch.setattr(ev_run, "run_unit", lambda *a, **k: pytest.fail("a cached unit was recomputed"))
    again = sweep.run_sweep("embedded", cache_dir=cache, out=tmp_path / "s.parquet", **KW)
    pd.testing.assert_frame_equal(again, ref)
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "s.parquet"), ref)
    monkeypatch.undo()
    # Results dropped, intermediates kept: candidate sets and overlap tables come from the cache and the
    # rows are identical; the context is built only for the ratios (no candidates() call).
    for p in (cache / "results").iterdir():
        p.unlink()
    calls = []
    orig = ev_overlap.TabulatedContext.candidates
    monkeypatch.setattr(ev_overlap.TabulatedContext, "candidates", lambda self, *a: calls.append(a) or orig(self, *a))
    monkeypatch.setattr(ev_overlap, "ellipse_overlap_error", lambda *a, **k: pytest.fail("overlap recomputed"))
    rebuilt = sweep.run_sweep("embedded", cache_dir=cache, **KW)
    assert calls == []
    pd.testing.assert_frame_equal(_numbers(rebuilt), _numbers(ref))


def test_filter_masks_are_cached(tmp_path, monkeypatch):
    kw = dict(blobs=["paper-best", "baseline"], pairs=2, max_keypoints=KPTS, filters=("th",), progress=False)
    first = sweep.run_sweep("embedded", cache_dir=tmp_path, **kw)
    assert any((tmp_path / "filters").iterdir())
    monkeypatch.setattr(ev_unit, "run_filter", lambda *a, **k: pytest.fail("filter recomputed"))
    again = sweep.run_sweep("embedded", cache_dir=tmp_path, recompute=True, **kw)
    pd.testing.assert_frame_equal(_numbers(again), _numbers(first))


def test_resume_after_interrupt_in_process(serial, tmp_path, monkeypatch):
    _, ref = serial
    done = []
    orig = ev_run.write_parquet_atomic

    def stop_after_two(df, path, metadata=None):
        if len(done) == 2:
            raise KeyboardInterrupt
        done.append(path)
        return orig(df, path, metadata)

    monkeypatch.setattr(ev_run, "write_parquet_atomic", stop_after_two)
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep("embedded", cache_dir=tmp_path, **KW)
    monkeypatch.undo()
    assert len(list((tmp_path / "results").glob("*.parquet"))) == 2
    resumed = sweep.run_sweep("embedded", cache_dir=tmp_path, **KW)
    pd.testing.assert_frame_equal(_numbers(resumed), _numbers(ref))


def test_resume_after_sigkill(serial, tmp_path, kill_after_first_part):
    """A real kill -9 of `ctxmatch sweep` in the middle of a run; the rerun completes it exactly."""
    _, ref = serial
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    code = ("import pickle, sys; from ctxmatch_lib.evaluation import run_sweep; "
            "run_sweep('embedded', cache_dir=sys.argv[1], **pickle.loads(bytes.fromhex(sys.argv[2])))")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path), pickle.dumps(KW).hex()], env=env)
    n_parts = kill_after_first_part(proc, tmp_path / "results", 0.05)
    assert 1 <= n_parts <= 3
    resumed = sweep.run_sweep("embedded", cache_dir=tmp_path, **KW)
    assert not resumed.duplicated(KEYS).any()
    pd.testing.assert_frame_equal(_numbers(resumed), _numbers(ref))


def test_joblib_equals_serial(serial, tmp_path):
    _, ref = serial
    par = sweep.run_sweep("embedded", cache_dir=tmp_path, n_jobs=2, **KW)
    pd.testing.assert_frame_equal(_numbers(par), _numbers(ref))


def test_dask_local_cluster_equals_serial(serial, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, ref = serial
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        par = sweep.run_sweep("embedded", cache_dir=tmp_path, dask=lc.scheduler_address, **KW)
    pd.testing.assert_frame_equal(_numbers(par), _numbers(ref))


# -------------------------------------------------------------------------------------- bad arguments


@pytest.mark.parametrize("kwargs, match", [
    (dict(n_jobs=0), "n_jobs"),
    (dict(n_jobs=2, dask="tcp://localhost:8786"), "not both"),
    (dict(dask="localhost"), "scheduler address"),
    (dict(blobs="best"), "unknown blob setup 'best'"),
    (dict(features="no-such-preset"), "unknown feature preset"),
    (dict(filters=("nope",)), "unknown filter 'nope'"),
    (dict(models=("7pt",)), "unknown model '7pt'"),
    (dict(pairs=0), "pairs must be a positive"),
    (dict(pairs=["no/such-pair"]), "unknown pair ids"),
    (dict(gt_method="Z"), "gt_method"),
    (dict(gt_threshold=-1.0), "gt_threshold"),
    (dict(filter_params={"dtm": {}}), "filter_params"),
    (dict(out="x.csv"), "parquet"),
])
def test_bad_arguments(kwargs, match, tmp_path):
    with pytest.raises(ValueError, match=match):
        sweep.run_sweep("embedded", cache_dir=tmp_path, progress=False, **kwargs)


def test_bad_dataset():
    with pytest.raises(ValueError, match="name_or_path"):
        sweep.plan_sweep("no-such-dataset")


def test_cli_errors_and_run(tmp_path, capsys):
    from ctxmatch_lib.cli import main

    assert main(["sweep", "--features", "sosnet", "--cache-dir", str(tmp_path)]) == 2
    assert "unknown feature preset" in capsys.readouterr().err
    assert main(["sweep", "--jobs", "0", "--cache-dir", str(tmp_path)]) == 2
    assert "--jobs must be a positive number" in capsys.readouterr().err
    assert main(["sweep", "--out", "x.csv"]) == 2
    assert main(["sweep", "--gt-threshold", "-1", "--cache-dir", str(tmp_path)]) == 2
    assert "--gt-threshold must be a positive number" in capsys.readouterr().err
    assert main(["sweep", "--model-threshold", "0", "--cache-dir", str(tmp_path)]) == 2
    assert "--model-threshold must be a positive number" in capsys.readouterr().err
    out = tmp_path / "s.parquet"
    assert main(["sweep", "--blob", "paper-best,baseline", "--pairs", "2", "--max-keypoints", str(KPTS),
                 "--cache-dir", str(tmp_path), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    # Named presets keep their names in the blob column, as in ctxmatch eval.
    assert "2 pairs, 4 rows" in printed and "paper-best" in printed and "baseline" in printed
    assert len(pd.read_parquet(out)) == 4


def test_source_digest_ignores_documentation_not_code(tmp_path):
    from ctxmatch_lib.evaluation.cache import _code_bytes

    def code(text):
        path = tmp_path / "m.py"
        path.write_text(text)
        return _code_bytes(path)

    base = code('"""Module."""\n\ndef f(x=1):\n    """Doc."""\n    return x + 1  # one\n')
    assert code('"""Module, reworded."""\n\n\ndef f(x=1):\n    """Other doc."""\n    return x + 1\n') == base
    assert code('"""Module."""\n\ndef f(x=2):\n    """Doc."""\n    return x + 1\n') != base  # a default
    assert code('def f(x=1):\n    return x + 1\n') == base
    assert code('def f(x=1):\n    """Doc."""\n') != base  # a docstring-only body is not the code above


@pytest.mark.parametrize("value, expected", [("paper", 1500), ("dense", 8000), ("1200", 1200), (0, 0), (None, None)])
def test_keypoint_budgets(value, expected):
    from ctxmatch_lib.features import keypoint_budget

    assert keypoint_budget(value) == expected


@pytest.mark.parametrize("value", ["sparse", -1, 1.5, True])
def test_keypoint_budget_errors_name_the_argument(value):
    from ctxmatch_lib.evaluation import plan_units, select_pairs

    with pytest.raises(ValueError, match="max_keypoints"):
        plan_units(select_pairs("embedded")[:1], max_keypoints=value)


def test_units_without_filters_keep_their_key_when_a_filter_changes():
    from ctxmatch_lib.evaluation import cache as ev_cache
    from ctxmatch_lib.evaluation import plan_units, select_pairs

    pairs = select_pairs("embedded")[:1]
    blob_only = plan_units(pairs, filters=())[0]
    filtered = plan_units(pairs, filters=("th",))[0]
    assert blob_only.salt == ev_cache.source_digest(())
    assert filtered.salt == ev_cache.source_digest(("th",)) != blob_only.salt


def _edited_copy(tmp_path, rel: str, old: str, new: str):
    """A copy of the package with one code edit in ``rel``."""
    import shutil

    import ctxmatch_lib

    src = Path(ctxmatch_lib.__file__).parent
    dst = tmp_path / "ctxmatch_lib"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__"))
    path = dst / rel
    text = path.read_text()
    assert old in text, (rel, old)
    path.write_text(text.replace(old, new, 1))
    return dst


@pytest.mark.parametrize("rel", ["io/export.py", "match.py", "cache.py", "cli/eval.py", "report/tables.py",
                                 "plots/eval.py", "io/interop.py"])
def test_editing_code_that_computes_no_number_keeps_every_key(tmp_path, rel):
    """The key of a unit follows the code it runs: a code edit (not a docstring) in export, the cache folder's
    module, the command line, plots, reports or interop keeps every key."""
    from ctxmatch_lib.evaluation.cache import source_digest

    root = _edited_copy(tmp_path, rel, "\n\n\n", "\n\n_EDITED_CONSTANT = 1\n\n\n")
    for filters in [(), ("th",), ("dtm", "adalam")]:
        assert source_digest(filters, package_root=root) == source_digest(filters), filters


def test_editing_a_filter_renews_the_keys_of_its_units_only(tmp_path):
    from ctxmatch_lib.evaluation.cache import source_digest

    root = _edited_copy(tmp_path, "filters/th.py", "\n\n\n", "\n\n_EDITED_CONSTANT = 1\n\n\n")
    assert source_digest(("th",), package_root=root) != source_digest(("th",))
    assert source_digest(("dtm", "th"), package_root=root) != source_digest(("dtm", "th"))
    assert source_digest((), package_root=root) == source_digest(())
    assert source_digest(("dtm",), package_root=root) == source_digest(("dtm",))
    # Code every unit runs (blob matching) renews every key.
    root2 = _edited_copy(tmp_path / "b", "blob/core.py", "\n\n\n", "\n\n_EDITED_CONSTANT = 1\n\n\n")
    for filters in [(), ("th",), ("dtm",)]:
        assert source_digest(filters, package_root=root2) != source_digest(filters), filters


def test_every_candidate_set_counts_the_context_build_once():
    """Each candidate key's seconds hold the context's build once (a standalone blob_matching would build it),
    not twice for the first key and never for the others."""
    from ctxmatch_lib.evaluation.cache import candidate_sets

    class Instant:
        def candidates(self, *key):
            return np.zeros((1, 2), np.int64), np.zeros(1)

    built = 100.0  # a declared build time, far above what a call here takes
    out = candidate_sets(lambda: (Instant(), built), [(10, "cup", 5), (3, "cap", 1)], None, "f")
    for _, _, seconds in out.values():
        assert built <= seconds < 2 * built
