"""``ctxmatch figures``: run the figure notebooks through papermill, quietly, with one status line whose time
left comes from the previous run's durations (``executed/durations.json``). ``--jobs`` notebooks run at once;
one that reads another's cached results (:data:`AFTER`) starts after it, the rest in :data:`PRIORITY` order.
Figures carry no clock (:func:`ctxmatch_lib.plots.base.provenance`), so a rerun with the same numbers writes
the same bytes."""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

#: Arguments of the kernels: no kernel log (a cell's error still reaches papermill), and no "IProgress not
#: found" warning from tqdm.auto's text-bar fallback.
KERNEL_ARGUMENTS = [
    "--IPKernelApp.log_level=CRITICAL",
    "--IPKernelApp.exec_lines=import warnings; warnings.filterwarnings('ignore', message='IProgress not found')",
]


#: Notebook -> the notebooks whose cached results (features, filter masks, sweeps) it reads; it starts after
#: those of them that are selected.
AFTER = {
    "fig_blob_bands": ("fig_agreement",),
    "fig_blob_heatmap": ("fig_blob_bands",),
    "fig_geometry": ("fig_agreement", "fig_gt_calibrated"),
    "fig_gt_methods": ("fig_agreement",),
    "fig_inlier_hist": ("fig_agreement",),
    "fig_match_examples": ("fig_agreement",),
    "fig_pr_scatter": ("fig_agreement", "fig_geometry"),
    "tables": ("fig_agreement",),
}

#: Start order: the long evaluation, small independent ones beside it, then the rest longest first; unlisted last.
PRIORITY = ("fig_agreement", "fig_gt_calibrated", "fig_dtm_steps", "fig_boundary", "fig_blob_toy", "fig_blob_bands",
            "fig_geometry", "fig_gt_methods", "fig_match_examples", "fig_pr_scatter", "tables", "fig_inlier_hist",
            "fig_blob_heatmap")


def add_parser(sub) -> None:
    p = sub.add_parser("figures", help="regenerate the paper's figures and tables by running the notebooks",
                       description="Execute notebooks/*.ipynb with papermill; figures (PNG + PDF) and tables go to "
                                   "figures/ of the checkout, replacing the committed ones, the executed notebooks "
                                   "and the running times to figures/executed/ (untracked). A rerun that computes "
                                   "the same numbers writes the same bytes.")
    p.add_argument("--params", choices=["default", "paper"], default="default",
                   help="default: the embedded offline dataset (minutes); paper: notebooks/params/<stem>.yaml, "
                        "real data under CTXMATCH_DATA")
    p.add_argument("--only", default="", help="comma-separated notebook stems (default: all)")
    p.add_argument("--output", type=Path, default=None,
                   help="figure folder (default: figures/ of the checkout; figures/paper/ with --params paper)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE",
                   help="set a notebook parameter (VALUE is read as YAML: 2, [a, b], null), after --params; "
                        "repeatable, given to every notebook run that has the parameter")
    p.add_argument("--jobs", type=int, default=2,
                   help="notebooks run at once (default 2; each evaluation runs its own worker processes too); "
                        "1 runs them one after the other. The figures do not depend on it")
    p.add_argument("--no-progress", action="store_true", help="no status line, only one line per notebook")
    p.set_defaults(func=run)


def _parse_params(items) -> dict:
    import yaml

    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key.strip().isidentifier():
            raise ValueError(f"--param must be KEY=VALUE with KEY a parameter name, got {item!r}")
        out[key.strip()] = yaml.safe_load(value) if value.strip() else ""
    return out


def _fmt(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 60}:{seconds % 60:02d}" if seconds >= 60 else f"{seconds} s"


class _Status:
    """One status line, refreshed every second (30 s off a terminal): notebooks in progress, time elapsed, and
    the time left when every remaining notebook has a previous duration, else the number done."""

    def __init__(self, stems, expected: dict, enabled: bool, jobs: int = 1):
        self.stems, self.expected, self.done = list(stems), dict(expected), {}
        self.running: dict[str, float] = {}  # stem -> start time
        self.jobs = max(1, int(jobs))
        self.start = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.enabled = enabled
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self._width = 0

    def _left(self, now: float) -> float | None:
        todo = [s for s in self.stems if s not in self.done]
        if not todo:
            return 0.0
        # Notebooks differ by orders of magnitude: only their own previous durations estimate them.
        if any(s not in self.expected for s in todo):
            return None
        rest = {s: self.expected[s] - min(now - self.running[s], self.expected[s]) if s in self.running
                else self.expected[s] for s in todo}
        # The work left shared by the slots, at least the longest notebook left.
        return max(max(rest.values()), sum(rest.values()) / self.jobs)

    def line(self) -> str:
        now = time.perf_counter()
        with self._lock:
            running = dict(self.running)
        k = len(self.done) + len(running)
        parts = [f"[{k}/{len(self.stems)}] " + ", ".join(
            f"{stem} {_fmt(now - t0)}" + (f" (last run {_fmt(self.expected[stem])})" if stem in self.expected else "")
            for stem, t0 in running.items())]
        left = self._left(now)
        elapsed = f"{_fmt(now - self.start)} elapsed"
        if left is not None:
            parts.append(f"{elapsed}, about {_fmt(left)} left")
        else:
            parts.append(f"{elapsed}, {len(self.done)} of {len(self.stems)} notebooks done")
        return " | ".join(parts)

    def _show(self) -> None:
        text = self.line()
        if self.tty:
            sys.stderr.write("\r" + text + " " * (self._width - len(text)))
            self._width = len(text)
        else:
            sys.stderr.write(text + "\n")
        sys.stderr.flush()

    def _loop(self) -> None:
        period = 1.0 if self.tty else 30.0
        while not self._stop.wait(period):
            self._show()

    def begin(self, stem: str) -> None:
        with self._lock:
            self.running[stem] = time.perf_counter()
        if self.enabled:
            self._show()
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, daemon=True)
                self._thread.start()

    def end(self, stem: str, message) -> float:
        """Close ``stem``'s line with ``message(took)``, ``took`` its running time in seconds."""
        with self._lock:
            took = time.perf_counter() - self.running.pop(stem)
            self.done[stem] = took
        if self.enabled and self.tty:
            sys.stderr.write("\r" + " " * self._width + "\r")
            self._width = 0
        print(message(took), flush=True)
        return took

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


def _execute(src: str, out: str, params: dict, cwd: str) -> str | None:
    """Run one notebook (in a worker process); ``None``, or why it failed (its last error line)."""
    import papermill as pm

    try:
        pm.execute_notebook(src, out, parameters=params, cwd=cwd, progress_bar=False, kernel_name="python3",
                            extra_arguments=KERNEL_ARGUMENTS)
    except Exception as exc:  # keep going: one broken notebook should not hide the others
        first = (str(exc).strip().splitlines() or [""])[-1][:200]
        return f"{type(exc).__name__}: {first}"  # may hold braces: never a format template
    return None


def _schedule(stems, jobs: int, start, finished) -> None:
    """Run ``stems``, at most ``jobs`` at once, in :data:`PRIORITY` order once their :data:`AFTER` notebooks are
    done (failed or not): ``start(stem)`` returns a future, ``finished(stem, future)`` is called on completion."""
    from concurrent.futures import FIRST_COMPLETED, wait

    rank = {stem: i for i, stem in enumerate(PRIORITY)}
    pending = sorted(stems, key=lambda s: (rank.get(s, len(rank)), s))
    running: dict = {}
    while pending or running:
        for stem in list(pending):
            if len(running) >= jobs:
                break
            if not any(dep in pending or dep in running.values() for dep in AFTER.get(stem, ())):
                pending.remove(stem)
                running[start(stem)] = stem
        done, _ = wait(list(running), return_when=FIRST_COMPLETED)
        for fut in done:
            finished(running.pop(fut), fut)


def output_dir(params: str, output, root: Path) -> Path:
    """Where the figures go: ``output``, else the checkout's ``figures/`` (``figures/paper/`` for ``paper``)."""
    if output is not None:
        return Path(output).resolve()
    return (root / "figures" / "paper" if params == "paper" else root / "figures").resolve()


def run(args: argparse.Namespace) -> int:
    import papermill as pm
    import yaml

    from ..cache import repo_root

    root = repo_root()
    if root is None or not (root / "notebooks").is_dir():
        print("ctxmatch figures needs the repository checkout (notebooks/ not found)", file=sys.stderr)
        return 2
    try:
        overrides = _parse_params(args.param)
    except ValueError as exc:
        print(f"ctxmatch figures: {exc}", file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"ctxmatch figures: --jobs must be a positive integer, got {args.jobs}", file=sys.stderr)
        return 2
    nb_dir = root / "notebooks"
    out_dir = output_dir(args.params, args.output, root)
    (out_dir / "executed").mkdir(parents=True, exist_ok=True)
    stems = sorted(p.stem for p in nb_dir.glob("*.ipynb"))
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = sorted(set(wanted) - set(stems))
        if unknown:
            print(f"unknown notebook(s): {', '.join(unknown)}; known: {', '.join(stems)}", file=sys.stderr)
            return 2
        stems = [s for s in stems if s in wanted]
    durations_file = out_dir / "executed" / "durations.json"
    try:
        durations = json.loads(durations_file.read_text())
        expected = {s: float(durations[args.params][s]) for s in stems if s in durations.get(args.params, {})}
    except (OSError, ValueError, TypeError, AttributeError):
        durations, expected = {}, {}
    if overrides:
        known = {stem: set(pm.inspect_notebook(str(nb_dir / f"{stem}.ipynb"))) for stem in stems}
        unused = sorted(k for k in overrides if not any(k in names for names in known.values()))
        if unused:
            print(f"ctxmatch figures: --param {', '.join(unused)}: no selected notebook has such a parameter "
                  f"(papermill --help-notebook notebooks/<stem>.ipynb lists them)", file=sys.stderr)
            return 2
    # One BLAS thread per kernel: OpenBLAS's float32 rounding, and so a figure's bytes, depends on the count.
    saved_env = {var: os.environ.get(var) for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    os.environ.update(dict.fromkeys(saved_env, "1"))
    status = _Status(stems, expected, enabled=not args.no_progress, jobs=args.jobs)
    failed = []

    def params_of(stem: str) -> dict:
        params = {"output_dir": str(out_dir)}
        if args.params == "paper":
            yml = nb_dir / "params" / f"{stem}.yaml"
            if yml.exists():
                params.update(yaml.safe_load(yml.read_text()) or {})
        params.update({k: v for k, v in overrides.items() if k in known[stem]})
        return params

    def start(stem: str):
        status.begin(stem)
        return pool.submit(_execute, str(nb_dir / f"{stem}.ipynb"), str(out_dir / "executed" / f"{stem}.ipynb"),
                           params_of(stem), str(nb_dir))

    def finished(stem: str, fut) -> None:
        try:
            why = fut.result()
        except Exception as exc:  # the worker process itself died
            why = f"{type(exc).__name__}: {exc}"
        if why is not None:
            failed.append(stem)
            status.end(stem, lambda took: f"{stem}: FAILED after {took:.1f} s ({why})")
        else:
            took = status.end(stem, lambda took: f"{stem}: ok in {took:.1f} s")
            durations.setdefault(args.params, {})[stem] = round(took, 1)

    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    try:
        # Fresh interpreters (spawn), not forks of this one and its status thread; they inherit the environment.
        with ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            _schedule(stems, args.jobs, start, finished)
    finally:
        status.close()
        for var, value in saved_env.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
    durations_file.write_text(json.dumps(durations, indent=1, sort_keys=True) + "\n")
    total = time.perf_counter() - status.start
    print(f"{len(stems) - len(failed)} of {len(stems)} notebooks ran in {_fmt(total)}; figures and tables in "
          f"{out_dir}, executed notebooks and running times in {out_dir / 'executed'}")
    if failed:
        print(f"{len(failed)} notebook(s) failed: {', '.join(failed)}; see {out_dir / 'executed'}", file=sys.stderr)
        return 1
    return 0
