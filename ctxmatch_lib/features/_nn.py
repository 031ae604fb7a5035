"""numpy inference of the patch networks of :mod:`.deep` (TFeat, HardTFeat, OriNet) and kornia's patch sampling.

float32 on ``(N, H, W, C)`` arrays, parameters named as in the torch ``state_dict``; products are formed in
float64 and rounded once, so the numbers do not depend on the BLAS kernel or thread count.
"""

from __future__ import annotations

import numpy as np

from .._numerics import fixedmath as _fixedmath
from .._numerics import fixedmath_kernels as _fixedmath_kernels
from .._numerics.blas import one_blas_thread
from ._conv_kernels import direct_conv2d

__all__ = ["conv2d", "tfeat", "hardtfeat", "orinet", "pyramid_patches", "NETS"]

_F32 = np.float32


def _tanh(x: np.ndarray) -> np.ndarray:
    """float32 ``tanh`` from float64 fixedmath, rounded once (numpy's follows its SIMD loop)."""
    return _fixedmath_kernels.tanh_f32(x)


def conv2d(x: np.ndarray, w: np.ndarray, b: np.ndarray | None = None, *, stride: int = 1,
           padding: int = 0) -> np.ndarray:
    """2-D cross-correlation of ``x`` (N, H, W, C) with torch-layout weights ``w`` (O, C, kh, kw) -> (N, H', W', O).

    An ``im2col`` product, or :func:`._conv_kernels.direct_conv2d` where the im2col copy costs more (OriNet).
    """
    if padding:
        x = np.pad(x, ((0, 0), (padding, padding), (padding, padding), (0, 0)))
    o, c, kh, kw = w.shape
    if c <= 16 and kh * kw <= 9 and o % 8 == 0:
        out = direct_conv2d(x, w, stride=stride)
        if b is not None:
            out += b
        return out
    n, h, wd = x.shape[:3]
    ho, wo = (h - kh) // stride + 1, (wd - kw) // stride + 1
    # float64 at once (exact): the product's operand without a second copy.
    cols = np.empty((n, ho, wo, kh, kw, c), np.float64)
    for i in range(kh):
        for j in range(kw):
            rows, cols_j = slice(i, i + stride * (ho - 1) + 1, stride), slice(j, j + stride * (wo - 1) + 1, stride)
            cols[:, :, :, i, j, :] = x[:, rows, cols_j]
    out = _product(cols.reshape(n * ho * wo, kh * kw * c), w.transpose(0, 2, 3, 1).reshape(o, -1).T)
    if b is not None:
        out += b
    return out.reshape(n, ho, wo, o)


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` of float32 matrices in float64, rounded once to float32 (same on any CPU, docs/features.md)."""
    return (a.astype(np.float64, copy=False) @ b.astype(np.float64)).astype(np.float32)


def _chunked(fn):
    # Chunks of exactly `chunk` patches (the last zero-padded; the im2col buffers stay in cache) on one BLAS
    # thread: OpenBLAS picks its kernel by shape and threads, and a descriptor must not depend on either.
    def run(p: dict, patches: np.ndarray, chunk: int = 16) -> np.ndarray:
        patches = np.asarray(patches, np.float32)
        if not len(patches):
            return fn(p, patches)
        buf = np.zeros((chunk, *patches.shape[1:]), np.float32)
        out = []
        with one_blas_thread():
            for s in range(0, len(patches), chunk):
                part = patches[s : s + chunk]
                buf[: len(part)] = part
                buf[len(part) :] = 0
                out.append(fn(p, buf)[: len(part)])
        return np.concatenate(out)

    run.__doc__, run.__name__, run.__wrapped__ = fn.__doc__, fn.__name__, fn
    return run


def _max_pool2(x: np.ndarray) -> np.ndarray:
    """2×2 max pooling, stride 2 (an odd last row or column is dropped, as torch does)."""
    h, w = x.shape[1] // 2 * 2, x.shape[2] // 2 * 2
    return np.maximum(np.maximum(x[:, 0:h:2, 0:w:2], x[:, 0:h:2, 1:w:2]),
                      np.maximum(x[:, 1:h:2, 0:w:2], x[:, 1:h:2, 1:w:2]))


def _standardise(p: np.ndarray, eps: float, *, unbiased: bool, inside: bool) -> np.ndarray:
    """Per-patch ``(p - mean) / (std + eps)`` (``inside=False``) or ``/ sqrt(var + eps)`` (instance norm);
    statistics accumulated in float64, as torch does on the CPU."""
    q = p.reshape(len(p), -1).astype(np.float64)
    mean = q.mean(axis=1)
    var = q.var(axis=1, ddof=1 if unbiased else 0)
    den = np.sqrt(var + eps) if inside else np.sqrt(var) + eps
    return ((p - mean.astype(_F32)[:, None, None]) / den.astype(_F32)[:, None, None])[..., None]


def _batch_norm(p: dict, name: str, x: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    # Evaluation mode: running statistics; OriNet's batch norms have no affine part.
    scale = 1.0 / np.sqrt(p[name + ".running_var"] + _F32(eps))
    if name + ".weight" in p:
        scale = scale * p[name + ".weight"]
    shift = -p[name + ".running_mean"] * scale
    if name + ".bias" in p:
        shift = shift + p[name + ".bias"]
    return x * scale + shift


@_chunked
def tfeat(p: dict, patches: np.ndarray) -> np.ndarray:
    """TFeat (Balntas et al., BMVC 2016) of ``(N, 32, 32)`` patches -> ``(N, 128)`` (kornia's ``TFeat`` layout)."""
    x = _standardise(patches, 1e-5, unbiased=False, inside=True)
    x = _tanh(_max_pool2(conv2d(x, p["features.1.weight"], p["features.1.bias"])))  # tanh is monotonic
    x = _tanh(conv2d(x, p["features.4.weight"], p["features.4.bias"]))
    flat = x.transpose(0, 3, 1, 2).reshape(len(x), -1)  # torch's (C, H, W) flattening
    return _tanh(_product(flat, p["descr.0.weight"].T) + p["descr.0.bias"])


@_chunked
def hardtfeat(p: dict, patches: np.ndarray) -> np.ndarray:
    """HardTFeat (TFeat trained with the HardNet loss; the authors' ``HardTFeatNet``), ``(N, 32, 32)`` ->
    ``(N, 128)``."""
    x = _standardise(patches, 1e-7, unbiased=True, inside=False)
    x = _tanh(_max_pool2(conv2d(x, p["features.0.weight"], p["features.0.bias"])))  # tanh is monotonic
    x = _tanh(conv2d(x, p["features.3.weight"], p["features.3.bias"]))
    return _tanh(conv2d(x, p["classifier.1.weight"], p["classifier.1.bias"]).reshape(len(x), -1))


#: (conv index, stride) of OriNet's six conv + batch norm + ReLU layers (3×3, padding 1, no bias).
_ORINET_LAYERS = ((0, 1), (3, 1), (6, 2), (9, 1), (12, 2), (15, 1))


@_chunked
def orinet(p: dict, patches: np.ndarray) -> np.ndarray:
    """OriNet (Mishkin et al., ECCV 2018) of ``(N, 32, 32)`` patches: the angle in radians (kornia's ``OriNet``)."""
    x = _standardise(patches, 1e-6, unbiased=True, inside=False)
    for i, stride in _ORINET_LAYERS:
        x = conv2d(x, p[f"features.{i}.weight"], stride=stride, padding=1)
        x = np.maximum(_batch_norm(p, f"features.{i + 1}", x), _F32(0))
    xy = _tanh(conv2d(x, p["features.19.weight"], p["features.19.bias"], padding=1)).mean(axis=(1, 2))
    return _fixedmath.atan2(xy[:, 0] + _F32(1e-8), xy[:, 1] + _F32(1e-8)).astype(_F32)


NETS = {"tfeat": tfeat, "hardtfeat": hardtfeat, "orinet": orinet}


def _pyrdown(img: np.ndarray) -> np.ndarray:
    """kornia's ``pyrdown``: 5×5 binomial blur (reflect-101 border), bilinear resize to ``floor(side / 2)``
    with ``align_corners=False``."""
    import cv2

    k = np.array([1, 4, 6, 4, 1], np.float32) / 16
    blur = cv2.sepFilter2D(img, cv2.CV_32F, k, k, borderType=cv2.BORDER_REFLECT_101)
    h, w = img.shape
    for axis, (n_in, n_out) in enumerate(((h, h // 2), (w, w // 2))):
        src = np.maximum((np.arange(n_out, dtype=np.float32) + _F32(0.5)) * _F32(n_in / n_out) - _F32(0.5), 0)
        i0 = src.astype(np.int64)
        i1 = np.minimum(i0 + 1, n_in - 1)
        lam = (src - i0).astype(np.float32)
        if axis == 0:
            blur = blur[i0] * (1 - lam)[:, None] + blur[i1] * lam[:, None]
        else:
            blur = blur[:, i0] * (1 - lam) + blur[:, i1] * lam
    return np.ascontiguousarray(blur, np.float32)


def _levels(h: int, w: int, ps: int) -> list[tuple[int, int]]:
    # The levels kornia builds: halve while the shorter side stays >= ps, at most min(h, w) // ps levels.
    sizes = [(h, w)]
    for _ in range(1, max(1, min(h, w) // ps)):
        hl, wl = sizes[-1]
        if min(hl, wl) <= 2 or min(hl // 2, wl // 2) < ps:
            break
        sizes.append((hl // 2, wl // 2))
    return sizes


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # Bilinear interpolation at (x, y) clamped to the pixel centres: outside, the border pixel is read.
    from scipy.ndimage import map_coordinates

    h, w = img.shape
    return map_coordinates(img, [np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], order=1, mode="nearest",
                           prefilter=False)


def pyramid_patches(img: np.ndarray, kpts: np.ndarray, A: np.ndarray, ps: int = 32) -> np.ndarray:
    """Square patches sampled as kornia's ``extract_patches_from_pyramid`` samples LAFs ``[A | kpt]``.

    Cell ``(i, j)`` of the ``(N, ps, ps)`` result samples ``kpt + A @ (u_j, u_i)``, ``u_k = (2k + 1) / ps - 1``,
    bilinearly from level ``floor(log2(2 sqrt|det A| / ps))`` (clamped); outside, the border pixel is read.
    """
    img = np.ascontiguousarray(img, np.float32)
    h, w = img.shape
    kpts = np.asarray(kpts, np.float64)
    A = np.asarray(A, np.float64)
    u = (2 * np.arange(ps) + 1) / ps - 1
    px = kpts[:, 0, None, None] + A[:, 0, 0, None, None] * u[None, None, :] + A[:, 0, 1, None, None] * u[None, :, None]
    py = kpts[:, 1, None, None] + A[:, 1, 0, None, None] * u[None, None, :] + A[:, 1, 1, None, None] * u[None, :, None]
    sizes = _levels(h, w, ps)
    # det written out and the level from the binary exponent: LAPACK and np.log2 round by CPU.
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    scale = np.sqrt(np.abs(det) + 1e-10)
    arg = 2 * scale / ps
    level = np.clip(_fixedmath.floor_log2(np.where(np.isfinite(arg), arg, 1.0)), 0, len(sizes) - 1)
    out = np.zeros((len(kpts), ps, ps), np.float32)
    ok = np.isfinite(px).all(axis=(1, 2)) & np.isfinite(py).all(axis=(1, 2))  # a non-finite frame: zero patch
    cur = img
    for lv, (hl, wl) in enumerate(sizes):
        if lv:
            cur = _pyrdown(cur)
        sel = np.flatnonzero((level == lv) & ok)
        if len(sel):
            out[sel] = _bilinear(cur, (px[sel] + 0.5) * (wl / w) - 0.5, (py[sel] + 0.5) * (hl / h) - 0.5)
    return out
