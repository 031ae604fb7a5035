import importlib.util
import os
import signal
import time
from pathlib import Path

import matplotlib
import pytest
from hypothesis import HealthCheck, settings

matplotlib.use("Agg")

# One cache of compiled kernels for the whole run, shared by the workers and by every subprocess a test starts:
# a test that points CTXMATCH_CACHE at a fresh folder reuses the machine code instead of compiling it again
# (the tests of where numba caches unset the variable themselves).
if "NUMBA_CACHE_DIR" not in os.environ:
    from ctxmatch_lib.cache import cache_dir

    os.environ["NUMBA_CACHE_DIR"] = str(cache_dir("numba"))

# The longest files first: the suite runs a file per worker (pytest-xdist --dist loadfile), and a long file
# started last would keep one worker busy after the other has finished.
_LONG_FIRST = ("test_blas_kernels.py", "fig_blob_heatmap.ipynb", "test_docs.py", "fig_geometry.ipynb",
               "fig_gt_methods.ipynb", "test_sweep.py", "test_match_cli.py", "test_datasets_calibrated.py",
               "fig_agreement.ipynb", "test_notebooks.py", "test_jupyterlab.py", "test_eval.py",
               "fig_match_examples.ipynb")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(_LONG_FIRST)}
    items.sort(key=lambda item: rank.get(Path(str(item.fspath)).name, len(rank)))

# Deterministic property tests in CI: the same examples every run.
settings.register_profile("ci", derandomize=True, deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session")
def data_root():
    """The shared real data (CTXMATCH_DATA); skips the test with a reason when it is absent."""
    from ctxmatch_lib.cache import data_root as _root

    root = _root()
    if root is None:
        pytest.skip("CTXMATCH_DATA is not set or not a folder: real-data test skipped")
    return root


@pytest.fixture(scope="session")
def load_benchmark():
    """``load_benchmark(name)`` imports ``benchmarks/<name>.py`` by path (the folder is not a package)."""
    root = Path(__file__).resolve().parents[1] / "benchmarks"

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, root / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


@pytest.fixture(scope="session")
def kill_after_first_part():
    """``kill(proc, parts, poll)``: SIGKILL the process ``proc`` once a ``*.parquet`` part stands in the folder
    ``parts`` (or when it has ended, or after 120 s, looking every ``poll`` seconds); returns how many parts
    it left there."""

    def kill(proc, parts: Path, poll: float) -> int:
        deadline = time.time() + 120
        while time.time() < deadline and proc.poll() is None:
            if parts.is_dir() and len(list(parts.glob("*.parquet"))) >= 1:
                break
            time.sleep(poll)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return len(list(parts.glob("*.parquet")))

    return kill


@pytest.fixture(scope="module")
def bench(load_benchmark):
    """``benchmarks/bench_filters_ref.py``, the reference-filter benchmark, once per test module."""
    return load_benchmark("bench_filters_ref")
