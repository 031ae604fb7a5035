"""Training OANet and ACNe here, on correspondences generated from the embedded images (imports torch).

Reach it through :func:`ctxmatch_lib.filters.learned.train_learned_filter` or ``ctxmatch train oanet|acne``.
The data are those of :mod:`.data` (random homographies and layered non-planar scenes on the embedded
images' SIFT keypoints, planted outliers, inlier ratios 5-60 %), drawn afresh at every step from one seeded
generator; nothing is read from ``CTXMATCH_DATA``. The loss is the binary cross-entropy of every stage's
inlier logits against the labels (OANet: both stages, as the authors' classification loss; ACNe: the output
logits plus, with weight 1, the local-attention logits of every ACN layer, the authors' "multi-logit"
loss). The authors' geometric (essential-matrix) loss is not used: the labels here are exact. Adam,
learning rate ``lr`` with cosine decay to ``lr / 10``.

Runs are deterministic for a given seed and thread count (``num_threads``, default 1).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .checkpoints import save_model
from .data import keypoint_pool, network_input, random_training_set
from .nets import ACNe, build_network

__all__ = ["TRAINED_HERE_CONFIGS", "TRAINED_HERE_STEPS", "TrainResult", "train", "evaluate_generated"]

#: Network shapes of the weights trained here: smaller than the authors' (128 channels, depth 12, 500
#: clusters) so that training fits in minutes on two CPU cores.
TRAINED_HERE_CONFIGS = {
    "oanet": {"net_channels": 48, "net_depth": 8, "clusters": 32, "iter_num": 1, "side_channels": 1},
    "acne": {"net_channels": 48, "net_depth": 6, "num_inner": 2, "groups": 8, "side_channels": 0},
}

#: Steps of the shipped runs (seed 0, batch 8, K in [500, 1500], one thread): what ``steps=None`` means.
TRAINED_HERE_STEPS = {"oanet": 400, "acne": 2000}


@dataclass
class TrainResult:
    """Outcome of :func:`train`."""

    arch: str
    net: torch.nn.Module
    losses: list = field(default_factory=list)  # mean loss of every step
    validation: dict = field(default_factory=dict)  # precision / recall on generated sets
    seconds: float = 0.0
    path: Path | None = None


def _batch(pool, rng, batch_size, k, side):
    xs, ys = [], []
    for _ in range(batch_size):
        s = random_training_set(pool, k, rng)
        xs.append(network_input(s.x1, s.x2, s.scores, s.image_size, s.image_size, side=side))
        ys.append(s.is_inlier)
    return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys).astype(np.float32))


def _loss(net, x, y):
    if isinstance(net, ACNe):
        logits, _, attention = net.forward_all(x)
        loss = F.binary_cross_entropy_with_logits(logits, y)
        if attention:
            loss = loss + torch.stack([F.binary_cross_entropy_with_logits(a, y) for a in attention]).mean()
        return loss
    return torch.stack([F.binary_cross_entropy_with_logits(lg, y) for lg in net(x)]).sum()


def evaluate_generated(net, pool, *, side: str, n_sets: int = 20, n_candidates: int = 1000,
                       inlier_ratio: float = 0.4, seed: int = 12345) -> dict:
    """Pooled precision and recall of ``logit > 0`` on generated sets at a fixed inlier ratio."""
    rng = np.random.default_rng(seed)
    tp = fp = fn = 0
    net.eval()
    with torch.no_grad():
        for _ in range(n_sets):
            s = random_training_set(pool, n_candidates, rng, inlier_ratio=inlier_ratio)
            x = torch.from_numpy(network_input(s.x1, s.x2, s.scores, s.image_size, s.image_size, side=side))
            keep = net(x[None])[-1][0].numpy() > 0
            tp += int((keep & s.is_inlier).sum())
            fp += int((keep & ~s.is_inlier).sum())
            fn += int((~keep & s.is_inlier).sum())
    return {"precision": tp / max(tp + fp, 1), "recall": tp / max(tp + fn, 1), "inlier_ratio": inlier_ratio,
            "n_sets": n_sets, "n_candidates": n_candidates}


def train(arch: str, *, steps: int | None = None, batch_size: int = 8, n_candidates=(500, 1500), lr: float = 1e-3,
          seed: int = 0, config: dict | None = None, output=None, max_images: int | None = None,
          num_threads: int = 1, progress: bool = True, validate: bool = True) -> TrainResult:
    """Train ``arch`` ("oanet" or "acne") from scratch; see :func:`ctxmatch_lib.filters.learned.train_learned_filter`."""
    if arch not in TRAINED_HERE_CONFIGS:
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    steps = TRAINED_HERE_STEPS[arch] if steps is None else steps
    for name, v in (("steps", steps), ("batch_size", batch_size), ("num_threads", num_threads)):
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    k_lo, k_hi = (n_candidates, n_candidates) if np.isscalar(n_candidates) else n_candidates
    if not 8 <= k_lo <= k_hi:
        raise ValueError(f"n_candidates must be an int >= 8 or a (low, high) range, got {n_candidates!r}")
    if not lr > 0:
        raise ValueError(f"lr must be positive, got {lr!r}")
    cfg = dict(TRAINED_HERE_CONFIGS[arch], **(config or {}))
    side = "score_rank" if cfg.get("side_channels", 0) == 1 else "none"
    if cfg.get("side_channels", 0) not in (0, 1):
        raise ValueError("config side_channels must be 0 or 1 for training here")

    old_threads = torch.get_num_threads()
    torch.set_num_threads(int(num_threads))
    t0 = time.perf_counter()
    try:
        pool = keypoint_pool(max_images)
        rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        net = build_network(arch, cfg)
        opt = torch.optim.Adam(net.parameters(), lr=lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps, eta_min=lr / 10)
        losses = []
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=steps, desc=f"train {arch} (trained here)", unit="step")
        net.train()
        for _ in range(steps):
            k = int(rng.integers(k_lo, k_hi + 1))
            x, y = _batch(pool, rng, batch_size, k, side)
            opt.zero_grad()
            loss = _loss(net, x, y)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
            sched.step()
            losses.append(loss.item())
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{np.mean(losses[-20:]):.3f}")
        if bar is not None:
            bar.close()
        net.eval()
        validation = evaluate_generated(net, pool, side=side) if validate else {}
    finally:
        torch.set_num_threads(old_threads)
    seconds = time.perf_counter() - t0
    result = TrainResult(arch, net, losses, validation, seconds)
    if output is not None:
        training = {"steps": steps, "batch_size": batch_size, "n_candidates": [int(k_lo), int(k_hi)], "lr": lr,
                    "seed": seed, "max_images": max_images, "num_threads": num_threads, "seconds": seconds,
                    "final_loss": float(np.mean(losses[-50:])), "validation": validation,
                    "data": "generated from the embedded images (ctxmatch_lib.filters.learned.data)",
                    "torch": str(torch.__version__)}
        result.path = save_model(output, arch, net, training=training, side=side)
    return result
