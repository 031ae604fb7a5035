"""The evaluation cache: deterministic keys and atomic files (hloc's skip-what-exists, per unit).

Every cached file is named by a SHA-1 of what its content depends on (:func:`digest`), written to a
temporary name and moved into place, so a run killed at any moment leaves whole files only and a rerun
skips what exists. Layout under ``ctxmatch_lib.cache.cache_dir("sweep")`` (features are cached by
:mod:`ctxmatch_lib.features` in its own folder)::

    results/<unit-hash>.parquet      one part per finished unit (rows of one pair)
    candidates/<pair-hash>.npz       candidate sets G (matches, distances) per (f, ∩/∪, f') of a pair
    overlap/<image-hash>.npz         overlap errors of every pair of keypoints of an image whose patches
                                     can overlap (FGINN by overlap looks them up instead of recomputing)
    filters/<hash>.npz               filter masks per blob setup, per (pair, filter, filter parameters)
"""

from __future__ import annotations

import ast
import functools
import hashlib
import time
from pathlib import Path

import numpy as np

from ..cache import atomic_path
from ..datasets.base import Pair
from ..features import Features

__all__ = ["FORMAT", "digest", "pair_digest", "features_digest", "source_digest", "save_npz", "load_npz",
           "engine_cache", "candidate_sets"]

# Bump when the rows or the cached intermediates change meaning: old parts and caches are then ignored.
FORMAT = 4  # 4: the geometry columns and the OpenCV matcher rows (issue 30)


def digest(*parts) -> str:
    h = hashlib.sha1()
    for p in parts:
        if isinstance(p, np.ndarray):
            h.update(repr((p.dtype.str, p.shape)).encode())
            h.update(np.ascontiguousarray(p).tobytes())
        elif isinstance(p, (bytes, bytearray)):
            h.update(p)
        else:
            h.update(repr(p).encode())
        h.update(b"\x00")
    return h.hexdigest()


def pair_digest(pair: Pair) -> str:
    """What a pair's rows depend on besides the sweep settings: both image files and the ground truth."""
    gt = pair.gt
    fields = [type(gt).__name__]
    for name in ("H", "F", "pts1", "pts2", "flow12", "flow21"):
        value = getattr(gt, name, None)
        fields.append(name if value is None else np.asarray(value))
    return digest(Path(pair.image1).read_bytes(), Path(pair.image2).read_bytes(), pair.kind, *fields)


def features_digest(*feats: Features) -> str:
    # The metric enters only when it is not L2, so the L2 digests (and cached candidate sets) are unchanged.
    extra = [f.metric for f in feats if f.metric != "l2"]
    return digest(*[a for f in feats for a in (f.kpts, f.shapes, f.desc)], *extra)


@functools.lru_cache(maxsize=2)
def source_digest(filters: bool = True) -> str:
    """SHA-1 of the library source files and shipped models that produce evaluation numbers (all of
    ``ctxmatch_lib`` but ``plots/``, ``cli/``, the report modules (``report``, ``report_blob``, ``report_paper``,
    ``gt_compare``, which read the engine's rows) and the faces ``evalcache.py`` and ``sweep.py``).

    Python files enter by their syntax tree without docstrings and comments: a documentation edit keeps the
    cache, any code edit (a constant, a default) renews it. ``filters=False`` also leaves out ``filters/`` and
    ``dtm/`` (the spatial filters, which nothing else in the library imports): the key of units that run no
    filter (the blob-matching sweeps), so that editing a filter keeps them."""
    root = Path(__file__).resolve().parent.parent
    # The faces and the report layer compute no numbers.
    skip = {root / name for name in ("report.py", "report_blob.py", "report_paper.py", "gt_compare.py", "evalcache.py",
                                     "sweep.py")}
    h = hashlib.sha1()
    # Shipped models (LMR's trees, the learned filters' and the stand-in descriptors' weights, all .npz) produce
    # numbers too.
    files = [*root.rglob("*.py"), *root.rglob("*.npz")]
    for path in sorted(files):
        rel = path.relative_to(root)
        if path in skip or rel.parts[0] in ("plots", "cli") or (not filters and rel.parts[0] in ("filters", "dtm")):
            continue
        h.update(str(rel).encode())
        h.update(_code_bytes(path) if path.suffix == ".py" else path.read_bytes())
    return h.hexdigest()


def _code_bytes(path: Path) -> bytes:
    """The code of a Python file without its docstrings, comments and layout (its syntax tree, docstrings
    removed), so that editing documentation keeps the cached evaluation rows."""
    tree = ast.parse(path.read_bytes(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def save_npz(path: Path, arrays: dict) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def load_npz(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception:  # a foreign or damaged file is a miss; it is overwritten
        return None


def engine_cache(cache_dir) -> Path:
    if cache_dir is None:
        from ..cache import cache_dir as default_cache_dir

        return default_cache_dir("sweep")
    path = Path(cache_dir)
    path.mkdir(parents=True, exist_ok=True)
    return path


def candidate_sets(ctx_factory, keys, cache: Path | None, feats_digest: str, salt: str = ""):
    """G per candidate key, with the seconds it took (descriptor distances + the set), from the cache or
    from the context (then cached). ``ctx_factory()`` returns the context and the seconds its building took."""
    path = cache / "candidates" / f"{digest(FORMAT, feats_digest, salt)}.npz" if cache is not None else None
    stored = (load_npz(path) if path is not None else None) or {}
    out, added = {}, False
    for key in keys:
        name = "{}_{}_{}".format(*key)
        if f"m_{name}" in stored:
            out[key] = (stored[f"m_{name}"].astype(np.int64), stored[f"d_{name}"], float(stored[f"t_{name}"]))
            continue
        ctx, t_ctx = ctx_factory()
        t0 = time.perf_counter()
        matches, dist = ctx.candidates(*key)
        # The context (all descriptor distances) serves every key; each key's time includes building it once,
        # as a standalone blob_matching call would (it was counted twice for the first key and not at all
        # for the others before).
        t = time.perf_counter() - t0 + t_ctx
        out[key] = (matches, dist, t)
        stored[f"m_{name}"] = matches.astype(np.int32)
        stored[f"d_{name}"] = dist
        stored[f"t_{name}"] = np.float64(t)
        added = True
    if added and path is not None:
        save_npz(path, stored)
    return out
