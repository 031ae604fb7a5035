"""MOP's and MOP+MiHo's reference for ``bench_mop_ref.py``: the authors' PyTorch code (fb82/MiHo) run on point
correspondences, in the reference's own interpreter (CPU torch), never imported by the library.

``--miho DIR`` is a folder holding the authors' ``src/`` (``git archive HEAD src`` of a fb82/MiHo clone, outside
this repository, read at run time and never copied). Usage, with the reference environment's Python::

    python ref_miho.py --miho DIR [--methods miho_unduplex miho_duplex] [--no-warmup] IN.npz OUT.npz [IN OUT ...]

Each IN holds ``pt1``, ``pt2`` (K, 2) float32 (x, y pixels; row i is one correspondence) and ``seeds`` (S,) int.
For every method and seed, MiHo's ``planar_clustering`` runs once on the CPU with one torch thread
(``torch.set_num_threads(1)``, and OMP/MKL/OpenBLAS threads set to 1 before torch loads), with
``params['get_avg_hom']['ransac_middle_args']['check_reflection'] = True`` as in miho_ncc_demo.py.

Methods: ``miho_duplex`` = src/miho.py (MOP+MiHo in the paper), ``miho_unduplex`` = src/miho_other.py (MOP).

Seeding: the authors reseed torch inside ``get_avg_hom`` with ``random_seed_init`` (default 123, applied on
every call); its only randomness is ``torch.rand`` in ``sampler4_par`` (no numpy / python ``random``). A seed s
here sets ``random_seed_init = s`` in the instance's params directly (``update_params`` drops falsy values
such as 0 because it "purges" defaults with ``if not aux``), and ``torch.manual_seed(s)``, ``np.random.seed(s)``
are also called before each run for good measure.

OUT holds, per method m: ``{m}_labels`` (S, K) int64 (their ``Hidx``: cluster index, -1 = rejected),
``{m}_cpu`` (S,) process time (s) and ``{m}_wall`` (S,) wall time (s) of ``planar_clustering`` alone,
``{m}_clusters`` (S,) number of homographies found; and ``seeds``, ``torch_threads``, ``torch_version``.

torchvision: src/miho.py, src/miho_other.py and src/ncc.py import ``torchvision.transforms`` at the top, but
use it only for images (``attach_images``, ``show_fig``, ncc's patch saving), never in ``planar_clustering``.
There is no CPU torchvision wheel here, so a stand-in module is put in ``sys.modules`` whose every attribute
access raises: if the code path ever touched torchvision this script would fail loudly.
"""

import os

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_v] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

class _NoTorchvision(types.ModuleType):
    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        raise RuntimeError(f"torchvision stand-in: {self.__name__}.{name} was used; install torchvision")


def _install_torchvision_stub():
    try:
        import torchvision  # noqa: F401
        return False
    except Exception:
        pass
    tv = _NoTorchvision("torchvision")
    tr = _NoTorchvision("torchvision.transforms")
    tv.__path__ = []
    tv.__dict__["transforms"] = tr
    sys.modules["torchvision"] = tv
    sys.modules["torchvision.transforms"] = tr
    return True


def load_methods(names, miho: Path):
    stub = _install_torchvision_stub()
    import torch

    torch.set_num_threads(1)
    sys.path.insert(0, str(miho))
    import importlib

    mods = {"miho_duplex": "src.miho", "miho_unduplex": "src.miho_other"}
    out = {}
    for name in names:
        mod = importlib.import_module(mods[name])
        if str(getattr(mod, "device", "cpu")) != "cpu":
            raise RuntimeError(f"{mods[name]} picked device {mod.device}; run with CUDA_VISIBLE_DEVICES=''")
        out[name] = mod
    return out, stub


def make(mod, seed):
    m = mod.miho()
    params = m.get_current()
    params["get_avg_hom"]["ransac_middle_args"]["check_reflection"] = True
    m.update_params(params)
    # Set directly: update_params would drop a seed of 0 (falsy) and keep the default 123.
    m.params["get_avg_hom"]["random_seed_init"] = int(seed)
    return m


def run_one(mod, pt1, pt2, seed):
    import torch

    m = make(mod, seed)
    torch.manual_seed(int(seed))
    np.random.seed(int(seed) % 2**32)
    t1 = torch.from_numpy(np.ascontiguousarray(pt1, np.float32))
    t2 = torch.from_numpy(np.ascontiguousarray(pt2, np.float32))
    c0, w0 = time.process_time(), time.perf_counter()
    Hs, Hidx = m.planar_clustering(t1, t2)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    return np.asarray(Hidx.cpu().numpy(), np.int64), cpu, wall, len(Hs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=["miho_unduplex", "miho_duplex"],
                    choices=["miho_unduplex", "miho_duplex"])
    ap.add_argument("--miho", type=Path, required=True, help="folder holding the authors' src/ (fb82/MiHo)")
    ap.add_argument("--no-warmup", action="store_true", help="skip the untimed first call of each method")
    ap.add_argument("files", nargs="+", help="IN.npz OUT.npz [IN OUT ...]")
    args = ap.parse_args(argv)
    if len(args.files) % 2:
        ap.error("files must come in IN OUT pairs")
    jobs = list(zip(args.files[::2], args.files[1::2]))
    if not (args.miho / "src" / "miho.py").is_file():
        ap.error(f"--miho: {args.miho} holds no src/miho.py")
    mods, stub = load_methods(args.methods, args.miho)
    import torch

    if not args.no_warmup and jobs:  # torch's lazy initialisation outside the timings
        d = np.load(jobs[0][0])
        for mod in mods.values():
            run_one(mod, d["pt1"][:500], d["pt2"][:500], 0)
    for src, dst in jobs:
        d = np.load(src)
        pt1, pt2 = d["pt1"], d["pt2"]
        seeds = np.atleast_1d(d["seeds"]).astype(np.int64)
        out = dict(seeds=seeds, torch_threads=torch.get_num_threads(), torch_version=torch.__version__,
                   torchvision_stub=stub)
        for name, mod in mods.items():
            res = [run_one(mod, pt1, pt2, s) for s in seeds]
            out[f"{name}_labels"] = np.stack([r[0] for r in res]) if res else np.zeros((0, len(pt1)), np.int64)
            out[f"{name}_cpu"] = np.array([r[1] for r in res])
            out[f"{name}_wall"] = np.array([r[2] for r in res])
            out[f"{name}_clusters"] = np.array([r[3] for r in res])
        np.savez(dst, **out)
        print(f"{src}: K={len(pt1)} " + " ".join(
            f"{n}: kept {(out[n + '_labels'] > -1).sum(1).tolist()} cpu {np.round(out[n + '_cpu'], 2).tolist()}"
            for n in mods), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
