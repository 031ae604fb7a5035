"""Training OANet and ACNe here (imports torch).

Entry points: :func:`ctxmatch_lib.filters.learned.train_learned_filter`, ``ctxmatch train oanet|acne``.
Loss: binary cross-entropy of every OANet stage, or of ACNe's output plus the mean over its local-attention
logits (the authors' losses); no geometric loss (the labels are exact). Adam, cosine decay to ``lr / 10``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..._numerics.extras import require
from .checkpoints import save_model
from .data import keypoint_pool, network_input, random_training_set
from .nets import ACNe, build_network

torch = require("torch", "torch", "training the learned filters")
F = torch.nn.functional

__all__ = ["TRAINED_HERE_CONFIGS", "TRAINED_HERE_STEPS", "TrainResult", "train", "evaluate_generated",
           "evaluate_blob_sets"]

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


def _blob_batch(sets, rng, batch_size, k_max, side):
    """``batch_size`` random blob sets, each cut to a random subset of K = min(sizes, ``k_max``) rows."""
    chosen = [sets[i] for i in rng.integers(len(sets), size=batch_size)]
    k = min(k_max, min(len(s.x1) for s in chosen))
    xs, ys = [], []
    for s in chosen:
        r = rng.choice(len(s.x1), size=k, replace=False) if len(s.x1) > k else rng.permutation(k)
        xs.append(network_input(s.x1[r], s.x2[r], s.scores[r], s.size1, s.size2, side=side))
        ys.append(s.is_inlier[r])
    return torch.from_numpy(np.stack(xs)), torch.from_numpy(np.stack(ys).astype(np.float32))


def _bce(logits, y, balanced):
    if not balanced:
        return F.binary_cross_entropy_with_logits(logits, y)
    # The OANet / CNe authors' balanced loss: half the positives' mean, half the negatives' (per set).
    per = F.binary_cross_entropy_with_logits(logits, y, reduction="none")
    pos = (per * y).sum(-1) / y.sum(-1).clamp(min=1)
    neg = (per * (1 - y)).sum(-1) / (1 - y).sum(-1).clamp(min=1)
    return (0.5 * (pos + neg)).mean()


def _loss(net, x, y, balanced=False):
    if isinstance(net, ACNe):
        logits, _, attention = net.forward_all(x)
        loss = _bce(logits, y, balanced)
        if attention:
            loss = loss + torch.stack([_bce(a, y, balanced) for a in attention]).mean()
        return loss
    return torch.stack([_bce(lg, y, balanced) for lg in net(x)]).sum()


def _precision_recall(net, labelled_inputs) -> dict:
    """Pooled precision and recall of ``logit > 0`` over ``(input (C, K), is_inlier (K,))`` pairs."""
    tp = fp = fn = 0
    net.eval()
    with torch.no_grad():
        for x, is_inlier in labelled_inputs:
            keep = net(torch.from_numpy(x)[None])[-1][0].numpy() > 0
            tp += int((keep & is_inlier).sum())
            fp += int((keep & ~is_inlier).sum())
            fn += int((~keep & is_inlier).sum())
    return {"precision": tp / max(tp + fp, 1), "recall": tp / max(tp + fn, 1)}


def evaluate_generated(net, pool, *, side: str, n_sets: int = 20, n_candidates: int = 1000,
                       inlier_ratio: float = 0.4, seed: int = 12345) -> dict:
    """Pooled precision and recall of ``logit > 0`` on generated sets at a fixed inlier ratio."""
    rng = np.random.default_rng(seed)
    sets = (random_training_set(pool, n_candidates, rng, inlier_ratio=inlier_ratio) for _ in range(n_sets))
    inputs = ((network_input(s.x1, s.x2, s.scores, s.image_size, s.image_size, side=side), s.is_inlier) for s in sets)
    return {**_precision_recall(net, inputs), "inlier_ratio": inlier_ratio, "n_sets": n_sets,
            "n_candidates": n_candidates}


def evaluate_blob_sets(net, sets, *, side: str) -> dict:
    """Pooled precision and recall of ``logit > 0`` on blob sets (whole sets, every row)."""
    inputs = ((network_input(s.x1, s.x2, s.scores, s.size1, s.size2, side=side), s.is_inlier) for s in sets)
    return {**_precision_recall(net, inputs), "n_sets": len(sets),
            "inlier_ratio": float(np.mean([s.inlier_ratio for s in sets])) if sets else float("nan")}


def _check(arch, steps, batch_size, num_threads, n_candidates, lr, data):
    if arch not in TRAINED_HERE_CONFIGS:
        raise ValueError(f"arch must be 'oanet' or 'acne', got {arch!r}")
    if data not in ("generated", "blob"):
        raise ValueError(f"data must be 'generated' or 'blob', got {data!r}")
    for name, v in (("steps", steps), ("batch_size", batch_size), ("num_threads", num_threads)):
        if not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive int, got {v!r}")
    k_lo, k_hi = (n_candidates, n_candidates) if np.isscalar(n_candidates) else n_candidates
    if not 8 <= k_lo <= k_hi:
        raise ValueError(f"n_candidates must be an int >= 8 or a (low, high) range, got {n_candidates!r}")
    if not lr > 0:
        raise ValueError(f"lr must be positive, got {lr!r}")
    return int(k_lo), int(k_hi)


def _check_blob_sets(blob_sets):
    """``(train_sets, val_sets, info)`` of ``data="blob"``, checked."""
    if blob_sets is None:
        raise ValueError("data='blob' needs blob_sets=(train_sets, val_sets, info): build them with "
                         "ctxmatch_lib.training.blob_training_sets, or train with "
                         "ctxmatch_lib.training.train_on_blob_candidates")
    train_sets, val_sets, info = blob_sets
    if not len(train_sets):
        raise ValueError("blob_sets holds no training set")
    return list(train_sets), list(val_sets), dict(info)


def train(arch: str, *, steps: int | None = None, batch_size: int = 8, n_candidates=(500, 1500), lr: float = 1e-3,
          seed: int = 0, config: dict | None = None, output=None, max_images: int | None = None,
          num_threads: int = 1, progress: bool = True, validate: bool = True, data: str = "generated",
          balanced: bool = False, init=None, blob_sets=None) -> TrainResult:
    """Train ``arch``; see :func:`ctxmatch_lib.filters.learned.train_learned_filter` (``blob_sets``: of
    :class:`ctxmatch_lib.training.BlobSet`)."""
    steps = TRAINED_HERE_STEPS[arch] if steps is None and arch in TRAINED_HERE_STEPS else steps
    k_lo, k_hi = _check(arch, steps, batch_size, num_threads, n_candidates, lr, data)
    cfg = dict(TRAINED_HERE_CONFIGS[arch], **(config or {}))
    side = "score_rank" if cfg.get("side_channels", 0) == 1 else "none"
    if cfg.get("side_channels", 0) not in (0, 1):
        raise ValueError("config side_channels must be 0 or 1 for training here")

    old_threads = torch.get_num_threads()
    torch.set_num_threads(int(num_threads))
    t0 = time.perf_counter()
    try:
        if data == "blob":
            train_sets, val_sets, blob_info = _check_blob_sets(blob_sets)
            draw = lambda rng: _blob_batch(train_sets, rng, batch_size, k_hi, side)  # noqa: E731
        else:
            pool = keypoint_pool(max_images)
            draw = lambda rng: _batch(pool, rng, batch_size, int(rng.integers(k_lo, k_hi + 1)), side)  # noqa: E731
        rng = np.random.default_rng(seed)
        torch.manual_seed(seed)
        net = build_network(arch, cfg)
        if init is not None:
            _load_init(net, arch, init)
        losses = _optimise(net, draw, rng, steps, lr, balanced, f"train {arch} (trained here)" if progress else None)
        net.eval()
        validation = {}
        if validate:
            validation = evaluate_blob_sets(net, val_sets, side=side) if data == "blob" else \
                evaluate_generated(net, pool, side=side)
    finally:
        torch.set_num_threads(old_threads)
    seconds = time.perf_counter() - t0
    result = TrainResult(arch, net, losses, validation, seconds)
    if output is not None:
        training = {"steps": steps, "batch_size": batch_size, "n_candidates": [k_lo, k_hi], "lr": lr,
                    "seed": seed, "num_threads": num_threads, "seconds": seconds, "balanced_loss": balanced,
                    "final_loss": float(np.mean(losses[-50:])), "validation": validation,
                    "torch": str(torch.__version__), "init": _init_record(init)}
        if data == "blob":
            training.update(data="blob candidates of generated pairs (ctxmatch_lib.training.blobsets)",
                            n_train_sets=len(train_sets), n_val_sets=len(val_sets), **blob_info)
        else:
            training.update(data="generated from the embedded images (ctxmatch_lib.filters.learned.data)",
                            max_images=max_images)
        result.path = save_model(output, arch, net, training=training, side=side)
    return result


def _load_init(net, arch, init) -> None:
    """Start from the weights in ``init`` (fine-tuning); their network shape must be ``net``'s."""
    from .checkpoints import load_model

    src = load_model(arch, init).net
    if src.config != net.config:
        raise ValueError(f"init weights {init} have the shape {src.config}, not {net.config}")
    net.load_state_dict(src.state_dict())


def _init_record(init):
    if init is None:
        return None
    import hashlib

    path = Path(init)
    return {"file": path.name, "sha1": hashlib.sha1(path.read_bytes()).hexdigest() if path.is_file() else None}


def _optimise(net, draw, rng, steps, lr, balanced, desc) -> list:
    """Adam with cosine decay to ``lr / 10``, gradient norm clipped at 10; returns the loss of every step."""
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps, eta_min=lr / 10)
    losses = []
    bar = None
    if desc is not None:
        from tqdm.auto import tqdm

        bar = tqdm(total=steps, desc=desc, unit="step")
    net.train()
    for _ in range(steps):
        x, y = draw(rng)
        opt.zero_grad()
        loss = _loss(net, x, y, balanced)
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
    return losses
