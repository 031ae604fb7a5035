"""The evaluation cache: deterministic keys (SHA-1 of what a file depends on, :func:`digest`) and atomic files.

Layout under ``ctxmatch_lib.cache.cache_dir("sweep")``::

    results/<unit-hash>.parquet      one part per finished unit (rows of one pair)
    candidates/<pair-hash>.npz       candidate sets G per (f, ∩/∪, f') of a pair
    overlap/<image-hash>.npz         overlap errors of an image's keypoint pairs that may overlap
    filters/<hash>.npz               filter masks per (pair, filters, parameters), per blob setup
"""

from __future__ import annotations

import ast
import functools
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

from ..cache import atomic_path
from ..datasets.base import Pair
from ..features import Features

__all__ = ["FORMAT", "digest", "pair_digest", "features_digest", "source_digest", "save_npz", "load_npz",
           "engine_cache", "candidate_sets", "code_closure"]

# Bump when the rows or the cached intermediates change meaning: old parts and caches are then ignored.
FORMAT = 5


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
    # The metric enters only when it is not L2 (L2 digests match those without a metric).
    extra = [f.metric for f in feats if f.metric != "l2"]
    return digest(*[a for f in feats for a in (f.kpts, f.shapes, f.desc)], *extra)


#: Modules a unit's key never follows into: the front door and the filters' registry (they import
#: everything; a unit's key takes its filters one by one) and the cache folder's module (no numbers).
_KEY_CUTS = ("ctxmatch_lib", "ctxmatch_lib.filters", "ctxmatch_lib.cache")
#: The code every unit runs (with its imports).
_UNIT_ROOT = "ctxmatch_lib.evaluation.unit"
_PACKAGE_ROOT = Path(__file__).resolve().parent.parent


@functools.lru_cache(maxsize=4)
def _modules(root: Path = _PACKAGE_ROOT) -> dict[str, Path]:
    """The modules of the package at ``root``: ``{dotted name: path}``."""
    paths = {}
    for path in root.rglob("*.py"):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        paths[".".join(parts)] = path
    return paths


def _imports(name: str, paths: dict[str, Path]) -> set[str]:
    """The modules of ``paths`` that module ``name`` imports, read from its source (imports inside functions
    included)."""
    path = paths[name]
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    edges = set()
    for level, module, names in _source_facts(path.read_bytes())[0]:
        if level:
            base = package.split(".")[: len(package.split(".")) - level + 1]
            target = ".".join(base + ([module] if module else []))
        else:
            target = module
        edges.update(f"{target}.{a}" if f"{target}.{a}" in paths else target for a in names)
        if not names:  # import a.b
            edges.add(target)
    return {e for e in edges if e in paths and e != name}


def code_closure(roots, *, package_root: Path = _PACKAGE_ROOT) -> list[str]:
    """The library modules that ``roots`` run: the roots and everything they import, transitively, without
    entering :data:`_KEY_CUTS` (a root may be inside one)."""
    paths = _modules(package_root)
    seen, todo = set(), [r for r in roots if r in paths]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo.extend(e for e in _imports(name, paths) if e not in seen and e not in _KEY_CUTS)
    return sorted(seen)


def _filter_module(name: str) -> str | None:
    """The module that implements the registered filter ``name`` (a partial or a wrapper is unwrapped)."""
    from ..filters import FILTERS

    func = FILTERS.get(name)
    while func is not None and (hasattr(func, "__wrapped__") or isinstance(func, functools.partial)):
        func = func.func if isinstance(func, functools.partial) else func.__wrapped__
    return getattr(func, "__module__", None)


def source_digest(filters: tuple[str, ...] = (), *, package_root: Path = _PACKAGE_ROOT) -> str:
    """SHA-1 of the code a unit runs: the import closure (:func:`code_closure`) of the unit and its
    ``filters``, and the shipped ``.npz`` models in it; documentation edits keep the cache (:func:`_code_bytes`).
    A filter from outside the package (a user's, by import path) adds its own module's code, read anew at
    each call, so that editing it recomputes its rows."""
    outside = [_outside_code(m) for m in map(_filter_module, filters)
               if m is not None and not m.startswith(_PACKAGE_ROOT.name + ".")]
    inside = _package_digest(tuple(filters), Path(package_root))
    return digest(inside, *outside) if outside else inside


def _outside_code(module: str) -> bytes:
    """The syntax tree of a module from outside the package (:func:`_code_bytes`), or its name alone when it
    has no readable source file."""
    path = getattr(sys.modules.get(module), "__file__", None)
    try:
        return module.encode() + b"\0" + _code_bytes(Path(path))
    except (TypeError, OSError, SyntaxError, ValueError):
        return module.encode()


@functools.lru_cache(maxsize=64)
def _package_digest(filters: tuple[str, ...], root: Path) -> str:
    """:func:`source_digest` of the package's own code."""
    paths = _modules(root)
    modules = [_filter_module(n) for n in filters]
    closure = code_closure([_UNIT_ROOT, *(m for m in modules if m in paths)], package_root=root)
    h = hashlib.sha1()
    for name in closure:
        h.update(name.encode())
        h.update(_code_bytes(paths[name]))
    for name in modules:
        if name not in paths:
            h.update(repr(name).encode())
    packages = {paths[name].parent for name in closure}
    for path in sorted(root.rglob("*.npz")):
        if any(folder in path.parents for folder in packages):
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def _code_bytes(path: Path) -> bytes:
    """The syntax tree of a Python file without docstrings, comments and layout, dumped."""
    return _dumped(path.read_bytes())


@functools.lru_cache(maxsize=1024)
def _dumped(source: bytes) -> bytes:
    return ast.dump(_source_facts(source)[1]).encode()


@functools.lru_cache(maxsize=1024)
def _source_facts(source: bytes) -> tuple[tuple, ast.Module]:
    """What the cache key reads of one module's source, parsed once per content: its imports as
    ``(level, module, names)`` (``import a.b`` is ``(0, "a.b", ())``) and its syntax tree without docstrings."""
    tree = ast.parse(source)
    imports = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imports.extend((0, a.name, ()) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            imports.append((node.level, node.module or "", tuple(a.name for a in node.names)))
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tuple(imports), tree


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
        # Each key's time includes building the shared context once, as a standalone blob_matching call would.
        t = time.perf_counter() - t0 + t_ctx
        out[key] = (matches, dist, t)
        stored[f"m_{name}"] = matches.astype(np.int32)
        stored[f"d_{name}"] = dist
        stored[f"t_{name}"] = np.float64(t)
        added = True
    if added and path is not None:
        save_npz(path, stored)
    return out
