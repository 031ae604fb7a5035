"""Peer filters side by side with their authors' reference implementations on real candidates.

For every ``--ref NAME=SPEC`` the filter ``NAME`` of :data:`ctxmatch_lib.filters.FILTERS` and its reference run
on the SAME blob candidates of the shared real pairs (``CTXMATCH_DATA``; datasets ``planar`` and ``nonplanar``,
``--pairs N`` pairs evenly spread over each by :func:`ctxmatch_lib.evaluation.select_pairs`). Configurations
(``--configs``): ``baseline`` = SIFT + RootSIFT features with the ``baseline`` blob preset, ``best`` = HarrisZ +
SOSNet (stand-in) with ``paper-best-overlap``, both at ``--max-keypoints paper`` (1500). Labels are the library's
ground truth (method D, :func:`~ctxmatch_lib.evaluation.steps.label_candidates`). Both sides get the candidate rows
in their canonical order (:func:`ctxmatch_lib.filters._common.canonical_order`: score, keypoint coordinates,
keypoint indices), the order our filters decide in whatever order they are given, so a reference that depends on
the order of its rows sees the rows as our filter's core sees them.

References (each runs in its own process, with its own interpreter, through a small driver written to a temp
dir; inputs and outputs travel as ``.npz``; the reference is never imported here and never a dependency):

- ``gms=PYTHON``: ``cv2.xfeatures2d.matchGMS`` of opencv-contrib-python(-headless), which conflicts with the
  project's opencv-python-headless, so ``PYTHON`` is the interpreter of a scratch environment, e.g.
  ``python3.11 -m venv /tmp/refenv && /tmp/refenv/bin/pip install opencv-contrib-python-headless numpy``.
  Every candidate row is one ``DMatch`` (its ``distance`` carries the row index so that repeated rows stay
  apart); ``withRotation`` / ``withScale`` are off and ``thresholdFactor`` is 6, the defaults of matchGMS and
  the call of the authors' Python ``GmsMatcher.compute_matches``.
- ``adalam=kornia`` (or ``adalam=PYTHON``, an interpreter with torch and kornia; ``kornia`` is this one):
  ``kornia.feature.adalam.AdalamFilter.filter_matches`` with its default configuration. Its input is one
  putative match per image-1 keypoint, so every candidate row becomes its own image-1 point (the keypoint of
  the row), matched to its image-2 keypoint; the scores are passed squared (kornia's ratio scores are ratios of
  squared distances: its seed threshold is ``0.8 ** 2``); no mutual-nearest-neighbour mask (blob candidates are
  not plain nearest neighbours); orientations (degrees) and scales from the keypoint shapes ``A``: the angle of
  the closest rotation to ``A`` and ``sqrt(|det A|)``.

Printed per filter, configuration and dataset: the number of pairs and mean candidates, the mean precision /
recall (percent; recall is the library's normalised recall, :func:`ctxmatch_lib.metrics.recall`, against the
pair's correct candidates) of ours and of the reference, the mean Jaccard index of the two keep masks, and the
summed CPU times (process time, one thread, each measured around the filter call only, the fastest of
``--repeat`` calls, after one untimed call on the first pair on both sides) with the ratio ours / reference
(< 1: ours faster). The reference's time excludes building its inputs (OpenCV ``KeyPoint`` / ``DMatch`` lists,
torch tensors) from the arrays.

MATLAB references, run by GNU Octave (``apt-get install octave liboctave-dev``: ``octave`` and ``mkoctfile`` on
PATH); ``DIR`` is a checkout of the authors' code, outside this repository, read at run time and never copied:

- ``lpm=DIR`` (jiayi-ma/LPM): the parameter lines and the filtering block (between ``tic;`` and ``toc``) of
  ``demo_LPM_v2.m``, calling ``LPM_cosF.m``; VLFeat's ``vl_kdtreebuild`` / ``vl_kdtreequery`` compiled from the
  checkout's ``vlfeat`` sources with ``mkoctfile --mex`` into the run's temp dir.
- ``glpm=DIR`` (jiayi-ma/GLPM): the two filtering blocks of ``demo.m`` (the small set after
  ``load(fn_match_1_5)``, the guided passes after ``load(fn_match_1)``) with ``ffm2.cpp`` and the k-d tree
  compiled likewise; the small set is the candidates with ``scores <= ratio`` (our ``ratio``), the whole set
  all of them. A pair on which the demo stops with an error is reported and left out.
- ``vfc=DIR`` (jiayi-ma/VFC, ``VFC_short.zip`` unpacked): ``norm2``, ``VFC_init`` and ``SparseVFC`` (the method
  the demo selects) on ``(nX, nY - nX)``; the random state is reset to 0 before each call.

Every candidate row is one correspondence ``X(i, :) = kpts1[matches[i, 0]]``, ``Y(i, :) = kpts2[matches[i, 1]]``
(pixels). The reference's time is Octave's ``cputime`` around the filtering block (process time, as ours).
``--param`` settings shared with the reference (:data:`OCTAVE_OPTIONS`) override the demo's values.

``--permutations N`` runs every reference N more times on its candidate rows permuted (seeded) and prints its
P / R and the Jaccard with its unpermuted run: LPM's and GLPM's code exclude a query from its own k-d tree
answers by dropping the first one, which among rows at one location depends on their order.

Run::

    OMP_NUM_THREADS=1 CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_filters_ref.py \\
        --ref gms=/tmp/refenv/bin/python --ref adalam=kornia --pairs 6
    OMP_NUM_THREADS=1 CTXMATCH_DATA=/path/to/data .venv/bin/python benchmarks/bench_filters_ref.py \\
        --ref lpm=/tmp/ref/LPM --ref glpm=/tmp/ref/GLPM --ref vfc=/tmp/ref/VFC --pairs 6 --configs baseline best

(the second: about a minute on one core, candidates included).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

CONFIGS = {"baseline": ("sift-rootsift", "baseline"), "best": ("harrisz-sosnet", "paper-best-overlap")}
DATASETS = ("planar", "nonplanar")

# One driver for every reference: argv = kind, input folder, output folder. Each input ``case-*.npz`` holds
# kpts1, kpts2 (N, 2) (x, y) pixels (pixel-centre origin, OpenCV's and kornia's convention too), matches (K, 2),
# scores (K,), size1, size2 (width, height), shapes1, shapes2 (N, 2, 2); each output holds keep (K,) bool and
# cpu, the process time of the reference call alone.
_DRIVER = r'''
import sys, time
from pathlib import Path
import numpy as np

kind, src, dst, repeat = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])


def gms(d):
    import cv2
    k1 = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in d["kpts1"]]
    k2 = [cv2.KeyPoint(float(x), float(y), 1.0) for x, y in d["kpts2"]]
    # The row index rides in ``distance`` so that repeated rows remain distinct in the output.
    dm = [cv2.DMatch(int(i), int(j), float(r)) for r, (i, j) in enumerate(d["matches"])]
    size1, size2 = tuple(int(v) for v in d["size1"]), tuple(int(v) for v in d["size2"])
    c0 = time.process_time()
    out = cv2.xfeatures2d.matchGMS(size1, size2, k1, k2, dm, withRotation=bool(d.get("withRotation", False)),
                                   withScale=bool(d.get("withScale", False)),
                                   thresholdFactor=float(d.get("thresholdFactor", 6.0)))
    cpu = time.process_time() - c0
    keep = np.zeros(len(dm), bool)
    keep[[int(m.distance) for m in out]] = True
    return keep, cpu


def adalam(d):
    import torch
    from kornia.feature.adalam import AdalamFilter, get_adalam_default_config
    torch.set_num_threads(1)
    m = d["matches"]
    if len(m) == 0:
        return np.zeros(0, bool), 0.0

    def orient_scale(A):
        # Closest rotation to A (polar decomposition) and the scale of its area.
        ang = np.degrees(np.arctan2(A[:, 1, 0] - A[:, 0, 1], A[:, 0, 0] + A[:, 1, 1]))
        sc = np.sqrt(np.abs(A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]))
        return torch.from_numpy(ang.astype(np.float32)), torch.from_numpy(sc.astype(np.float32))

    o1, s1 = orient_scale(d["shapes1"][m[:, 0]])
    o2, s2 = orient_scale(d["shapes2"])
    k1 = torch.from_numpy(d["kpts1"][m[:, 0]].astype(np.float32))
    k2 = torch.from_numpy(d["kpts2"].astype(np.float32))
    fnn = torch.from_numpy(m[:, 1].astype(np.int64))
    sc = torch.from_numpy((d["scores"] ** 2).astype(np.float32))
    size1, size2 = [int(v) for v in d["size1"]], [int(v) for v in d["size2"]]
    config = get_adalam_default_config()
    for key in [k for k in d if k.startswith("config_")]:
        value = d[key][()]
        config[key[len("config_"):]] = None if isinstance(value, float) and np.isnan(value) else value.item()
    filt = AdalamFilter(config)
    c0 = time.process_time()
    out = filt.filter_matches(k1, k2, fnn, sc, mnn=None, im1shape=size1, im2shape=size2, o1=o1, o2=o2,
                              s1=s1, s2=s2)
    cpu = time.process_time() - c0
    keep = np.zeros(len(m), bool)
    keep[out[:, 0].numpy()] = True
    return keep, cpu


run = {"gms": gms, "adalam": adalam}[kind]
files = sorted(src.glob("case-*.npz"))
if files:  # one untimed call first: imports and first-call set-up are not the filter's time
    run(dict(np.load(files[0])))
for f in files:
    d = dict(np.load(f))
    keep, cpu = run(d)
    for _ in range(repeat - 1):  # the fastest of ``repeat`` calls
        cpu = min(cpu, run(d)[1])
    np.savez(dst / f.name, keep=keep, cpu=cpu)
'''

#: Octave references defined in their own module beside this script, ``benchmarks/ref_<name>.py``, which holds
#: ``FILES`` (names a checkout must hold), ``FUNC_FILES`` (their folders go on Octave's path), ``OPTIONS`` (our
#: keyword -> the reference's variables, as :data:`OCTAVE_OPTIONS`), ``octave_body(root, params)`` (Octave lines
#: that read ``X``, ``Y`` (K, 2), ``small`` (K,) and ``info`` = [w1 h1 w2 h2] and set ``keep`` (1-based row
#: indices) and ``cpu`` (``cputime`` around the filtering)) and optionally ``compile_mex(root, dst)``. The
#: module runs with this script's helpers as its global ``host`` (set by :func:`plugin`): it calls
#: ``host.find_reference_file``, ``host.demo_block``, ``host.block_bounds``, ``host.octave_assignments``,
#: ``host.compile_octave_mex``.
PLUGIN_REFERENCES = ("llt", "rfm_scan", "lmr")

REFERENCES = ("gms", "adalam", "lpm", "glpm", "vfc", *PLUGIN_REFERENCES)


@functools.lru_cache(maxsize=None)
def plugin(name: str):
    """The module ``benchmarks/ref_<name>.py`` of an Octave reference of :data:`PLUGIN_REFERENCES`, loaded
    once, with this script's shared helpers as its global ``host``."""
    import importlib.util

    path = Path(__file__).resolve().parent / f"ref_{name}.py"
    if not path.exists():
        raise ValueError(f"--ref {name}: its reference module {path.name} is missing beside {Path(__file__).name}")
    spec = importlib.util.spec_from_file_location(f"ref_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    mod.host = SimpleNamespace(find_reference_file=find_reference_file, demo_block=demo_block,
                               block_bounds=block_bounds, octave_assignments=octave_assignments,
                               compile_octave_mex=compile_octave_mex)
    spec.loader.exec_module(mod)
    return mod

#: Our keyword -> the reference's option, for the ``--param`` settings that exist on both sides (given to both).
SHARED_OPTIONS = {
    "gms": {"with_scale": "withScale", "with_rotation": "withRotation", "alpha": "thresholdFactor"},
    "adalam": {k: "config_" + v for k, v in {
        "area_ratio": "area_ratio", "search_expansion": "search_expansion", "ransac_iters": "ransac_iters",
        "min_inliers": "min_inliers", "min_confidence": "min_confidence",
        "orientation_threshold": "orientation_difference_threshold", "scale_rate_threshold": "scale_rate_threshold",
        "detected_scale_rate_threshold": "detected_scale_rate_threshold", "refit": "refit"}.items()},
}


def reference_options(name: str, params: dict) -> dict:
    """The driver's option arrays for our ``params`` that the reference of ``name`` shares (None -> NaN)."""
    table = SHARED_OPTIONS.get(name, {})
    return {table[k]: np.asarray(np.nan if v is None else v) for k, v in params.items() if k in table}


def parse_ref(text: str) -> tuple[str, str]:
    """``NAME=SPEC`` -> ``(name, spec)``: SPEC is an interpreter path, or ``kornia`` (this interpreter) for
    ``adalam``; for the :data:`OCTAVE_REFERENCES` the directory of the authors' MATLAB code (run by Octave)."""
    name, sep, spec = text.partition("=")
    if not sep or not spec:
        raise ValueError(f"--ref must be NAME=SPEC, got {text!r}")
    if name not in REFERENCES:
        raise ValueError(f"--ref: no reference runner for filter {name!r}; known: {', '.join(REFERENCES)}")
    if name in OCTAVE_REFERENCES:
        if not Path(spec).is_dir():
            raise ValueError(f"--ref {text!r}: {spec} is not a directory (the checkout of the authors' code)")
        for f in (plugin(name).FILES if name in PLUGIN_REFERENCES else OCTAVE_FILES[name]):
            find_reference_file(Path(spec), f)
        return name, spec
    if spec == "kornia":
        if name != "adalam":
            raise ValueError(f"--ref {text!r}: 'kornia' is the reference of adalam only")
        return name, sys.executable
    if not Path(spec).is_file():
        raise ValueError(f"--ref {text!r}: {spec} is not an interpreter")
    return name, spec


def run_reference(kind: str, python: str, cases: list[dict], repeat: int = 1) -> list[tuple[np.ndarray, float]]:
    """Run reference ``kind`` in ``python`` on every case (dicts of the driver's input arrays); one process.

    Returns one ``(keep, cpu_seconds)`` per case, in order; the time is the fastest of ``repeat`` calls.
    """
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in", Path(tmp) / "out"
        src.mkdir()
        dst.mkdir()
        for i, case in enumerate(cases):
            np.savez(src / f"case-{i:05d}.npz", **case)
        driver = Path(tmp) / "driver.py"
        driver.write_text(_DRIVER)
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        subprocess.run([python, str(driver), kind, str(src), str(dst), str(int(repeat))], check=True, env=env)
        out = []
        for i in range(len(cases)):
            d = np.load(dst / f"case-{i:05d}.npz")
            out.append((d["keep"].astype(bool), float(d["cpu"])))
    return out


# ---------------------------------------------------------------------------------------------------------------
# MATLAB references under GNU Octave (lpm, glpm, vfc). The authors' code is run as published: their functions
# (LPM_cosF, ffm2, SparseVFC, norm2, VFC_init) from the checkout, and the filtering block of their demo read from
# the checkout at run time (the lines between two markers of demo_LPM_v2.m / demo.m), so none of it is copied
# here. The C/C++ parts (VLFeat's k-d tree, GLPM's ffm2.cpp) are compiled with ``mkoctfile --mex`` into the
# temp dir of the run. Inputs and outputs travel as plain text.

OCTAVE_REFERENCES = ("lpm", "glpm", "vfc", *PLUGIN_REFERENCES)

#: Files a checkout must hold, per reference (searched anywhere under PATH, e.g. VFC_short.zip unpacked).
OCTAVE_FILES = {"lpm": ("demo_LPM_v2.m", "LPM_cosF.m"), "glpm": ("demo.m", "ffm2.cpp"),
                "vfc": ("SparseVFC.m", "norm2.m", "VFC_init.m")}

#: Our keyword -> the reference's variable, for the options given to both sides (see SHARED_OPTIONS).
OCTAVE_OPTIONS = {
    "lpm": {"k": ("numNeigh1", "numNeigh2"), "tau": ("tau1", "tau2"), "lambdas": ("lambda1", "lambda2")},
    "vfc": {"beta": ("conf.beta",), "lam": ("conf.lambda",), "tau": ("conf.theta",), "gamma": ("conf.gamma",),
            "a": ("conf.a",), "max_iter": ("conf.MaxIter",), "tol": ("conf.ecr",), "min_p": ("conf.minP",)},
}


def find_reference_file(root: Path, name: str) -> Path:
    """The first file called ``name`` under ``root`` (the shallowest), or a ValueError naming it."""
    hits = sorted(Path(root).rglob(name), key=lambda p: (len(p.parts), str(p)))
    if not hits:
        raise ValueError(f"--ref: no {name} under {root}")
    return hits[0]


def block_bounds(lines: list[str], start: str, stop: str, *, after: int = 0) -> tuple[int, int]:
    """``(i, j)``: the index of the first of ``lines`` (at or after ``after``) that starts with ``start`` and of
    the next one that starts with ``stop``; marker matching ignores leading blanks. A ValueError names a
    missing marker."""
    strip = [ln.strip() for ln in lines]
    try:
        i = next(n for n in range(after, len(lines)) if strip[n].startswith(start))
        j = next(n for n in range(i + 1, len(lines)) if strip[n].startswith(stop))
    except StopIteration:
        raise ValueError(f"demo has no block from {start!r} to {stop!r}") from None
    return i, j


def demo_block(text: str, start: str, stop: str, *, include_stop: bool = False, after: int = 0) -> str:
    """The lines of ``text`` after the first line (at or after line ``after``) that starts with ``start`` and
    before the next line that starts with ``stop`` (included if ``include_stop``), as :func:`block_bounds`
    finds them."""
    lines = text.splitlines()
    i, j = block_bounds(lines, start, stop, after=after)
    return "\n".join(lines[i + 1:j + 1 if include_stop else j])


def lpm_demo_parts(demo: str) -> tuple[str, str]:
    """(parameter lines, filtering block) of the authors' ``demo_LPM_v2.m``: the assignments of
    ``lambda1/2``, ``numNeigh1/2``, ``tau1/2`` and the lines between ``tic;`` and ``toc``."""
    params = "\n".join(ln for ln in demo.splitlines()
                       if ln.strip().startswith(("lambda1", "numNeigh1", "tau1")))
    if not params:
        raise ValueError("demo_LPM_v2.m: no parameter lines (lambda1 / numNeigh1 / tau1)")
    return params, demo_block(demo, "tic", "toc")


def glpm_demo_parts(demo: str) -> tuple[str, str]:
    """The two filtering blocks of the authors' GLPM ``demo.m``: the small set (after ``load(fn_match_1_5)``
    up to ``time1 = toc``) and the guided passes on the whole set (after ``load(fn_match_1)`` up to the
    ``ind = find(p == 1)`` that follows the last ``ffm2`` call)."""
    small = demo_block(demo, "load(fn_match_1_5)", "time1 = toc")
    lines = demo.splitlines()
    i = next((n for n, ln in enumerate(lines) if ln.strip().startswith("load(fn_match_1)")), None)
    if i is None:
        raise ValueError("demo.m: no line load(fn_match_1)")
    j = next((n for n in range(i, len(lines)) if lines[n].strip().startswith("p = ffm2")), None)
    if j is None:
        raise ValueError("demo.m: no line p = ffm2(...) after load(fn_match_1)")
    whole = demo_block(demo, "load(fn_match_1)", "ind = find(p == 1)", include_stop=True, after=i)
    return small, whole


def octave_assignments(name: str, params: dict) -> str:
    """Octave lines setting the reference's variables of our shared ``params`` (after its own defaults)."""
    out = []
    for key, value in params.items():
        table = plugin(name).OPTIONS if name in PLUGIN_REFERENCES else OCTAVE_OPTIONS.get(name, {})
        targets = table.get(key)
        if not targets:
            continue
        values = list(value) if isinstance(value, (list, tuple)) else [value] * len(targets)
        if len(values) != len(targets):
            raise ValueError(f"--param {name}:{key}: {len(targets)} value(s) expected, got {value!r}")
        out += [f"{t} = {float(v)!r};" for t, v in zip(targets, values)]
    return "\n".join(out)


def read_keep(text: str, n: int) -> np.ndarray:
    """The keep mask of ``n`` rows from the driver's output: 1-based indices of the kept rows, one per line."""
    idx = np.array([int(float(t)) for t in text.split()], np.int64)
    if idx.size and (idx.min() < 1 or idx.max() > n):
        raise ValueError(f"reference returned row indices outside 1..{n}")
    keep = np.zeros(n, bool)
    keep[idx - 1] = True
    return keep


def _mex(sources: list[Path], out: Path, includes: list[Path], defines=()) -> None:
    cmd = (["mkoctfile", "--mex", *[f"-D{d}" for d in defines], *[f"-I{p}" for p in includes]]
           + [str(s) for s in sources] + ["-o", str(out)])
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0 or not out.exists():
        raise RuntimeError(f"mkoctfile failed for {out.name}:\n{res.stdout}\n{res.stderr}")


def compile_octave_mex(name: str, root: Path, dst: Path) -> None:
    """Compile the C/C++ parts of reference ``name`` (checkout ``root``) into ``dst`` with mkoctfile."""
    if name in PLUGIN_REFERENCES:
        build = getattr(plugin(name), "compile_mex", None)
        if build is not None:
            build(Path(root), dst)
        return
    if name in ("lpm", "glpm"):  # VLFeat's k-d tree, as shipped in the checkout
        vl = find_reference_file(root, "kdtree.c").parent.parent  # .../vlfeat (vl/kdtree.c)
        srcs = [vl / "vl" / f for f in ("kdtree.c", "generic.c", "host.c", "random.c", "mathop.c", "stringop.c")]
        for fn in ("vl_kdtreebuild", "vl_kdtreequery"):
            _mex([find_reference_file(vl / "toolbox", fn + ".c"), *srcs], dst / f"{fn}.mex",
                 [vl, vl / "toolbox"], ("VL_DISABLE_SSE2", "VL_DISABLE_THREADS"))
    if name == "glpm":  # ffm2.cpp is stored as UTF-16: re-encoded for the compiler, unchanged otherwise
        raw = find_reference_file(root, "ffm2.cpp").read_bytes()
        text = raw.decode("utf-16") if raw[:2] in (b"\xff\xfe", b"\xfe\xff") else raw.decode("utf-8", "replace")
        src = dst / "ffm2_src.cpp"
        src.write_text(text.replace("\r\n", "\n"))
        _mex([src], dst / "ffm2.mex", [])


def octave_driver(name: str, root: Path, params: dict) -> str:
    """The Octave function ``ref_filter(X, Y, small, info)`` -> ``(keep indices, cpu seconds)`` of reference
    ``name`` (``info`` = [w1 h1 w2 h2], the image sizes)."""
    if name in PLUGIN_REFERENCES:
        body = plugin(name).octave_body(Path(root), params)
    elif name == "lpm":
        defaults, block = lpm_demo_parts(find_reference_file(root, "demo_LPM_v2.m").read_text(errors="replace"))
        body = f"{defaults}\n{octave_assignments(name, params)}\nc0 = cputime;\n{block}\ncpu = cputime - c0;\n" \
               "keep = find(p2 == 1);"
    elif name == "glpm":
        small, whole = glpm_demo_parts(find_reference_file(root, "demo.m").read_text(errors="replace"))
        body = ("Xall = X; Yall = Y; X = Xall(small, :); Y = Yall(small, :);\nc0 = cputime;\n"
                f"{small}\nX = Xall; Y = Yall;\n{whole}\ncpu = cputime - c0;\nkeep = find(p == 1);")
    else:
        body = (f"conf = [];\n{octave_assignments(name, params)}\nc0 = cputime;\n[nX, nY, normal] = norm2(X, Y);\n"
                "conf = VFC_init(conf);\nVecFld = SparseVFC(nX, nY - nX, conf);\ncpu = cputime - c0;\n"
                "keep = VecFld.VFCIndex;")
    return f"function [keep, cpu] = ref_filter(X, Y, small, info)\n{body}\nend\n"


_OCTAVE_MAIN = r'''
src = '{src}'; dst = '{dst}'; repeat = {repeat};
addpath('{mex}'); addpath('{dirs}');
more off;
files = dir(fullfile(src, 'case-*-X.txt'));
for f = 1:numel(files)
  stem = files(f).name(1:end - 6);
  X = load(fullfile(src, [stem '-X.txt'])); Y = load(fullfile(src, [stem '-Y.txt']));
  small = logical(load(fullfile(src, [stem '-S.txt']))); info = load(fullfile(src, [stem '-I.txt']));
  rand('state', 0); randn('state', 0);
  try
    if f == 1, ref_filter(X, Y, small, info); rand('state', 0); randn('state', 0); end  % one untimed call first
    [keep, cpu] = ref_filter(X, Y, small, info);
    for r = 2:repeat
      rand('state', 0); randn('state', 0);
      [~, c] = ref_filter(X, Y, small, info); cpu = min(cpu, c);
    end
  catch err  % the authors' code stopped on this input: recorded, the case is left out of the means
    fid = fopen(fullfile(dst, [stem '-error.txt']), 'w'); fprintf(fid, '%s\n', err.message); fclose(fid);
    continue
  end
  fid = fopen(fullfile(dst, [stem '-keep.txt']), 'w'); fprintf(fid, '%d\n', keep); fclose(fid);
  fid = fopen(fullfile(dst, [stem '-cpu.txt']), 'w'); fprintf(fid, '%.9g\n', cpu); fclose(fid);
end
'''


def run_octave_reference(name: str, root: Path, cases: list[dict], repeat: int = 1,
                         params: dict | None = None) -> list[tuple[np.ndarray, float]]:
    """Run the authors' MATLAB code of ``name`` (checkout ``root``) under Octave on every case; one process.

    Each case holds ``X``, ``Y`` (K, 2) (the candidates' keypoints in image 1 and 2) and ``small`` (K,) bool
    (GLPM's small putative set). Returns one ``(keep, cpu_seconds)`` per case; the time is Octave's ``cputime``
    around the filtering (the demo's block), the fastest of ``repeat`` calls, the random state reset to 0
    before each call (SparseVFC draws its control points with ``randperm``).
    """
    if shutil.which("octave") is None:
        raise RuntimeError("--ref lpm/glpm/vfc needs GNU Octave ('octave' on PATH), e.g. apt-get install octave")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src, dst, mex = tmp / "in", tmp / "out", tmp / "mex"
        for d in (src, dst, mex):
            d.mkdir()
        compile_octave_mex(name, Path(root), mex)
        (tmp / "ref_filter.m").write_text(octave_driver(name, Path(root), params or {}))
        funcs = {"lpm": ["LPM_cosF.m"], "vfc": ["SparseVFC.m"]}.get(name, [])  # glpm: ffm2, compiled above
        if name in PLUGIN_REFERENCES:
            funcs = list(plugin(name).FUNC_FILES)
        dirs = [str(find_reference_file(root, f).parent) for f in funcs]
        for i, case in enumerate(cases):
            np.savetxt(src / f"case-{i:05d}-X.txt", case["X"], fmt="%.17g")
            np.savetxt(src / f"case-{i:05d}-Y.txt", case["Y"], fmt="%.17g")
            np.savetxt(src / f"case-{i:05d}-S.txt", np.asarray(case["small"], np.int64), fmt="%d")
            np.savetxt(src / f"case-{i:05d}-I.txt", np.asarray(case.get("info", np.zeros(4)), np.float64)[None],
                       fmt="%.17g")
        main = tmp / "main.m"
        main.write_text(_OCTAVE_MAIN.format(src=src, dst=dst, mex=mex, dirs=os.pathsep.join(dirs), repeat=int(repeat)))
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        res = subprocess.run(["octave", "--no-gui", "--no-window-system", "--quiet", "--no-init-file",
                              "--eval", f"cd('{tmp}'); main"], capture_output=True, text=True, env=env)
        out = []
        for i, case in enumerate(cases):
            err = dst / f"case-{i:05d}-error.txt"
            if err.exists():  # the authors' code stopped with an error on this input
                out.append((None, err.read_text().strip()))
                continue
            if not (dst / f"case-{i:05d}-cpu.txt").exists():
                raise RuntimeError(f"octave ({name}) failed on case {i}:\n{res.stderr[-3000:]}")
            keep = read_keep((dst / f"case-{i:05d}-keep.txt").read_text(), len(case["X"]))
            out.append((keep, float((dst / f"case-{i:05d}-cpu.txt").read_text())))
    return out


def make_octave_case(f1, f2, matches, scores, ratio: float, size1=(0, 0), size2=(0, 0)) -> dict:
    """The Octave driver's inputs: the candidates' keypoints, GLPM's small set (``scores <= ratio``) and the
    image sizes ``info`` = [w1 h1 w2 h2]."""
    m = np.asarray(matches, np.int64).reshape(-1, 2)
    return dict(X=np.asarray(f1.kpts[m[:, 0], :2], np.float64), Y=np.asarray(f2.kpts[m[:, 1], :2], np.float64),
                small=np.asarray(scores, np.float64) <= ratio,
                info=np.asarray([*size1, *size2], np.float64))


def permute_case(case: dict, perm: np.ndarray) -> dict:
    """``case`` with its candidate rows (``matches``, ``scores``; ``X``, ``Y``, ``small``) in the order ``perm``;
    the reference's keep mask ``k`` of it maps back as ``keep[perm] = k``."""
    rows = ("matches", "scores", "X", "Y", "small")
    return {key: (np.asarray(v)[perm] if key in rows else v) for key, v in case.items()}


def make_case(f1, f2, matches, scores, size1, size2) -> dict:
    """The driver's input arrays for one candidate set."""
    return dict(kpts1=np.asarray(f1.kpts[:, :2], np.float64), kpts2=np.asarray(f2.kpts[:, :2], np.float64),
                matches=np.asarray(matches, np.int64), scores=np.asarray(scores, np.float64),
                size1=np.asarray(size1, np.int64), size2=np.asarray(size2, np.int64),
                shapes1=np.asarray(f1.shapes, np.float64), shapes2=np.asarray(f2.shapes, np.float64))


def jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """|a & b| / |a | b| of two masks; 1 when both are empty."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def precision_recall(matches: np.ndarray, labels: np.ndarray, keep: np.ndarray) -> tuple[float, float]:
    """Precision and the library's normalised recall (against the correct candidates), in percent."""
    from ctxmatch_lib.metrics import precision, recall

    p = precision(labels[keep])
    r = recall(matches[keep], labels[keep], matches[labels])
    return 100 * p, 100 * r


def _inputs(dataset: str, config: str, n_pairs: int, max_keypoints):
    """The canonical candidates of ``config`` (:func:`_common.canonical_candidates`), the same rows on both sides."""
    from _common import canonical_candidates

    return canonical_candidates(dataset, *CONFIGS[config], n_pairs, max_keypoints)


def _default(name: str, key: str):
    """The default of keyword ``key`` of our filter ``name``."""
    import inspect

    from ctxmatch_lib.filters import FILTERS

    return inspect.signature(FILTERS[name]).parameters[key].default


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ref", action="append", required=True, metavar="NAME=SPEC",
                        help="filter and its reference: gms=PYTHON (opencv-contrib env), adalam=kornia|PYTHON, "
                             "lpm=DIR, glpm=DIR, vfc=DIR, llt=DIR, rfm_scan=DIR (checkouts of the authors' MATLAB "
                             "code; GNU Octave)")
    parser.add_argument("--configs", nargs="+", default=["baseline"], choices=list(CONFIGS))
    parser.add_argument("--datasets", nargs="+", default=list(DATASETS))
    parser.add_argument("--pairs", type=int, default=6, help="pairs per dataset, evenly spread (default 6)")
    parser.add_argument("--max-keypoints", default="paper", help="keypoint budget (default 'paper': 1500)")
    parser.add_argument("--param", action="append", default=[], metavar="NAME:KEY=JSON",
                        help="extra keyword of our filter, e.g. gms:with_scale=true (repeatable); the reference "
                             "gets it too where it has the same option (SHARED_OPTIONS)")
    parser.add_argument("--repeat", type=int, default=3, help="time the fastest of this many calls (default 3)")
    parser.add_argument("--permutations", type=int, default=0, metavar="N",
                        help="also run each reference N times on its rows permuted (seeded) and print its "
                             "P / R and the Jaccard of its keep masks with the unpermuted run: how much the "
                             "reference depends on the order of its rows (default 0)")
    parser.add_argument("--json", type=Path, help="also write the per-pair numbers here")
    args = parser.parse_args(argv)
    try:
        refs = dict(parse_ref(r) for r in args.ref)
    except ValueError as exc:
        parser.error(str(exc))
    if args.pairs < 1:
        parser.error(f"--pairs must be a positive integer, got {args.pairs}")
    if args.repeat < 1:
        parser.error(f"--repeat must be a positive integer, got {args.repeat}")
    if args.permutations < 0:
        parser.error(f"--permutations must be a non-negative integer, got {args.permutations}")
    params: dict[str, dict] = {name: {} for name in refs}
    for p in args.param:
        name, _, kv = p.partition(":")
        key, sep, val = kv.partition("=")
        if name not in refs or not sep:
            parser.error(f"--param must be NAME:KEY=JSON with NAME among the --ref filters, got {p!r}")
        params[name][key] = json.loads(val)
    if not os.environ.get("CTXMATCH_DATA"):
        print("CTXMATCH_DATA is not set: nothing to compare", file=sys.stderr)
        return 2
    from ctxmatch_lib.evaluation.steps import run_filter

    print("command: " + " ".join([Path(sys.argv[0]).name] + (sys.argv[1:] if argv is None else list(argv))))
    print(f"{'filter':<7} {'config':<9} {'dataset':<10} {'pairs':>5} {'cands':>6} {'ours P / R':>13} "
          f"{'ref P / R':>13} {'Jaccard':>7} {'ours ms':>8} {'ref ms':>8} {'ours/ref':>8}")
    rows = []
    for config in args.configs:
        for dataset in args.datasets:
            data = list(_inputs(dataset, config, args.pairs, args.max_keypoints))
            for name, python in refs.items():
                opts = reference_options(name, params[name])
                if name in OCTAVE_REFERENCES:
                    ratio = params[name].get("ratio", _default(name, "ratio")) if name == "glpm" else np.inf
                    cases = [make_octave_case(f1, f2, m, s, ratio, p.image_size1, p.image_size2)
                             for p, f1, f2, m, s, _ in data]
                    ref_out = run_octave_reference(name, Path(python), cases, args.repeat, params[name])
                else:
                    cases = [dict(make_case(f1, f2, m, s, p.image_size1, p.image_size2), **opts)
                             for p, f1, f2, m, s, _ in data]
                    ref_out = run_reference(name, python, cases, args.repeat)
                per = []
                if data:  # one untimed call first (numba kernels load or compile on the first call)
                    pair, f1, f2, m, s, _ = data[0]
                    run_filter(name, f1, f2, m, s, image_size1=pair.image_size1, image_size2=pair.image_size2,
                               **params[name])
                failed = []
                for (pair, f1, f2, m, s, lab), (rkeep, rcpu) in zip(data, ref_out):
                    if rkeep is None:  # the reference stopped with an error: not compared
                        failed.append((pair.pair_id, rcpu))
                        continue
                    cpu = np.inf
                    for _ in range(args.repeat):  # the fastest of ``repeat`` calls, as for the reference
                        c0 = time.process_time()
                        keep, _ = run_filter(name, f1, f2, m, s, image_size1=pair.image_size1,
                                             image_size2=pair.image_size2, **params[name])
                        cpu = min(cpu, time.process_time() - c0)
                    per.append(dict(pair=pair.pair_id, K=int(len(m)), ours=precision_recall(m, lab, keep),
                                    ref=precision_recall(m, lab, rkeep), jaccard=jaccard(keep, rkeep),
                                    kept_ours=int(keep.sum()), kept_ref=int(rkeep.sum()), t_ours=cpu, t_ref=rcpu))
                for pid, msg in failed:
                    print(f"  {name}: the reference stopped on pair {pid} ({msg}); left out", flush=True)
                if not per:
                    continue
                po, ro = np.nanmean([x["ours"] for x in per], axis=0)
                pr, rr = np.nanmean([x["ref"] for x in per], axis=0)
                jac = np.mean([x["jaccard"] for x in per])
                to, tr = sum(x["t_ours"] for x in per), sum(x["t_ref"] for x in per)
                ratio = to / tr if tr > 0 else float("inf")
                print(f"{name:<7} {config:<9} {dataset:<10} {len(per):>5} {np.mean([x['K'] for x in per]):>6.0f} "
                      f"{po:>6.1f} / {ro:<5.1f} {pr:>6.1f} / {rr:<5.1f} {jac:>7.3f} {1e3 * to:>8.1f} {1e3 * tr:>8.1f} "
                      f"{ratio:>7.2f}x", flush=True)
                rows.extend(dict(filter=name, config=config, dataset=dataset, **x) for x in per)
                for seed in range(1, args.permutations + 1):
                    perms = [np.random.default_rng([seed, i]).permutation(len(d[3])) for i, d in enumerate(data)]
                    pcases = [permute_case(c, pm) for c, pm in zip(cases, perms)]
                    pout = (run_octave_reference(name, Path(python), pcases, 1, params[name])
                            if name in OCTAVE_REFERENCES else run_reference(name, python, pcases, 1))
                    pr_, jr = [], []
                    for (pair, f1, f2, m, s, lab), (rkeep, _), (pkeep, _), pm in zip(data, ref_out, pout, perms):
                        if rkeep is None or pkeep is None:
                            continue
                        back = np.zeros(len(pkeep), bool)
                        back[pm] = pkeep
                        pr_.append(precision_recall(m, lab, back))
                        jr.append(jaccard(back, rkeep))
                    if pr_:
                        pp, rp = np.nanmean(pr_, axis=0)
                        print(f"  {name} reference, rows permuted (seed {seed}): P / R {pp:.1f} / {rp:.1f}, "
                              f"Jaccard with its unpermuted run {np.mean(jr):.3f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
