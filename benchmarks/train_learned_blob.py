"""Fine-tune the OANet / ACNe weights trained here on blob candidate sets like the real ones.

Two stages per network, both seeded:

1. ``ctxmatch train ARCH`` 's recipe (:func:`ctxmatch_lib.filters.learned.train_learned_filter` with its
   defaults: the shipped weights): correspondences generated from the embedded images' SIFT keypoints
   (:mod:`ctxmatch_lib.filters.learned.data`). Skipped with ``--init ARCH=PATH`` (start from those weights,
   e.g. ``--init oanet=ctxmatch_lib/filters/learned/weights/oanet_trained_here.npz``).
2. Fine-tuning on blob candidate sets (:mod:`ctxmatch_lib.training.blobsets`: the project's blob
   candidates, presets ``baseline`` and ``paper-best-overlap``, of SIFT / HarrisZ + RootSIFT at the paper
   budget on warped and layered scenes of scikit-image's photos; sets built once and cached under the user
   cache), with the OANet / CNe authors' balanced loss (``--plain``: the plain mean cross-entropy).

Measured on the shared real pairs (``benchmarks/eval_learned_real.py``), the fine-tuned weights trade
precision for recall along the shipped weights' own precision-recall curve; they are not shipped
(``ctxmatch_lib/filters/learned/weights/README.md`` has the numbers). Nothing reads ``CTXMATCH_DATA``.
The weights files record every setting, the seed and the wall time in their ``__meta__`` (``training``).

    OMP_NUM_THREADS=1 python benchmarks/train_learned_blob.py [--arch oanet acne] [--out DIR] \
        [--init oanet=PATH acne=PATH] [--steps N] [--plain]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from ctxmatch_lib.cache import cache_dir
from ctxmatch_lib.filters.learned import train_learned_filter
from ctxmatch_lib.training import train_on_blob_candidates

#: Stage 2 (the run measured in the weights' README: variant "balanced, short").
FINE_TUNE = {
    "oanet": dict(steps=250, batch_size=4, n_candidates=(8, 3000), lr=1e-3),
    "acne": dict(steps=800, batch_size=4, n_candidates=(8, 3000), lr=1e-3),
}
N_SCENES = 48
SEED = 0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", nargs="*", default=["oanet", "acne"], choices=["oanet", "acne"])
    ap.add_argument("--out", default=None, help="folder of the .npz files (default: the user cache's weights/blob)")
    ap.add_argument("--init", nargs="*", default=[], help="ARCH=PATH: skip stage 1, start from PATH")
    ap.add_argument("--n-scenes", type=int, default=N_SCENES)
    ap.add_argument("--steps", type=int, default=None, help="stage-2 steps (default: FINE_TUNE's)")
    ap.add_argument("--plain", action="store_true", help="plain mean cross-entropy instead of the balanced loss")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    init = dict(s.split("=", 1) for s in args.init)
    out = Path(args.out) if args.out else cache_dir("weights") / "blob"
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="ctxmatch-train-"))
    for arch in args.arch:
        start = init.get(arch)
        if start is None:
            start = tmp / f"{arch}_stage1.npz"
            r1 = train_learned_filter(arch, output=start, num_threads=args.threads)
            print(f"{arch} stage 1: {r1.seconds:.0f} s, generated-set validation {json.dumps(r1.validation)}")
        kw = dict(FINE_TUNE[arch], **({} if args.steps is None else {"steps": args.steps}))
        r2 = train_on_blob_candidates(arch, n_scenes=args.n_scenes, balanced=not args.plain, init=start, seed=SEED,
                                      num_threads=args.threads, output=out / f"{arch}_trained_here.npz", **kw)
        print(f"{arch} stage 2: {r2.seconds:.0f} s, held-out blob-set validation {json.dumps(r2.validation)}; "
              f"wrote {r2.path}")


if __name__ == "__main__":
    main()
