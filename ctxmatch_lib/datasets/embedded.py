"""The embedded offline default, generated deterministically from ``skimage.data`` into the cache in the
custom format (:func:`embedded_root`, :func:`generate_embedded`): 15 planar pairs (three six-view
sequences, exact ``H``), 4 layered non-planar scenes (exact dense :class:`FlowGT` with occlusion) and the
Middlebury motorcycle stereo pair (:func:`motorcycle_flows`); see ``docs/evaluation.md`` (Datasets).
Rendering: 2× supersampling, area downsampling, pixel centres at integers.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._numerics.fixedmath import opencv_baseline, power, sincos
from .base import FlowGT, PoseGT

__all__ = ["EMBEDDED_VERSION", "MOTORCYCLE_CALIBRATION", "embedded_root", "generate_embedded", "motorcycle_flows",
           "motorcycle_pose_gt"]

# Bump whenever the generated images or ground truth change: a new cache folder is generated.
EMBEDDED_VERSION = 3

VIEW_W, VIEW_H = 640, 480
_SS = 2  # supersampling factor of the renderer


# --------------------------------------------------------------------------------------------- sources
def _photo(name: str) -> np.ndarray:
    """A bundled scikit-image photo as float32 RGB in [0, 1]."""
    from skimage import data

    img = np.asarray(getattr(data, name)())
    img = img.astype(np.float32) if img.dtype == np.bool_ else img.astype(np.float32) / 255.0
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    return np.ascontiguousarray(img[..., :3])


def _resize_h(img: np.ndarray, height: int) -> np.ndarray:
    import cv2

    h, w = img.shape[:2]
    width = int(round(w * height / h))
    interp = cv2.INTER_AREA if height < h else cv2.INTER_CUBIC
    return np.clip(cv2.resize(img, (width, height), interpolation=interp), 0, 1)


def _mosaic(rows: list[list[str]], tile_h: int = 480) -> np.ndarray:
    """Photos side by side (each resized to ``tile_h`` rows), rows stacked, cropped to the narrowest row."""
    built = [np.concatenate([_resize_h(_photo(n), tile_h) for n in row], axis=1) for row in rows]
    width = min(r.shape[1] for r in built)
    return np.ascontiguousarray(np.concatenate([r[:, :width] for r in built], axis=0))


# ------------------------------------------------------------------------------------------- geometry
def _translate(tx, ty):
    return np.array([[1.0, 0, tx], [0, 1.0, ty], [0, 0, 1.0]])


def _similarity(scale, angle_deg):
    s, c = sincos(np.deg2rad(angle_deg))  # np.sin / np.cos round by CPU
    c, s = c * scale, s * scale
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _view_corners(w=VIEW_W, h=VIEW_H):
    return np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float64)


def _quad(center, size, angle_deg, tilt, tilt_axis="x"):
    """Scene quadrilateral a view sees: a rotated rectangle whose one side is shortened by ``tilt``."""
    w, h = size
    c = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    # Foreshortening: the far side (right or bottom) looks shorter; in the scene, the view sees more there.
    if tilt_axis == "x":
        c[[1, 2], 1] *= 1 + tilt
    else:
        c[[2, 3], 0] *= 1 + tilt
    s, co = sincos(np.deg2rad(angle_deg))  # np.sin / np.cos round by CPU
    R = np.array([[co, -s], [s, co]])
    return c @ R.T + np.asarray(center, np.float64)


def _homography(src, dst) -> np.ndarray:
    import cv2

    return cv2.getPerspectiveTransform(np.float32(src), np.float32(dst)).astype(np.float64)


def _apply(H, pts):
    pts = np.asarray(pts, np.float64)
    x, y = pts[:, 0], pts[:, 1]  # column arithmetic: (N, 2) @ (2, 2) products are slow in numpy
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    return np.stack([(H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w], 1)


def _warp(img, G, size=(VIEW_W, VIEW_H), border=0.0):
    """Render ``img`` through ``G`` (image pixels → view pixels) anti-aliased by supersampling."""
    import cv2

    w, h = size
    # The centre of view pixel x is at _SS * x + (_SS - 1) / 2 in the supersampled grid.
    S = np.array([[_SS, 0, (_SS - 1) / 2], [0, _SS, (_SS - 1) / 2], [0, 0, 1.0]])
    big = cv2.warpPerspective(
        img, S @ G, (w * _SS, h * _SS), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
        borderValue=(border, border, border, border),
    )
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


def _to_uint8(img):
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def _save_png(path: Path, rgb01: np.ndarray) -> None:
    import cv2

    img = _to_uint8(rgb01)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), img, [cv2.IMWRITE_PNG_COMPRESSION, 6]):
        raise OSError(f"cannot write image {path}")


# --------------------------------------------------------------------------------------------- planar
@dataclass(frozen=True)
class _PlanarSeq:
    name: str
    photos: tuple  # mosaic rows, or a single photo name
    change: str  # "illumination" | "blur" | "noise"
    angle_sign: float
    tilt_axis: str
    seed: int


_PLANAR = (
    _PlanarSeq("poster", (("astronaut", "coffee"), ("rocket", "chelsea")), "illumination", 1.0, "x", 11),
    _PlanarSeq("lab", (("immunohistochemistry", "coffee"), ("astronaut", "rocket")), "blur", -1.0, "y", 12),
    _PlanarSeq("hubble", "hubble_deep_field", "noise", 1.0, "y", 13),
)


def _planar_views(seq: _PlanarSeq):
    """Scene texture and the scene → view homographies G_1 … G_6 of a sequence."""
    if isinstance(seq.photos, str):
        tex = _photo(seq.photos)
    else:
        tex = _mosaic([list(r) for r in seq.photos])
    th, tw = tex.shape[:2]
    centre = np.array([(tw - 1) / 2, (th - 1) / 2])
    base = min(tw / 1.5, th / 1.5 * VIEW_W / VIEW_H)
    size0 = np.array([base, base * VIEW_H / VIEW_W])
    Gs = []
    for k in range(6):
        t = k / 5
        zoom = 1 + 0.4 * t
        quad = _quad(centre + t * np.array([0.03, -0.02]) * size0, size0 / zoom, seq.angle_sign * 30 * t,
                     0.45 * t, seq.tilt_axis)
        if quad.min() < 0 or (quad[:, 0] > tw - 1).any() or (quad[:, 1] > th - 1).any():
            raise AssertionError(f"embedded sequence {seq.name}: view {k + 1} leaves the scene texture")
        Gs.append(_homography(quad, _view_corners()))
    return tex, Gs


def _photometric(img, change: str, t: float, rng) -> np.ndarray:
    import cv2

    out = img.copy()
    if change == "illumination" and t > 0:
        x = np.linspace(-1, 1, img.shape[1], dtype=np.float32)[None, :, None]
        gain = (1 - 0.45 * t) * (1 + 0.35 * t * x)
        # fixedmath's power, rounded to float32: numpy's float32 ** follows the CPU's SIMD loop.
        out = power(np.clip(out, 0, 1), 1 + 0.6 * t).astype(np.float32) * gain
    elif change == "blur" and t > 0:
        out = cv2.GaussianBlur(out, (0, 0), sigmaX=2.5 * t)
    elif change == "noise" and t > 0:
        out = out + rng.normal(0, 0.05 * t, size=out.shape).astype(np.float32)
    # A touch of sensor noise everywhere but the reference view, so no two images are bit-identical.
    if t > 0:
        out = out + rng.normal(0, 0.004, size=out.shape).astype(np.float32)
    return np.clip(out, 0, 1)


def _write_planar(folder: Path, rows: list) -> None:
    for seq in _PLANAR:
        tex, Gs = _planar_views(seq)
        rng = np.random.default_rng(seq.seed)
        names = []
        for k, G in enumerate(Gs):
            img = _photometric(_warp(tex, G), seq.change, k / 5, rng)
            rel = f"images/planar_{seq.name}_{k + 1}.png"
            _save_png(folder / rel, img)
            names.append(rel)
        for k in range(1, 6):
            H = Gs[k] @ np.linalg.inv(Gs[0])
            H = H / H[2, 2]
            gt = f"gt/planar_{seq.name}_H_1_{k + 1}.txt"
            np.savetxt(folder / gt, H, fmt="%.17g")
            rows.append((f"planar/{seq.name}/1-{k + 1}", names[0], names[k], "planar", gt))


# ------------------------------------------------------------------------------------------ nonplanar
@dataclass
class _Layer:
    tex: np.ndarray  # (h, w, 3) float32
    mask: np.ndarray | None  # (h, w) float32 in [0, 1]; None = opaque everywhere inside the texture
    G1: np.ndarray  # texture → view 1
    G2: np.ndarray  # texture → view 2


def _ellipse_mask(h, w):
    yy, xx = np.mgrid[0:h, 0:w]
    return (((xx - (w - 1) / 2) / (w / 2)) ** 2 + ((yy - (h - 1) / 2) / (h / 2)) ** 2 <= 1).astype(np.float32)


def _star_mask(h, w, spikes=5):
    import cv2

    ang = np.linspace(0, 2 * np.pi, 2 * spikes, endpoint=False) - np.pi / 2
    rad = np.where(np.arange(2 * spikes) % 2 == 0, 0.5, 0.22)
    s, c = sincos(ang)  # np.sin / np.cos round by CPU
    pts = np.c_[(w - 1) / 2 + rad * w * c, (h - 1) / 2 + rad * h * s]
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return m.astype(np.float32)


def _place(tex_shape, view_xy, scale, angle, persp=(0.0, 0.0)):
    """Texture → view homography putting the texture centre at ``view_xy``."""
    h, w = tex_shape[:2]
    P = np.array([[1, 0, 0], [0, 1, 0], [persp[0], persp[1], 1.0]])
    return _translate(*view_xy) @ _similarity(scale, angle) @ P @ _translate(-(w - 1) / 2, -(h - 1) / 2)


def _bg_views(tex, shift2, angle2, zoom2, tilt2):
    th, tw = tex.shape[:2]
    centre = np.array([(tw - 1) / 2, (th - 1) / 2])
    base = min(tw / 1.45, th / 1.45 * VIEW_W / VIEW_H)
    size0 = np.array([base, base * VIEW_H / VIEW_W])
    q1 = _quad(centre, size0, 0.0, 0.0)
    q2 = _quad(centre + np.asarray(shift2) * size0, size0 / zoom2, angle2, tilt2)
    for q in (q1, q2):
        if q.min() < 0 or (q[:, 0] > tw - 1).any() or (q[:, 1] > th - 1).any():
            raise AssertionError("embedded non-planar background view leaves its texture")
    return _homography(q1, _view_corners()), _homography(q2, _view_corners())


def _nonplanar_scenes():
    horse = ~_photo("horse")[..., 0].astype(bool)
    scenes = {}

    bg = _mosaic([["rocket", "coffee"], ["coffee", "rocket"]])
    g1, g2 = _bg_views(bg, (0.04, 0.02), 4.0, 1.08, 0.10)
    cat = _photo("chelsea")[20:290, 80:390]
    scenes["cat"] = [
        _Layer(bg, None, g1, g2),
        _Layer(cat, _ellipse_mask(*cat.shape[:2]), _place(cat.shape, (300, 250), 0.9, -5),
               _place(cat.shape, (390, 230), 1.05, 12, (2e-4, 0))),
    ]

    bg = _mosaic([["astronaut", "rocket"], ["chelsea", "astronaut"]])
    g1, g2 = _bg_views(bg, (-0.03, 0.03), -6.0, 0.95, 0.15)
    coffee = _resize_h(_photo("coffee"), horse.shape[0])[:, : horse.shape[1]]
    scenes["horse"] = [
        _Layer(bg, None, g1, g2),
        _Layer(coffee, horse.astype(np.float32), _place(coffee.shape, (250, 260), 1.0, 0),
               _place(coffee.shape, (360, 280), 1.15, -8, (0, 3e-4))),
    ]

    bg = _photo("hubble_deep_field")
    g1, g2 = _bg_views(bg, (0.02, -0.04), 8.0, 1.12, 0.05)
    card = _photo("camera")[40:440, 60:460]
    coins = _photo("coins")[:, 40:343]
    scenes["cards"] = [
        _Layer(bg, None, g1, g2),
        _Layer(card, None, _place(card.shape, (220, 220), 0.75, 10),
               _place(card.shape, (280, 250), 0.8, -15, (-3e-4, 1e-4))),
        _Layer(coins, _ellipse_mask(*coins.shape[:2]), _place(coins.shape, (450, 300), 0.8, 0),
               _place(coins.shape, (330, 290), 0.95, 25)),
    ]

    bg = _mosaic([["immunohistochemistry", "chelsea"], ["coffee", "immunohistochemistry"]])
    g1, g2 = _bg_views(bg, (0.0, 0.03), 3.0, 1.05, 0.12)
    rocket = _photo("rocket")[:, 100:527]
    scenes["star"] = [
        _Layer(bg, None, g1, g2),
        _Layer(rocket, _star_mask(*rocket.shape[:2]), _place(rocket.shape, (330, 230), 0.7, 0),
               _place(rocket.shape, (310, 250), 1.1, 18, (1.5e-4, -1.5e-4))),
    ]
    return scenes


def _render_layers(layers, view: int):
    out = None
    for layer in layers:
        G = layer.G1 if view == 1 else layer.G2
        tex = _warp(layer.tex, G)
        if out is None:
            out = tex
            continue
        alpha = _warp(layer.mask if layer.mask is not None else np.ones(layer.tex.shape[:2], np.float32), G)
        out = out * (1 - alpha[..., None]) + tex * alpha[..., None]
    return np.clip(out, 0, 1)


def _labels_at(layers, view: int, pts: np.ndarray) -> np.ndarray:
    """Index of the visible layer at each (x, y) view point (-1 where none): the top-most opaque one."""
    from scipy.ndimage import map_coordinates

    labels = np.full(len(pts), -1, np.int64)
    for i, layer in enumerate(layers):
        G = layer.G1 if view == 1 else layer.G2
        uv = _apply(np.linalg.inv(G), pts)
        h, w = layer.tex.shape[:2]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        if layer.mask is not None:
            m = map_coordinates(layer.mask, [uv[:, 1], uv[:, 0]], order=1, mode="constant", cval=0.0)
            inside &= m >= 0.5
        labels[inside] = i
    return labels


def _layer_flow(layers, src: int) -> np.ndarray:
    """Exact dense flow from view ``src`` to the other view, NaN where out of view or occluded."""
    dst = 2 if src == 1 else 1
    yy, xx = np.mgrid[0:VIEW_H, 0:VIEW_W]
    pts = np.c_[xx.ravel(), yy.ravel()].astype(np.float64)
    lab = _labels_at(layers, src, pts)
    target = np.full_like(pts, np.nan)
    for i, layer in enumerate(layers):
        sel = lab == i
        Gs, Gd = (layer.G1, layer.G2) if src == 1 else (layer.G2, layer.G1)
        target[sel] = _apply(Gd @ np.linalg.inv(Gs), pts[sel])
    ok = lab >= 0
    q = np.where(ok[:, None], target, 0.0)
    ok &= (q[:, 0] >= 0) & (q[:, 0] <= VIEW_W - 1) & (q[:, 1] >= 0) & (q[:, 1] <= VIEW_H - 1)
    # Visible in the destination only if the same layer is on top there.
    ok &= _labels_at(layers, dst, q) == lab
    flow = np.where(ok[:, None], target - pts, np.nan)
    return flow.reshape(VIEW_H, VIEW_W, 2).astype(np.float32)


def _write_nonplanar(folder: Path, rows: list) -> None:
    from .custom import write_flow

    for s, (name, layers) in enumerate(sorted(_nonplanar_scenes().items())):
        rng = np.random.default_rng(100 + s)
        rel = []
        for view in (1, 2):
            img = _render_layers(layers, view)
            if view == 2:
                gain = 0.92 + 0.02 * s
                img = np.clip(img * gain + rng.normal(0, 0.008, img.shape).astype(np.float32), 0, 1)
            path = f"images/nonplanar_{name}_{view}.png"
            _save_png(folder / path, img)
            rel.append(path)
        gt = f"gt/nonplanar_{name}_flow.npz"
        write_flow(folder / gt, FlowGT(_layer_flow(layers, 1), _layer_flow(layers, 2)))
        rows.append((f"nonplanar/{name}", rel[0], rel[1], "nonplanar", gt))


# ---------------------------------------------------------------------------------------------- depth
def motorcycle_flows(disp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left → right and right → left flows ``(H, W, 2)`` float32 of a rectified pair from the left disparity
    ``disp`` ``(H, W)`` (NaN/inf unknown): the left pixel (x, y) is the right pixel (x - d, y), checked
    against the images (``stereo_motorcycle``'s docstring reads as the opposite sign).

    ``flow12 = (-d, 0)``; ``flow21`` inverts it per scanline between adjacent left pixels of one surface
    (disparities within 1 px), the nearest surface winning; NaN elsewhere.
    """
    disp = np.asarray(disp, np.float64)
    h, w = disp.shape
    valid = np.isfinite(disp)
    flow12 = np.full((h, w, 2), np.nan, np.float32)
    flow12[valid, 0] = -disp[valid]
    flow12[valid, 1] = 0.0
    flow21 = np.full((h, w, 2), np.nan, np.float32)
    d = np.where(valid, disp, 0.0)
    xr = np.arange(w, dtype=np.float64)[None, :] - d  # right-image position of each left pixel
    seg = valid[:, :-1] & valid[:, 1:] & (np.abs(d[:, 1:] - d[:, :-1]) <= 1.0)
    seg &= xr[:, 1:] > xr[:, :-1]  # a surface steep enough to fold over has no inverse here
    rows, c = np.nonzero(seg)
    a, b = xr[rows, c], xr[rows, c + 1]
    # With |d[c+1] - d[c]| <= 1 a segment spans at most 2 px, so at most 3 integer right pixels.
    cand_r, cand_x, cand_d = [], [], []
    for j in range(3):
        xi = np.ceil(a) + j
        ok = (xi <= b) & (xi >= 0) & (xi <= w - 1)
        f = (xi[ok] - a[ok]) / (b[ok] - a[ok])
        cand_r.append(rows[ok])
        cand_x.append(xi[ok].astype(np.int64))
        cand_d.append(d[rows[ok], c[ok]] + f * (d[rows[ok], c[ok] + 1] - d[rows[ok], c[ok]]))
    cand_r, cand_x, cand_d = map(np.concatenate, (cand_r, cand_x, cand_d))
    if len(cand_r):
        key = cand_r * w + cand_x
        order = np.lexsort((cand_d, key))  # per right pixel, the largest disparity (nearest surface) last
        last = np.r_[key[order][1:] != key[order][:-1], True]
        win = order[last]
        flow21[cand_r[win], cand_x[win], 0] = cand_d[win]
        flow21[cand_r[win], cand_x[win], 1] = 0.0
    return flow12, flow21


#: The calibration scikit-image gives for its (4x downsampled) motorcycle pair (``stereo_motorcycle``'s docstring):
#: focal length and left principal point in pixels, the right principal point ``dx`` further right, the baseline.
MOTORCYCLE_CALIBRATION = {"f": 994.978, "cx": 311.193, "cy": 254.877, "dx": 31.086, "baseline_mm": 193.001}


def motorcycle_pose_gt() -> PoseGT:
    """The motorcycle pair as a calibrated pair (:data:`MOTORCYCLE_CALIBRATION`): rectified, ``R = I``,
    ``t = (-B, 0, 0)`` mm, the right principal point ``dx`` further right (``d = f B / Z - dx``)."""
    c = MOTORCYCLE_CALIBRATION
    K1 = np.array([[c["f"], 0.0, c["cx"]], [0.0, c["f"], c["cy"]], [0.0, 0.0, 1.0]])
    K2 = K1.copy()
    K2[0, 2] += c["dx"]
    return PoseGT(K1, K2, np.eye(3), np.array([-c["baseline_mm"], 0.0, 0.0]), threshold_scale=741 / 1024)


def _write_depth(folder: Path, rows: list) -> None:
    from skimage import data

    from .custom import write_flow

    left, right, disp = data.stereo_motorcycle()
    _save_png(folder / "images/depth_motorcycle_left.png", left.astype(np.float32) / 255.0)
    _save_png(folder / "images/depth_motorcycle_right.png", right.astype(np.float32) / 255.0)
    flow12, flow21 = motorcycle_flows(disp)
    write_flow(folder / "gt/depth_motorcycle_flow.npz", FlowGT(flow12, flow21))
    rows.append(("depth/motorcycle", "images/depth_motorcycle_left.png", "images/depth_motorcycle_right.png",
                 "depth", "gt/depth_motorcycle_flow.npz"))


# ------------------------------------------------------------------------------------------ generation
def generate_embedded(folder) -> Path:
    """Generate the embedded dataset into ``folder`` and return it; bit-identical on any x86-64 CPU."""
    import csv

    folder = Path(folder)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "gt").mkdir(parents=True, exist_ok=True)
    rows: list = []
    with opencv_baseline():  # OpenCV's warps and resizes round by CPU in their SIMD builds
        _write_planar(folder, rows)
        _write_nonplanar(folder, rows)
        _write_depth(folder, rows)
    with open(folder / "pairs.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["pair_id", "image1", "image2", "kind", "gt"])
        w.writerows(rows)
    return folder


def embedded_root(root=None) -> Path:
    """``root/embedded-v<EMBEDDED_VERSION>`` (default root: the ``datasets`` cache), generated if needed
    into a temporary sibling renamed into place (safe against interruption and concurrent runs)."""
    if root is None:
        from ..cache import cache_dir

        root = cache_dir("datasets")
    root = Path(root)
    target = root / f"embedded-v{EMBEDDED_VERSION}"
    if (target / "pairs.csv").is_file():
        return target
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=root))
    try:
        generate_embedded(tmp)
        if target.exists() and not (target / "pairs.csv").is_file():
            shutil.rmtree(target, ignore_errors=True)  # a foreign partial folder
        try:
            os.replace(tmp, target)
        except OSError:
            if not (target / "pairs.csv").is_file():  # not a concurrent winner: a real failure
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return target
