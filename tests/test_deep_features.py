"""Deep presets (HardNet2 / SOSNet stand-ins, OriNet) through kornia: the optional torch extra.

Tests that need torch and kornia skip with a reason when they are absent; the stand-in weights are read from
``$CTXMATCH_WEIGHTS`` or ``$CTXMATCH_DATA/../weights`` (the shared weights folder) and skip without it.
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
        pytest.skip("stand-in weights not found: set CTXMATCH_WEIGHTS (or CTXMATCH_DATA beside a weights/ folder)")
    return d


def _torch():
    torch = pytest.importorskip("torch", reason="torch is not installed (optional extra: pip install 'ctxmatch[kornia]')")
    pytest.importorskip("kornia", reason="kornia is not installed (optional extra: pip install 'ctxmatch[kornia]')")
    return torch


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


def test_cache_key_includes_the_weights_hash(tmp_path, monkeypatch):
    src = _weights_dir()
    for f in ("HardTFeat.pth", "OriNet.pth"):
        shutil.copy(src / f, tmp_path / f)
    monkeypatch.setenv("CTXMATCH_WEIGHTS", str(tmp_path))
    cfg = FEATURE_PRESETS["sift-hardnet2"]
    k1 = cfg.key()
    with open(tmp_path / "HardTFeat.pth", "ab") as fh:  # same name, other content
        fh.write(b"\0")
    from ctxmatch_lib.features.deep import _file_sha1

    _file_sha1.cache_clear()
    assert cfg.key() != k1
    (tmp_path / "HardTFeat.pth").unlink()
    with pytest.raises(FileNotFoundError, match="HardTFeat.pth"):
        cfg.key()


def test_import_and_handcrafted_presets_without_torch(tmp_path):
    """With torch unimportable, ctxmatch_lib and the handcrafted presets work; a deep preset says what to install."""
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['kornia'] = None\n"
        "import numpy as np, ctxmatch_lib\n"
        "from ctxmatch_lib.features import FEATURE_PRESETS, extract_features\n"
        "from skimage.data import camera\n"
        "img = camera()[::4, ::4]\n"
        "for n in ('sift-rootsgloh2', 'harrisz-rootsift'):\n"
        "    assert len(extract_features(img, FEATURE_PRESETS[n], cache_dir=False)) > 0\n"
        "try:\n"
        "    extract_features(img, FEATURE_PRESETS['harrisz-sosnet'].__class__(detector='harrisz',"
        " descriptor='sosnet', weights='x.pth'), cache_dir=False)\n"
        "except (ImportError, FileNotFoundError) as e:\n"
        "    print('deep:', type(e).__name__, e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "CTXMATCH_CACHE": str(tmp_path)})
    assert out.returncode == 0, out.stderr
    assert "deep: ImportError" in out.stdout and "kornia" in out.stdout


def test_tfeat_weights_and_known_output():
    """kornia's TFeat with the stand-in SOSNet weights equals a functional re-computation of TFeat."""
    torch = _torch()
    import torch.nn.functional as F

    from ctxmatch_lib.features.deep import describe_patches, resolve_weights

    _weights_dir()
    path = resolve_weights("tfeat-liberty.params")
    sd = torch.load(path, map_location="cpu")
    patch = _patch()
    got = describe_patches(patch[None], "sosnet", net="tfeat", weights="tfeat-liberty.params")
    x = torch.from_numpy(patch)[None, None].double()
    x = (x - x.mean()) / torch.sqrt(x.var(unbiased=False) + 1e-5)  # InstanceNorm2d
    x = torch.tanh(F.conv2d(x, sd["features.1.weight"].double(), sd["features.1.bias"].double()))
    x = F.max_pool2d(x, 2, 2)
    x = torch.tanh(F.conv2d(x, sd["features.4.weight"].double(), sd["features.4.bias"].double()))
    x = torch.tanh(F.linear(x.flatten(1), sd["descr.0.weight"].double(), sd["descr.0.bias"].double()))
    ref = (x / x.norm(dim=1, keepdim=True)).numpy()
    assert got.shape == (1, 128)
    assert np.allclose(got, ref, atol=1e-5)


def test_hardtfeat_weights_and_known_output():
    """The HardNet2 stand-in (HardTFeat.pth, TFeat architecture) equals a functional re-computation."""
    torch = _torch()
    import torch.nn.functional as F

    from ctxmatch_lib.features.deep import describe_patches, load_descriptor_net, resolve_weights

    _weights_dir()
    net = load_descriptor_net("hardnet2", net="hardtfeat", weights="HardTFeat.pth")
    assert not net.training
    sd = torch.load(resolve_weights("HardTFeat.pth"), map_location="cpu", weights_only=False)["state_dict"]
    patch = _patch()
    got = describe_patches(patch[None], "hardnet2", net="hardtfeat", weights="HardTFeat.pth")
    x = torch.from_numpy(patch)[None, None].double()
    x = (x - x.mean()) / (x.std() + 1e-7)
    x = torch.tanh(F.conv2d(x, sd["features.0.weight"].double(), sd["features.0.bias"].double()))
    x = F.max_pool2d(x, 2, 2)
    x = torch.tanh(F.conv2d(x, sd["features.3.weight"].double(), sd["features.3.bias"].double()))
    x = F.conv2d(x, sd["classifier.1.weight"].double(), sd["classifier.1.bias"].double()).flatten(1)
    ref = (x / x.norm(dim=1, keepdim=True)).numpy()
    assert np.allclose(got, ref, atol=1e-5)


def test_orinet_follows_a_quarter_turn():
    """OriNet (OriNet.pth) angles turn with the image: np.rot90 changes them by about -90°."""
    _torch()
    from ctxmatch_lib.features.deep import orinet_angles

    _weights_dir()
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
    _torch()
    _weights_dir()
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
