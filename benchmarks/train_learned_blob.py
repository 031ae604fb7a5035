"""Regenerate the shipped OANet / ACNe weights (trained here) with one command.

Two stages per network, both seeded:

1. ``ctxmatch train ARCH`` 's recipe (:func:`ctxmatch_lib.filters.learned.train_learned_filter` with its
   defaults): correspondences generated from the embedded images' SIFT keypoints (:mod:`.data`). Skipped with
   ``--init ARCH=PATH`` (start from those weights instead, e.g. a previous stage-1 result).
2. Fine-tuning on blob candidate sets like the real ones (:mod:`ctxmatch_lib.filters.learned.blobsets`: the
   project's blob candidates, presets ``baseline`` and ``paper-best-overlap``, of SIFT / HarrisZ features at
   the paper budget on warped and layered scenes of scikit-image's photos; sets cached under the user cache),
   with the OANet / CNe authors' balanced classification loss.

The settings below are those of the shipped weights (``weights/README.md``); the weights file records them
in its ``__meta__`` (``training``), with the wall time. Nothing reads ``CTXMATCH_DATA``.

    OMP_NUM_THREADS=1 python benchmarks/train_learned_blob.py [--arch oanet acne] \\
        [--out ctxmatch_lib/filters/learned/weights] [--init oanet=PATH acne=PATH]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from ctxmatch_lib.filters.learned import train_learned_filter

#: Stage 2 of the shipped weights.
FINE_TUNE = {
    "oanet": dict(steps=250, batch_size=4, n_candidates=(8, 3000), lr=1e-3),
    "acne": dict(steps=800, batch_size=4, n_candidates=(8, 3000), lr=1e-3),
}
N_SCENES = 48
SEED = 0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", nargs="*", default=["oanet", "acne"], choices=["oanet", "acne"])
    ap.add_argument("--out", default="ctxmatch_lib/filters/learned/weights", help="folder of the .npz files")
    ap.add_argument("--init", nargs="*", default=[], help="ARCH=PATH: skip stage 1, start from PATH")
    ap.add_argument("--n-scenes", type=int, default=N_SCENES)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    init = dict(s.split("=", 1) for s in args.init)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="ctxmatch-train-"))
    for arch in args.arch:
        start = init.get(arch)
        if start is None:
            start = tmp / f"{arch}_stage1.npz"
            r1 = train_learned_filter(arch, output=start, num_threads=args.threads)
            print(f"{arch} stage 1: {r1.seconds:.0f} s, generated-set validation {json.dumps(r1.validation)}")
        r2 = train_learned_filter(arch, data="blob", n_scenes=args.n_scenes, balanced=True, init=start,
                                  seed=SEED, num_threads=args.threads, output=out / f"{arch}_trained_here.npz",
                                  **FINE_TUNE[arch])
        print(f"{arch} stage 2: {r2.seconds:.0f} s, held-out blob-set validation {json.dumps(r2.validation)}; "
              f"wrote {r2.path}")


if __name__ == "__main__":
    main()
