"""Deep presets (HardNet2 / SOSNet stand-ins, OriNet), run in numpy from the weights shipped with the package.

Most tests need neither torch nor the shared data (one runs the presets in an interpreter where ``import torch``
fails). The comparisons with kornia skip with a reason when torch/kornia are absent; those against the
published ``.pth`` files also when the shared weights folder (``$CTXMATCH_WEIGHTS`` or
``$CTXMATCH_DATA/../weights``) is not set.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from ctxmatch_lib.features import FEATURE_DESCRIPTIONS, FEATURE_PRESETS, FeatureConfig

DEEP = ["sift-hardnet2", "sift-sosnet", "harrisz-hardnet2", "harrisz-sosnet"]


def _weights_dir():
    from ctxmatch_lib.features.deep import weights_dir

    d = weights_dir()
    if d is None or not (d / "HardTFeat.pth").is_file():
        pytest.skip("published weights not found: set CTXMATCH_WEIGHTS (or CTXMATCH_DATA beside a weights/ folder)")
    return d


def _torch():
    torch = pytest.importorskip("torch", reason="torch is not installed (optional extra: pip install 'ctxmatch[kornia]')")
    pytest.importorskip("kornia", reason="kornia is not installed (optional extra: pip install 'ctxmatch[kornia]')")
    return torch


def _shipped(name):
    from ctxmatch_lib.features.deep import load_numpy_net

    return load_numpy_net(name, "auto")[1]


def _patch():
    y, x = np.mgrid[0:32, 0:32].astype(np.float32)
    return (128 + 60 * np.sin(x / 3.0) * np.cos(y / 5.0) + 2.0 * x).astype(np.float32)


def test_deep_presets_say_stand_in_and_name_their_weights():
    for name in DEEP:
        cfg, text = FEATURE_PRESETS[name], FEATURE_DESCRIPTIONS[name]
        assert "stand-in" in text and cfg.weights in text and cfg.orinet_weights in text
        assert cfg.resolved_orientation() == "orinet"
    for name in ("sift-rootsgloh2", "harrisz-rootsift", "harrisz-rootsgloh2"):
        assert FEATURE_PRESETS[name].weights is None
    assert set(FEATURE_DESCRIPTIONS) == set(FEATURE_PRESETS)


def test_cache_key_includes_the_weights_hash_and_the_inference(tmp_path, monkeypatch):
    import ctxmatch_lib.features.deep as deep

    src = deep.resolve_weights("HardTFeat.pth")
    assert src.parent == deep.shipped_weights_dir() and src.name == "HardTFeat.npz"
    copy = tmp_path / "mine.npz"
    shutil.copy(src, copy)
    cfg = FeatureConfig(descriptor="hardnet2", net="hardtfeat", weights=str(copy), orinet_weights="OriNet.pth")
    k1 = cfg.key()
    assert k1 == cfg.key()  # the arrays are hashed, not the zip container
    monkeypatch.setattr(deep, "NUMPY_IMPL", "numpy-test")  # another inference: another key
    assert cfg.key() != k1
    monkeypatch.undo()
    z = dict(np.load(copy))
    z["classifier.1.bias"] = z["classifier.1.bias"] + 1  # same name, other content
    np.savez(copy, **z)
    assert cfg.key() != k1
    copy.unlink()
    with pytest.raises(FileNotFoundError, match="mine.npz"):
        cfg.key()


def test_deep_presets_without_torch(tmp_path):
    """With torch and kornia unimportable, the deep presets run (numpy) and the heat map has its 8 blocks; a
    torch weights file says what to install."""
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['kornia'] = None\n"
        "import numpy as np, ctxmatch_lib\n"
        "from ctxmatch_lib.features import FEATURE_PRESETS, FeatureConfig, extract_features, paper_feature_blocks\n"
        "from skimage.data import camera\n"
        "assert len(paper_feature_blocks()) == 8, paper_feature_blocks()\n"
        "img = camera()[::4, ::4]\n"
        "for n in ('sift-rootsgloh2', 'sift-hardnet2', 'harrisz-sosnet'):\n"
        "    cfg = FeatureConfig(**{**FEATURE_PRESETS[n].__dict__, 'max_keypoints': 100})\n"
        "    f = extract_features(img, cfg, cache_dir=False)\n"
        "    assert len(f) > 20 and np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-5), n\n"
        "open('x.pth', 'wb').write(b'0')\n"
        "try:\n"
        "    extract_features(img, FeatureConfig(detector='harrisz', descriptor='sosnet', net='tfeat',"
        " weights='x.pth', orinet_weights='OriNet.pth'), cache_dir=False)\n"
        "except ImportError as e:\n"
        "    print('deep:', type(e).__name__, e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("CTXMATCH_DATA", "CTXMATCH_WEIGHTS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                         env={**env, "CTXMATCH_CACHE": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    assert "deep: ImportError" in out.stdout and "kornia" in out.stdout


def test_backend_argument_is_checked():
    from ctxmatch_lib.features.deep import describe_patches, orinet_angles

    with pytest.raises(ValueError, match="backend"):
        describe_patches(_patch()[None], "sosnet", net="tfeat", weights="tfeat-liberty.params", backend="jax")
    with pytest.raises(ValueError, match="backend='numpy'"):
        describe_patches(_patch()[None], "sosnet", weights=None, backend="numpy")  # kornia's published SOSNet
    with pytest.raises(ValueError, match="descriptor"):
        describe_patches(_patch()[None], "sift", weights="tfeat-liberty.params")
    assert orinet_angles(np.zeros((40, 40)), np.empty((0, 2)), np.empty((0, 2, 2)), weights="OriNet.pth").shape == (0,)


def test_tfeat_weights_and_known_output():
    """The numpy TFeat (stand-in SOSNet weights) equals a float64 functional re-computation of TFeat."""
    torch = _torch()
    import torch.nn.functional as F

    from ctxmatch_lib.features.deep import describe_patches

    sd = {k: torch.from_numpy(v).double() for k, v in _shipped("tfeat-liberty.params").items()}
    patch = _patch()
    got = describe_patches(patch[None], "sosnet", net="tfeat", weights="tfeat-liberty.params")
    x = torch.from_numpy(patch)[None, None].double()
    x = (x - x.mean()) / torch.sqrt(x.var(unbiased=False) + 1e-5)  # InstanceNorm2d
    x = torch.tanh(F.conv2d(x, sd["features.1.weight"], sd["features.1.bias"]))
    x = F.max_pool2d(x, 2, 2)
    x = torch.tanh(F.conv2d(x, sd["features.4.weight"], sd["features.4.bias"]))
    x = torch.tanh(F.linear(x.flatten(1), sd["descr.0.weight"], sd["descr.0.bias"]))
    ref = (x / x.norm(dim=1, keepdim=True)).numpy()
    assert got.shape == (1, 128) and got.dtype == np.float32
    assert np.allclose(got, ref, atol=1e-5)


def test_hardtfeat_weights_and_known_output():
    """The HardNet2 stand-in (HardTFeat, TFeat architecture with the authors' final tanh) equals a float64
    functional re-computation, in numpy and through the torch module."""
    torch = _torch()
    import torch.nn.functional as F

    from ctxmatch_lib.features.deep import describe_patches, load_descriptor_net

    net = load_descriptor_net("hardnet2", net="hardtfeat", weights="HardTFeat.pth")
    assert not net.training
    sd = {k: torch.from_numpy(v).double() for k, v in _shipped("HardTFeat.pth").items()}
    patch = _patch()
    x = torch.from_numpy(patch)[None, None].double()
    x = (x - x.mean()) / (x.std() + 1e-7)
    x = torch.tanh(F.conv2d(x, sd["features.0.weight"], sd["features.0.bias"]))
    x = F.max_pool2d(x, 2, 2)
    x = torch.tanh(F.conv2d(x, sd["features.3.weight"], sd["features.3.bias"]))
    x = torch.tanh(F.conv2d(x, sd["classifier.1.weight"], sd["classifier.1.bias"])).flatten(1)
    ref = (x / x.norm(dim=1, keepdim=True)).numpy()
    for backend in ("numpy", "torch"):
        got = describe_patches(patch[None], "hardnet2", net="hardtfeat", weights="HardTFeat.pth", backend=backend)
        assert np.allclose(got, ref, atol=1e-5), backend


def test_shipped_npz_are_the_published_weights(tmp_path):
    """The shipped .npz hold the published files' arrays unchanged, and name their origin and copyright."""
    _torch()
    src = _weights_dir()
    from ctxmatch_lib.features.deep import _SHIPPED_SOURCES, export_npz

    for name, (arch, _, notice) in _SHIPPED_SOURCES.items():
        fresh = np.load(export_npz(src / name, tmp_path / "x.npz", arch))
        shipped = np.load(__import__("ctxmatch_lib.features.deep", fromlist=["x"]).resolve_weights(name))
        assert sorted(fresh.files) == sorted(shipped.files)
        assert all(np.array_equal(fresh[k], shipped[k]) for k in fresh.files)
        meta = shipped["__meta__"].item()
        assert notice in meta and '"licence": "MIT"' in meta and name in meta


def test_numpy_inference_equals_kornia():
    """Patches, OriNet angles and descriptors: the numpy path against kornia's sampler and modules."""
    torch = _torch()
    import kornia.feature as KF

    from ctxmatch_lib.features import _nn
    from ctxmatch_lib.features.deep import deep_descriptors, describe_patches, orinet_angles

    rng = np.random.default_rng(0)
    img = (rng.uniform(0, 255, (161, 203)).astype(np.float32))
    import cv2

    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    n = 120
    kp = np.c_[rng.uniform(-5, 208, n), rng.uniform(-5, 166, n)]  # some near or past the border
    ang = rng.uniform(-np.pi, np.pi, n)
    c, s = np.cos(ang), np.sin(ang)
    A = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2) * np.exp(rng.uniform(0, 3.5, n))[:, None, None]
    A[:, :, 0] *= rng.uniform(0.6, 1.4, n)[:, None]  # anisotropic frames, pyramid levels 0-2
    laf = torch.from_numpy(np.concatenate([A, kp[:, :, None]], 2)).float()[None]
    ref = KF.extract_patches_from_pyramid(torch.from_numpy(img / 255)[None, None].float(), laf, 32)[0, :, 0]
    got = _nn.pyramid_patches(img / 255, kp, A)
    assert np.abs(got - ref.numpy()).max() < 1e-4  # kornia's float32 sampling grid
    for desc, net, w in (("hardnet2", "hardtfeat", "HardTFeat.pth"), ("sosnet", "tfeat", "tfeat-liberty.params")):
        same = [describe_patches(got, desc, net=net, weights=w, backend=b) for b in ("numpy", "torch")]
        assert np.abs(same[0] - same[1]).max() < 1e-5
        full = [deep_descriptors(img, kp, A, descriptor=desc, net=net, weights=w, backend=b, support=1.0)
                for b in ("numpy", "torch")]
        assert np.abs(full[0] - full[1]).max() < 2e-4
    a, b = (orinet_angles(img, kp, A, weights="OriNet.pth", support=1.0, backend=be) for be in ("numpy", "torch"))
    assert np.abs(np.angle(np.exp(1j * (a - b)))).max() < 1e-3


def test_orinet_follows_a_quarter_turn():
    """OriNet (OriNet.pth) angles turn with the image: np.rot90 changes them by about -90°."""
    from ctxmatch_lib.features.deep import orinet_angles

    import cv2

    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (121, 121)).astype(np.float32), (0, 0), 2.0)
    kp = np.array([[60.0, 60.0], [40.0, 70.0], [75.0, 45.0]])
    A = np.tile(np.eye(2) * 9.0, (3, 1, 1))
    a = orinet_angles(img, kp, A, weights="OriNet.pth")
    rot = np.rot90(img).copy()
    kp_r = np.c_[kp[:, 1], 120 - kp[:, 0]]  # (x, y) -> (y, W - 1 - x)
    b = orinet_angles(rot, kp_r, A, weights="OriNet.pth")
    diff = np.angle(np.exp(1j * (b - a + np.pi / 2)))
    assert np.all(np.abs(np.degrees(diff)) < 10), np.degrees(diff)


@pytest.mark.parametrize("name", ["sift-sosnet", "harrisz-hardnet2"])
def test_deep_presets_extract(name, tmp_path):
    from skimage.data import camera

    from ctxmatch_lib.features import extract_features

    cfg = FeatureConfig(**{**FEATURE_PRESETS[name].__dict__, "max_keypoints": 150})
    f = extract_features(camera()[::2, ::2], cfg, cache_dir=tmp_path)
    assert 50 < len(f) <= 150 and f.desc.shape == (len(f), 128)
    assert np.allclose(np.linalg.norm(f.desc, axis=1), 1, atol=1e-5)
    assert f.metric == "l2" and np.isfinite(f.angles).all()
    # Oriented shapes: the same ellipses turned by the OriNet angles.
    E = f.shapes @ np.swapaxes(f.shapes, 1, 2)
    assert np.all(np.linalg.det(E) > 0)


def test_shared_steps_kept_for_the_next_block_give_the_same_features(tmp_path):
    # A cold cache: the HarrisZ detections and OriNet angles of harrisz-hardnet2 are kept and read back by
    # harrisz-sosnet and harrisz-rootsift, SIFT's merged detections and OriNet angles of sift-hardnet2
    # by sift-sosnet and sift-rootsgloh2; every block equals its extraction without any cache.
    from skimage.data import camera

    from ctxmatch_lib.features import extract_features

    img = camera()[::2, ::2]
    names = ["harrisz-hardnet2", "harrisz-sosnet", "harrisz-rootsift", "sift-hardnet2", "sift-sosnet",
             "sift-rootsgloh2"]
    cfgs = [FeatureConfig(**{**FEATURE_PRESETS[n].__dict__, "max_keypoints": 120}) for n in names]
    cached = [extract_features(img, c, cache_dir=tmp_path) for c in cfgs]
    kept = sorted(p.parent.name.split("-v")[0] for p in tmp_path.rglob("shared/*/*.npz"))
    # One of each per detector: the later blocks read them back (SIFT's merged detections too).
    assert kept == ["harrisz", "orinet-angles", "orinet-angles", "sift-merged"], kept
    for c, f in zip(cfgs, cached):
        g = extract_features(img, c, cache_dir=False)
        for name in ("kpts", "shapes", "desc", "scales", "angles", "responses"):
            assert getattr(f, name).tobytes() == getattr(g, name).tobytes(), (c.descriptor, name)


@pytest.mark.parametrize("shape,stride", [((3, 10, 9, 16, 16), 1), ((2, 11, 12, 16, 32), 2), ((2, 7, 7, 1, 8), 1)])
def test_direct_conv2d_sums_in_i_j_c_order(shape, stride):
    """The compiled convolution of the few-channel layers (OriNet's first three) forms each output as the
    float64 sum over (i, j, c) in that order, from +0.0, rounded once to float32: the same bits as that sum
    written out in numpy (elementwise float64 operations, the same on any CPU), odd widths (the tail loop)
    included; the patch networks' conv2d takes it for those layers."""
    from ctxmatch_lib.features import _nn
    from ctxmatch_lib.features._conv_kernels import direct_conv2d

    n, h, wd, c, o = shape
    rng = np.random.default_rng(sum(shape))
    x = rng.standard_normal((n, h, wd, c)).astype(np.float32)
    w = (rng.standard_normal((o, c, 3, 3)) * 0.3).astype(np.float32)
    ho, wo = (h - 3) // stride + 1, (wd - 3) // stride + 1
    acc = np.zeros((n, ho, wo, o))
    for i in range(3):
        for j in range(3):
            win = x[:, i : i + stride * (ho - 1) + 1 : stride, j : j + stride * (wo - 1) + 1 : stride].astype(np.float64)
            for ci in range(c):
                acc = acc + win[..., ci, None] * w[:, ci, i, j].astype(np.float64)
    ref = acc.astype(np.float32)
    assert np.array_equal(direct_conv2d(x, w, stride=stride).view(np.int32), ref.view(np.int32))
    b = rng.standard_normal(o).astype(np.float32)
    assert np.array_equal(_nn.conv2d(x, w, b, stride=stride), ref + b)
    with pytest.raises(ValueError, match="multiple of 8"):
        direct_conv2d(x, w[:6], stride=stride)
