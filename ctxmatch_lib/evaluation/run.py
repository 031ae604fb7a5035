"""Running the engine's units (:func:`run_units`): in this process, on local workers (joblib) or on Dask."""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from .._numerics.extras import require
from ..cache import write_parquet_atomic
from .cache import engine_cache
from .plan import SweepUnit, keyed
from .rows import frame
from .unit import run_unit

__all__ = ["check_runner", "run_units"]


def _unit_task(unit, cache_dir, feature_cache_dir):
    """What a worker runs: the rows of one unit (the driver writes the part file)."""
    return unit.key, run_unit(unit, cache_dir=cache_dir, feature_cache_dir=feature_cache_dir)


def _distributed():
    return require("distributed", "dask", "running units on a Dask cluster")


def _connect_dask(dask):
    Client = _distributed().Client
    if isinstance(dask, Client):
        return dask, False
    if not isinstance(dask, str) or "://" not in dask:
        raise ValueError(f"dask must be a scheduler address like 'tcp://host:8786' or a distributed.Client, "
                         f"got {dask!r}")
    try:
        return Client(dask, timeout="20s"), True
    except OSError as exc:
        raise ConnectionError(f"cannot reach the Dask scheduler at {dask}: {exc}") from exc


def check_runner(n_jobs, dask):
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, (int, np.integer)) or n_jobs == 0 or n_jobs < -1:
        raise ValueError(f"n_jobs must be a positive int or -1, got {n_jobs!r}")
    if dask is not None and n_jobs != 1:
        raise ValueError("give either n_jobs (local processes) or dask (a cluster), not both")


def named_rows(df, unit: SweepUnit):
    """The unit's rows with its ``features_name`` and ``blob_names`` (a part may come from a unit named
    otherwise)."""
    if len(df) and (df["features"] != unit.features_name).any():
        df = df.assign(features=unit.features_name)
    if unit.blob_names:
        labels = {c.label: name for c, name in zip(unit.blobs, unit.blob_names)}
        df = df.assign(blob=df["blob"].map(labels).fillna(df["blob"]))
    return df


def _dispatch(todo, n_jobs, dask, cache_arg, feature_cache_dir, bar, done) -> None:
    """Run the units ``todo`` on Dask, on joblib workers or here, calling ``done(key, rows)`` for each."""
    if todo and dask is not None:
        client, own = _connect_dask(dask)
        try:
            as_completed = _distributed().as_completed
            bar.set_postfix_str(f"{len(todo)} pairs on the cluster", refresh=True)
            futures = [client.submit(_unit_task, u, cache_arg, feature_cache_dir, pure=False) for u in todo]
            for fut in as_completed(futures):
                done(*fut.result())
        finally:
            if own:
                client.close()
    elif todo and n_jobs != 1 and len(todo) > 1:
        from joblib import Parallel, delayed

        bar.set_postfix_str(f"{len(todo)} pairs on {n_jobs if n_jobs > 0 else 'all'} workers", refresh=True)
        par = Parallel(n_jobs=n_jobs, backend="loky", return_as="generator_unordered")
        for key, df in par(delayed(_unit_task)(u, cache_arg, feature_cache_dir) for u in todo):
            done(key, df)
    else:
        for u in todo:
            bar.set_postfix_str(u.label(), refresh=True)
            done(*_unit_task(u, cache_arg, feature_cache_dir))


def run_units(units: Sequence[SweepUnit], *, cache_dir=None, feature_cache_dir=None, n_jobs: int = 1, dask=None,
              progress: bool = True, recompute: bool = False, desc: str = "ctxmatch sweep"):
    """Run (or resume) work units and return their rows, in the units' order whatever the runner.

    Each finished unit is one Parquet part under ``<cache_dir>/results``, written atomically; a unit with an
    ``error`` gives a ``RuntimeWarning`` and no part (the next run retries it).

    Parameters
    ----------
    units : sequence of SweepUnit
        From :func:`~ctxmatch_lib.evaluation.plan.plan_sweep` or ``plan_units``.
    cache_dir : path, None or False
        The evaluation cache (default ``ctxmatch_lib.cache.cache_dir("sweep")``); ``False``: none.
    feature_cache_dir : path, optional
        The feature cache (default: that of :mod:`ctxmatch_lib.features`).
    n_jobs, dask, progress, recompute
        As in :func:`~ctxmatch_lib.evaluation.frontends.run_sweep`; ``desc`` is the progress bar's title.

    Returns
    -------
    pandas.DataFrame
        :data:`~ctxmatch_lib.evaluation.rows.SWEEP_COLUMNS`; ``attrs["units"]`` and
        ``attrs["units_computed"]`` count the distinct units and those this call computed.
    """
    import pandas as pd
    from tqdm.auto import tqdm

    check_runner(n_jobs, dask)
    units = keyed(list(units))
    if not units:
        return frame([])
    use_cache = cache_dir is not False
    if use_cache:
        cache = engine_cache(cache_dir)
        parts_dir = cache / "results"
        parts_dir.mkdir(parents=True, exist_ok=True)
        part = {u.key: parts_dir / f"{u.key}.parquet" for u in units}
        todo = list({u.key: u for u in units if recompute or not part[u.key].is_file()}.values())
        cache_arg = cache if cache_dir is not None else None
    else:
        part, cache_arg = {}, False
        todo = list({u.key: u for u in units}.values())
    n_total = len({u.key for u in units})
    in_memory: dict = {}
    failed: list[str] = []

    bar = tqdm(total=n_total, initial=n_total - len(todo), desc=desc, unit="pair", disable=not progress,
               dynamic_ncols=True, smoothing=0.1)

    def done(key, df):
        errors = [e for e in dict.fromkeys(df["error"]) if e]
        if errors or not use_cache:
            in_memory[key] = df
        else:
            write_parquet_atomic(df, part[key])
        if errors:
            pid = f"{df['dataset'].iloc[0]}/{df['pair_id'].iloc[0]}" if len(df) else key
            for e in errors:
                failed.append(f"{pid}: {e}")
                msg = f"pair {pid}: {e}"
                if progress:
                    bar.write(f"warning: {msg}")
                warnings.warn(msg, RuntimeWarning, stacklevel=4)
        bar.update(1)

    try:
        _dispatch(todo, n_jobs, dask, cache_arg, feature_cache_dir, bar, done)
    finally:
        bar.set_postfix_str("", refresh=False)
        bar.close()

    frames = [named_rows(in_memory[u.key] if u.key in in_memory else pd.read_parquet(part[u.key]), u) for u in units]
    out = pd.concat(frames, ignore_index=True)
    out.attrs.update(units=n_total, units_computed=len(todo))
    return out
