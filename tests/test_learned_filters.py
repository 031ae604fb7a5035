"""Tests of the learned filters OANet and ACNe (weights trained here) behind ``FILTERS``.

The filters run in numpy (``npnets``): the first tests need no torch (one runs the filters in an interpreter
where ``import torch`` fails); those comparing with the torch modules, or training, skip with a reason when
torch is absent (``pytest.importorskip``). The published-format tests build checkpoints laid
out as the authors' releases lay them out: OANet's ``state_dict`` names and shapes follow zjhthu/OANet
``core/oan.py``; the ACNe TensorFlow checkpoint below was written by TensorFlow 2.21 itself
(``tf.raw_ops.SaveV2``, the op behind ``tf.train.Saver``) with the variable names of vcg-uvic/acne, and is
embedded here zlib-compressed and base64-encoded.
"""

from __future__ import annotations

import base64
import subprocess
import sys
import zlib

import numpy as np
import pytest

from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.testing import planted_homography_matches

ARCHS = ["oanet", "acne"]
SIZE = (640, 480)

_TF_INDEX_Z = (
    "eNpjYGDjYJRi4mBkMBDyTSxJzshLLdHPyExJSc3TNdBPzs8r000qSsxLzgCzDfXT8+Lz8oty9ZNSSxI5GIVYhJg4OBRWsGgomN6c"
    "yV+vwyqUnpibi5DpAMnYVH68psIvVJRanpqZnlGin5SZWJxaDFXDpNDAosFheni6prouuxxEBUhOACjHCMUcYHUHmDUcTGepL+VR"
    "ERAqTs1J0wW5CNUwDoUFzEALtyy/aqLHLo/bMKA6Ro0GJtPoR8JHTVnl9R1TEnOxKjvBAlL28y73ZCU+ISPsvr/ACbQyKWIfH4bv"
    "N4BkOl1ur8Dj+xWcQN9fUFzrRMD3LziAvm/z234Yn+9PcAAtlJRqSiDg+xNsIG/JL3Bow+v7D5wgZUHqSxMFxIQy8wpKS/RxWt3A"
    "CLQ650KrK4O6DHpCQteK3WlgczQaGE1NWqp7OeWEcvLTM0vii/PTSnITK3BZzKgwgUeDxVRS7VuVIr4AZFT4wA10YMTn+jhOcaH8"
    "0hI8nmFU2AIyc5H+l7tS+M2cwgM0cxvH/9sM3HygNGEYX5BfnloEVMGgcABkxt/Xx+8D5dJz8pMSc+KLS1ILODiBcjt4gJGezlcY"
    "xgAEQUwMDEwgRt3Vpl8gmhFEHPi0cAMDI3MGQzc7XOz75lUHJ7BzzGXnZyAIwn83dKuUut8GAHsy5wQ="
)
_TF_DATA_Z = (
    "eNod0T1w2mYcx3HxLtQkFSBAuCmW67zYSw+cpUMkPU/SO2fIAF66MJBFSxeJd+xFfqHNdRFDh9pDL3fJzMxo49VeurCarvVK5nxT"
    "3/l0p9/z+3/+PFIURdGW2y+15ceX0WLNc9u+vXlrR4u+vduKbN7b9805727s2f6K92t7Xk05u61vnYvzisN558j40blv/uS0olcO"
    "XcfWfnFm+++czcmvDnMcRQmdeXXiBPYf9CJndfgn3XPnYP7318yd7R+7rejE1ZanLudcz/vNNWa/u9fr9y7rieVHRcz2Y2LyX0y0"
    "orh48SIhtGVCrA6Tgl1EtEgJz0sLW8sIY5YR901VXK9VcXGeFYGtiTcrTWxOvhGfdx6I25sH4pP/UBwZj8TB/JHgdwhF0TF0jBxG"
    "DiOPUcAoYBgYRYwiRgmjjFHGMDFMjArGBsYGxncYjzEeY3yPUcWoYmxiWBgWxhbGFsYPGNsY2xhPMJ5iPMV4hvEc4znGDj1BT9CT"
    "9CS9V/Re03tN72fykHMhZ0L2CTl3zE7HnD1mrxPOn7DbCZ1T9juld8qOZ3TP2POM/gf6H3he8rxkziVzLplzxZwr5lwxZ0F+R35H"
    "fkd+R74iX5GvyP8lV+TnHUXeNxW5OlQk30ze3ijyeq3IeTUm+X7ykx+TF+cxGS1ikm8pj4y4DOy49Ly45LvKg3lcvlnFpa0lJN9Y"
    "7rYScnOSkMYsIfneUlGSGEmMJEYSI4mRxEhipDBSGCmMFEYKI4WRxkhjpDHSGGmMNEYGI4ORwchgZDAyGCqGiqFiqBgqhoqhYmQx"
    "shhZjCxGFiOLodHT6en0dHo6PZ2eTk+nl6OXo5ejl6OXo5ejl2e3PLvl2S3Pbnl2y7Nbgd0K7FZgtwK7FditgGFgGBgGhoFhYBgY"
    "BkYRo4hRxChiFDGKGCWMEkYJo4RRwihhlDHKGGWMMkYZo4xhYpgYJoaJYWKYGCZGBaOCUcGoYFQwKhgb9Cx6Fj2LnkXPomfRs+ht"
    "kdfIa+Q18hp5jbxGXiOvM7fO3Dpz68ytM7fO3D1232P3PfqCvuDZ4NlgToM5DeY0mNNgToM5TfI2eZu8Td4mb5O3ydvk78h9cp/c"
    "J/fJfXKf3CcP2CNgj4A9AvYI2CNgjw57dNijwx12uMMOd9jhDrvcYZc77HKHXe6wyx12MXoYPYweRg+jh9HD6GH0MfoYfYw+Rh+j"
    "jzHAGGAMMAYYA4wBxhBjiDHEGGIMMYYYI4wRxghjhDHCGGGMMMYYY4wxxhhjjDHGOKQX8gzphngh/RAzZEaIG5K/53/KmSlnppyZ"
    "cmbKmSlnppyZkv8l/0kq//95nud+ARdEVEM="
)


@pytest.fixture(scope="module")
def torch():
    return pytest.importorskip("torch", reason="torch is not installed (pip install torch==2.13.0): learned "
                                               "filters not tested")


def _run(name, pm, **kw):
    return FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, pm.scores, image_size1=pm.image_size,
                         image_size2=pm.image_size, **kw)


# ------------------------------------------------------------------------------------- without torch
def test_filters_run_without_torch(tmp_path):
    # A fresh interpreter where ``import torch`` fails: the registry lists the learned filters, "all" includes
    # them, they run (K = 0..3 and a planted set; the ACNe authors' TF format too); training and torch
    # checkpoints raise ImportError with the install hint.
    prefix = _write_tf_fixture(tmp_path)
    code = f"""
import sys; sys.modules['torch'] = None; sys.modules['kornia'] = None
import numpy as np
from ctxmatch_lib.filters import FILTERS
from ctxmatch_lib.evaluation import resolve_filters
from ctxmatch_lib.filters.learned import torch_available, train_learned_filter
from ctxmatch_lib.testing import planted_homography_matches
assert not torch_available()
assert 'oanet' in list(FILTERS) and 'acne' in resolve_filters('all') and 'oanet' in resolve_filters('all')
pm = planted_homography_matches(400, 0.4, rng=1)
for name in ('oanet', 'acne'):
    for k in (0, 1, 2, 3, 400):
        keep = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches[:k], pm.scores[:k], image_size1=(640, 480),
                             image_size2=(640, 480))
        assert keep.dtype == bool and keep.shape == (k,), (name, k, keep)
    assert (keep & pm.is_inlier).sum() > 0.8 * keep.sum(), name
keep = FILTERS['acne'](pm.kpts1, pm.kpts2, pm.matches, None, image_size1=(640, 480), image_size2=(640, 480),
                       weights={str(prefix)!r})
assert keep.shape == (400,)
for call in (lambda: train_learned_filter('acne', steps=1),
             lambda: FILTERS['oanet'](pm.kpts1, pm.kpts2, pm.matches, None, image_size1=(640, 480),
                                      image_size2=(640, 480), weights={str(tmp_path / "x.pt")!r})):
    try:
        call()
    except ImportError as e:
        assert "pip install 'ctxmatch[torch]'" in str(e), str(e)
    else:
        raise AssertionError('no ImportError')
print('ok')
"""
    (tmp_path / "x.pt").write_bytes(b"not read")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


@pytest.mark.parametrize("name", ARCHS)
@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_tiny_candidate_sets(name, k):
    # K = 1 used to crash in torch's instance norm; with one candidate the context normalisation gives 0.
    from ctxmatch_lib.filters.learned import learned_logits

    pm = planted_homography_matches(5, 1.0, rng=9)
    m, s = pm.matches[:k], pm.scores[:k]
    keep = FILTERS[name](pm.kpts1, pm.kpts2, m, s, image_size1=SIZE, image_size2=SIZE)
    assert keep.dtype == bool and keep.shape == (k,)
    lg = learned_logits(name, pm.kpts1, pm.kpts2, m, s, image_size1=SIZE, image_size2=SIZE)
    assert lg.shape == (k,) and np.isfinite(lg).all()


def test_score_rank_and_normalisation():
    from ctxmatch_lib.filters.learned.data import normalise_coordinates, score_rank

    np.testing.assert_allclose(score_rank(np.array([0.3, 0.1, 0.3, 0.9])), [0.5, 0.0, 0.5, 1.0])
    np.testing.assert_allclose(score_rank(np.zeros(4)), 0.5)
    # The image centre goes to 0, the longer side spans [-1, 1] (pixel edges), the aspect ratio is kept.
    p = normalise_coordinates(np.array([[-0.5, -0.5], [319.5, 239.5], [639.5, 479.5]]), (640, 480))
    np.testing.assert_allclose(p, [[-1, -0.75], [0, 0], [1, 0.75]])


def test_tf_bundle_reader_on_a_tensorflow_written_checkpoint(tmp_path):
    from ctxmatch_lib.filters.learned.tfbundle import read_tf_checkpoint, write_tf_checkpoint

    prefix = _write_tf_fixture(tmp_path)
    t = read_tf_checkpoint(prefix.with_name(prefix.name + ".index"))
    names = _tf_fixture_names()
    assert sorted(t) == sorted(names)
    for i, (name, shape) in enumerate(names.items()):
        if name == "global_step":
            assert t[name].dtype == np.int64 and t[name].shape == () and t[name] == 1234
        elif name == "beta1_power":
            assert t[name].dtype == np.float32 and t[name].shape == () and t[name] == np.float32(0.9)
        else:
            expect = (np.arange(int(np.prod(shape))).reshape(shape) * 0.01 + i).astype(np.float32)
            np.testing.assert_array_equal(t[name], expect)
    # Our writer round-trips through our reader (TensorFlow reads it too; checked when it was written).
    write_tf_checkpoint(tmp_path / "copy", t)
    back = read_tf_checkpoint(tmp_path / "copy")
    assert all(np.array_equal(back[k], t[k]) and back[k].dtype == t[k].dtype for k in t)
    with pytest.raises(ValueError, match="not a TensorFlow checkpoint"):
        (tmp_path / "bad.index").write_bytes(b"\0" * 64)
        read_tf_checkpoint(tmp_path / "bad.index")


def _tf_fixture_names() -> dict:
    c = 8
    names = {"Matchnet/hidden-input/self-conv/weights": (1, 1, 4, c), "Matchnet/hidden-input/self-conv/biases": (c,)}
    for j in (1, 2):
        t = f"Matchnet/hidden-0/conv-branch/conv{j}"
        names.update({f"{t}/self-conv/weights": (1, 1, c, c), f"{t}/self-conv/biases": (c,),
                      f"{t}/reweight/weights": (1, 1, c, 2), f"{t}/reweight/biases": (2,),
                      f"{t}/gn_norm/gamma": (c,), f"{t}/gn_norm/beta": (c,),
                      f"{t}/self-conv/weights/Adam": (1, 1, c, c)})
    for n in ("logit_softmax", "output"):
        names.update({f"Matchnet/{n}/self-conv/weights": (1, 1, c, 1), f"Matchnet/{n}/self-conv/biases": (1,)})
    names.update({"global_step": (), "beta1_power": ()})
    return names


def _write_tf_fixture(folder):
    prefix = folder / "model.ckpt-1234"
    prefix.with_name(prefix.name + ".index").write_bytes(zlib.decompress(base64.b64decode("".join(_TF_INDEX_Z))))
    prefix.with_name(prefix.name + ".data-00000-of-00001").write_bytes(
        zlib.decompress(base64.b64decode("".join(_TF_DATA_Z))))
    (folder / "checkpoint").write_text('model_checkpoint_path: "model.ckpt-1234"\n'
                                       'all_model_checkpoint_paths: "model.ckpt-1234"\n')
    return prefix


# ------------------------------------------------------------------------------------------ with torch
@pytest.mark.parametrize("name", ARCHS)
def test_shapes_empty_and_bad_input(torch, name):
    pm = planted_homography_matches(57, 0.4, rng=1)
    keep = _run(name, pm)
    assert keep.dtype == bool and keep.shape == (57,)
    empty = FILTERS[name](pm.kpts1, pm.kpts2, np.empty((0, 2), np.int64), None, image_size1=SIZE, image_size2=SIZE)
    assert empty.dtype == bool and empty.shape == (0,)
    with pytest.raises(ValueError, match="matches"):
        FILTERS[name](pm.kpts1, pm.kpts2, pm.matches[:, :1], None, image_size1=SIZE, image_size2=SIZE)
    with pytest.raises(ValueError, match="threshold"):
        _run(name, pm, threshold=float("nan"))
    with pytest.raises(FileNotFoundError):
        _run(name, pm, weights="/nonexistent/weights.pt")


@pytest.mark.parametrize("name", ARCHS)
def test_permutation_equivariance(torch, name):
    from ctxmatch_lib.filters.learned import learned_logits

    pm = planted_homography_matches(800, 0.3, informative_scores=True, rng=2)
    perm = np.random.default_rng(3).permutation(len(pm.matches))
    kw = dict(image_size1=SIZE, image_size2=SIZE)
    lg = learned_logits(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores, **kw)
    lg_p = learned_logits(name, pm.kpts1, pm.kpts2, pm.matches[perm], pm.scores[perm], **kw)
    np.testing.assert_allclose(lg_p, lg[perm], rtol=1e-4, atol=1e-4)  # float32 sums in another order
    keep = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches, pm.scores, **kw)
    keep_p = FILTERS[name](pm.kpts1, pm.kpts2, pm.matches[perm], pm.scores[perm], **kw)
    clear = np.abs(lg[perm]) > 1e-3  # a logit within float noise of the threshold may flip
    np.testing.assert_array_equal(keep_p[clear], keep[perm][clear])


@pytest.mark.parametrize("name", ARCHS)
def test_shipped_weights_are_labelled_trained_here(name):
    from ctxmatch_lib.filters.learned import load_numpy_model_cached, shipped_weights
    from ctxmatch_lib.filters.learned.npnets import load_npz

    m = load_npz(name, shipped_weights(name))
    assert "trained here" in m.label and m.arch == name and shipped_weights(name).suffix == ".npz"
    assert "embedded" in np.load(shipped_weights(name))["__meta__"].item()
    assert "trained here" in load_numpy_model_cached(name).label
    assert all(v.dtype == np.float32 for v in m.params.values())
    assert shipped_weights(name).stat().st_size < 4 * 2**20
    with pytest.raises(ValueError, match="acne"):
        load_npz("oanet" if name == "acne" else "acne", shipped_weights(name))


@pytest.mark.parametrize("name", ARCHS)
def test_numpy_inference_equals_torch(torch, name):
    # The numpy engine against the torch modules the networks are trained with, same weights: logits within
    # float32 noise, identical keep masks (K >= 57; below 8 candidates OANet's eight-point fit is
    # degenerate and the two eigen-solvers may pick different null vectors).
    from ctxmatch_lib.filters.learned import learned_logits

    kw = dict(image_size1=SIZE, image_size2=SIZE)
    for k, ratio, seed in [(57, 0.4, 1), (800, 0.3, 2), (1500, 0.2, 3)]:
        pm = planted_homography_matches(k, ratio, informative_scores=True, rng=seed)
        a = learned_logits(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores, **kw)
        b = learned_logits(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores, backend="torch", **kw)
        # torch's own float32 error reaches 1.3e-3 here (OANet, K = 1500, against a float64 evaluation);
        # the numpy engine stays within 1e-4 of it.
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-3)
        np.testing.assert_array_equal(a > 0, b > 0)
    with pytest.raises(ValueError, match="backend"):
        learned_logits(name, pm.kpts1, pm.kpts2, pm.matches, pm.scores, backend="jax", **kw)


@pytest.mark.parametrize("name", ARCHS)
def test_shipped_weights_on_planted_sets(torch, name):
    # 40 % inliers under a homography, uniform outliers: pooled over three sets.
    tp = kept = n_in = 0
    for seed in range(3):
        pm = planted_homography_matches(1500, 0.4, informative_scores=seed == 2, rng=100 + seed)
        keep = _run(name, pm)
        tp += int((keep & pm.is_inlier).sum())
        kept += int(keep.sum())
        n_in += int(pm.is_inlier.sum())
    precision, recall = tp / max(kept, 1), tp / n_in
    assert precision >= 0.8 and recall >= 0.6, (precision, recall)


def _oanet_published_state_dict(torch, channels=8, depth=4, clusters=4, iters=1, side=0, seed=0):
    """Names and shapes of zjhthu/OANet ``OANet(config).state_dict()``, filled with random values."""
    g = torch.Generator().manual_seed(seed)
    sd = {}

    def conv(name, cin, cout):
        sd[f"{name}.weight"] = torch.randn(cout, cin, 1, 1, generator=g)
        sd[f"{name}.bias"] = torch.randn(cout, generator=g)

    def bn(name, c):
        sd[f"{name}.weight"] = torch.rand(c, generator=g) + 0.5
        sd[f"{name}.bias"] = torch.randn(c, generator=g)
        sd[f"{name}.running_mean"] = torch.randn(c, generator=g)
        sd[f"{name}.running_var"] = torch.rand(c, generator=g) + 0.5
        sd[f"{name}.num_batches_tracked"] = torch.tensor(7)

    def pointcn(name, cin, cout):
        bn(f"{name}.conv.1", cin)
        conv(f"{name}.conv.3", cin, cout)
        bn(f"{name}.conv.5", cout)
        conv(f"{name}.conv.7", cout, cout)
        if cin != cout:
            conv(f"{name}.shot_cut", cin, cout)

    c = channels
    half = depth // (iters + 1) // 2
    for s, stage in enumerate(["weights_init"] + [f"weights_iter.{i}" for i in range(iters)]):
        conv(f"{stage}.conv1", 4 + side + (2 if s else 0), c)
        for i in range(half):
            pointcn(f"{stage}.l1_1.{i}", c, c)
        bn(f"{stage}.down1.conv.1", c)
        conv(f"{stage}.down1.conv.3", c, clusters)
        for i in range(half):
            bn(f"{stage}.l2.{i}.conv1.1", c)
            conv(f"{stage}.l2.{i}.conv1.3", c, c)
            bn(f"{stage}.l2.{i}.conv2.0", clusters)
            conv(f"{stage}.l2.{i}.conv2.2", clusters, clusters)
            bn(f"{stage}.l2.{i}.conv3.2", c)
            conv(f"{stage}.l2.{i}.conv3.4", c, c)
        bn(f"{stage}.up1.conv.1", c)
        conv(f"{stage}.up1.conv.3", c, clusters)
        pointcn(f"{stage}.l1_2.0", 2 * c, c)
        for i in range(1, half):
            pointcn(f"{stage}.l1_2.{i}", c, c)
        conv(f"{stage}.output", c, 1)
    return sd


@pytest.mark.parametrize("side", [0, 2])
def test_load_oanet_published_checkpoint(torch, tmp_path, side):
    from ctxmatch_lib.filters.learned import load_learned_model

    sd = _oanet_published_state_dict(torch, side=side)
    path = tmp_path / "model_best.pth"
    torch.save({"epoch": 500000, "state_dict": sd, "best_acc": 0.5, "optimizer": {}}, path)
    model = load_learned_model("oanet", path)
    assert model.normalization == "hartley" and model.side == ("ratio_mutual" if side else "none")
    assert "authors" in model.label
    got = model.net.state_dict()
    assert sorted(got) == sorted(sd)
    assert all(torch.equal(got[k], sd[k]) for k in sd)
    pm = planted_homography_matches(300, 0.4, rng=4)
    keep = _run("oanet", pm, weights=path)
    assert keep.shape == (300,) and keep.dtype == bool
    # A bare state_dict loads too; a foreign file is a ValueError.
    torch.save(sd, tmp_path / "bare.pth")
    assert _run("oanet", pm, weights=tmp_path / "bare.pth").shape == (300,)
    torch.save({"something": torch.zeros(2)}, tmp_path / "other.pth")
    with pytest.raises(ValueError, match="OANet"):
        _run("oanet", pm, weights=tmp_path / "other.pth")


def test_load_acne_published_tf_checkpoint(torch, tmp_path):
    from ctxmatch_lib.filters.learned import load_learned_model
    from ctxmatch_lib.filters.learned.tfbundle import read_tf_checkpoint

    prefix = _write_tf_fixture(tmp_path)
    t = read_tf_checkpoint(prefix)
    for weights in (tmp_path, prefix.with_name(prefix.name + ".index"), prefix):  # folder, index file, prefix
        model = load_learned_model("acne", weights)
        assert model.net.config.net_channels == 8 and model.net.config.net_depth == 1
        assert "authors" in model.label
    sd = model.net.state_dict()
    # TF conv kernel [1, 1, in, out] -> torch (out, in, 1); the GN and attention parameters land in place.
    np.testing.assert_array_equal(sd["input.weight"].numpy()[:, :, 0],
                                  t["Matchnet/hidden-input/self-conv/weights"][0, 0].T)
    np.testing.assert_array_equal(sd["blocks.0.layers.1.acn.attn.weight"].numpy()[:, :, 0],
                                  t["Matchnet/hidden-0/conv-branch/conv2/reweight/weights"][0, 0].T)
    np.testing.assert_array_equal(sd["blocks.0.layers.0.norm.bias"].numpy(),
                                  t["Matchnet/hidden-0/conv-branch/conv1/gn_norm/beta"])
    pm = planted_homography_matches(300, 0.4, rng=5)
    assert _run("acne", pm, weights=prefix).shape == (300,)


def test_training_is_deterministic(torch, tmp_path):
    from ctxmatch_lib.filters.learned import load_learned_model, train_learned_filter

    kw = dict(steps=3, batch_size=2, n_candidates=64, max_images=2, progress=False, validate=False,
              config={"net_channels": 8, "net_depth": 1, "groups": 4})
    a = train_learned_filter("acne", seed=7, output=tmp_path / "a.pt", **kw)
    b = train_learned_filter("acne", seed=7, **kw)
    c = train_learned_filter("acne", seed=8, **kw)
    sa, sb, sc = (r.net.state_dict() for r in (a, b, c))
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a.losses == b.losses and len(a.losses) == 3
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)
    loaded = load_learned_model("acne", a.path)
    assert "trained here" in loaded.label
    assert all(torch.equal(loaded.net.state_dict()[k], sa[k]) for k in sa)
    # The .npz format (read without torch) holds the same arrays, and the two engines agree on them.
    from ctxmatch_lib.filters.learned.checkpoints import convert_to_npz
    from ctxmatch_lib.filters.learned.npnets import load_npz

    npz = load_npz("acne", convert_to_npz("acne", a.path, tmp_path / "a.npz"))
    assert npz.label == loaded.label and sorted(npz.params) == sorted(k for k in sa if "num_batches" not in k)
    assert all(np.array_equal(npz.params[k], sa[k].numpy()) for k in npz.params)
    x = np.random.default_rng(0).normal(size=(4, 50)).astype(np.float32)
    with torch.no_grad():
        ref = a.net(torch.from_numpy(x)[None])[-1][0].numpy()
    np.testing.assert_allclose(npz.logits(x), ref, rtol=0, atol=1e-4)
    o1 = train_learned_filter("oanet", seed=7, **dict(kw, config={"net_channels": 8, "net_depth": 4, "clusters": 4}))
    o2 = train_learned_filter("oanet", seed=7, **dict(kw, config={"net_channels": 8, "net_depth": 4, "clusters": 4}))
    assert all(torch.equal(v, o2.net.state_dict()[k]) for k, v in o1.net.state_dict().items())


def test_cli_train_registered():
    from ctxmatch_lib.cli import build_parser

    args = build_parser().parse_args(["train", "oanet", "--steps", "5", "--seed", "3"])
    assert args.arch == "oanet" and args.steps == 5 and args.seed == 3 and callable(args.func)
    assert build_parser().parse_args(["train", "acne"]).steps is None  # the shipped run's steps


def test_cli_train_tiny_run(torch, tmp_path, capsys):
    from ctxmatch_lib.cli import main
    from ctxmatch_lib.filters.learned import load_learned_model

    out = tmp_path / "acne.pt"
    assert main(["train", "acne", "--steps", "2", "--batch-size", "1", "--k-min", "32", "--k-max", "32",
                 "--max-images", "2", "--output", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "trained here" in text and "precision" in text and str(out) in text
    assert "trained here" in load_learned_model("acne", out).label


# ------------------------------------------------------------------------------ blob training sets
def test_blob_scene_ground_truth_follows_the_warp():
    from ctxmatch_lib.training.blobsets import make_scene
    from ctxmatch_lib.geometry import apply_homography

    rng = np.random.default_rng(0)
    imgs = [np.tile(np.uint8(i * 40), (120, 160)) for i in range(5)]
    pts = np.c_[rng.uniform(0, 159, 400), rng.uniform(0, 119, 400)]
    planar = make_scene(imgs, 1, kind="homography")
    dest = planar.true_positions(pts)
    seen = np.isfinite(dest[:, 0])
    assert seen.any() and len(planar.homographies) == 1
    np.testing.assert_allclose(dest[seen], apply_homography(planar.homographies[0], pts[seen]))
    # Out of view in image 2: no true position.
    w = apply_homography(planar.homographies[0], pts[~seen])
    assert np.all((w[:, 0] < -0.5) | (w[:, 0] > 159.5) | (w[:, 1] < -0.5) | (w[:, 1] > 119.5))
    layered = make_scene(imgs, 2, kind="layered")
    assert len(layered.homographies) >= 2 and layered.layers1.max() == len(layered.homographies) - 1
    dest = layered.true_positions(pts)
    ij = np.round(pts).astype(int)
    lab = layered.layers1[ij[:, 1], ij[:, 0]]
    for i, H in enumerate(layered.homographies):
        ok = np.isfinite(dest[:, 0]) & (lab == i)
        np.testing.assert_allclose(dest[ok], apply_homography(H, pts[ok]))
        # A seen point lands where its own layer is on top in image 2 (occlusion by the others).
        d = np.round(dest[ok]).astype(int)
        assert np.all(layered.layers2[d[:, 1], d[:, 0]] == i)
    with pytest.raises(ValueError, match="kind"):
        make_scene(imgs, 0, kind="affine")


def test_blob_sets_are_labelled_many_to_many_and_cached(tmp_path):
    from ctxmatch_lib.training import blobsets
    from ctxmatch_lib.groundtruth import GT_THRESHOLD_PX

    scene = blobsets.make_scene(blobsets.source_images()[:4], 3, kind="homography")
    sets = blobsets.scene_sets(scene, features=("sift-rootsift",), blobs=("baseline", "paper-best-overlap"),
                               max_keypoints=300)
    assert [s.blob for s in sets] == ["baseline", "paper-best-overlap"]
    base, best = sets
    assert len(best.x1) > len(base.x1) > 0  # f' = 5 against one-to-one
    assert 0 < best.inlier_ratio < 1
    err = np.linalg.norm(best.x2 - scene.true_positions(best.x1), axis=1)
    np.testing.assert_array_equal(best.is_inlier, np.nan_to_num(err, nan=np.inf) <= GT_THRESHOLD_PX)
    path = tmp_path / "s.npz"
    blobsets._save(path, sets)
    back = blobsets._load(path)
    assert [(b.kind, b.features, b.blob, b.size1) for b in back] == [(s.kind, s.features, s.blob, s.size1)
                                                                     for s in sets]
    np.testing.assert_array_equal(back[1].is_inlier, best.is_inlier)
    np.testing.assert_allclose(back[1].x2, best.x2, atol=1e-4)
    with pytest.raises(ValueError, match="n_scenes"):
        blobsets.build_sets(0, cache_dir=tmp_path)


def test_blob_training_sets_hold_out_the_last_scenes(tmp_path, monkeypatch):
    from ctxmatch_lib import training
    from ctxmatch_lib.training.blobsets import BlobSet

    rng = np.random.default_rng(0)
    per = training.blobsets.scene_count()

    def fake_build(n_scenes, seed, cache_dir=None, progress=False):
        return [BlobSet(rng.uniform(0, 600, (k, 2)), rng.uniform(0, 400, (k, 2)), rng.uniform(size=k),
                        np.arange(k) % 5 == 0, (640, 480), (600, 400), "homography", "sift-rootsift", "baseline")
                for i in range(n_scenes * per) for k in [150 if i % per else 50]]

    monkeypatch.setattr(training, "build_sets", fake_build)
    train_sets, val_sets, info = training.blob_training_sets(10, 0, cache_dir=tmp_path)
    # 10 scenes, the last one held out; the sets under 100 candidates left out of both.
    assert len(train_sets) == 9 * (per - 1) and len(val_sets) == per - 1
    assert info["n_scenes"] == 10 and info["blobsets"]["version"] == training.blobsets.GENERATOR_VERSION
    with pytest.raises(ValueError, match="val_fraction"):
        training.blob_training_sets(10, val_fraction=1.0)


def test_blob_batches_and_balanced_loss(torch, tmp_path):
    from ctxmatch_lib.filters.learned import training
    from ctxmatch_lib.training.blobsets import BlobSet

    rng = np.random.default_rng(0)

    def fake(k, ratio):
        lab = rng.uniform(size=k) < ratio
        return BlobSet(rng.uniform(0, 600, (k, 2)), rng.uniform(0, 400, (k, 2)), rng.uniform(size=k), lab,
                       (640, 480), (600, 400), "homography", "sift-rootsift", "baseline")

    sets = [fake(300, 0.1), fake(500, 0.2), fake(900, 0.3)]
    x, y = training._blob_batch(sets, np.random.default_rng(1), 4, 400, "score_rank")
    assert x.shape[0] == 4 and x.shape[1] == 5 and x.shape[2] <= 400 and y.shape == (4, x.shape[2])
    # Balanced: positives and negatives weigh half each, whatever their counts.
    logits = torch.zeros(1, 10)
    yb = torch.tensor([[1.0] + [0.0] * 9])
    assert abs(training._bce(logits, yb, True).item() - np.log(2)) < 1e-6
    logits[0, 0] = 5.0  # only the positive improves: the balanced loss drops by half its change
    plain, bal = training._bce(logits, yb, False).item(), training._bce(logits, yb, True).item()
    assert bal < plain
    blob_sets = (sets, sets[:1], {"n_scenes": 3})
    small = {"net_channels": 8, "net_depth": 1, "groups": 4}
    r = training.train("acne", steps=2, batch_size=2, n_candidates=(8, 128), data="blob", balanced=True,
                       progress=False, config=small, output=tmp_path / "a.npz", blob_sets=blob_sets)
    assert len(r.losses) == 2 and r.validation["n_sets"] == 1
    # The loop never builds candidates itself (the filters sit under the engine): no sets, a clear error.
    with pytest.raises(ValueError, match="blob_sets"):
        training.train("acne", steps=1, data="blob", progress=False, config=small)
    # Fine-tuning starts from the given weights: one step at a vanishing learning rate leaves them as they were.
    r2 = training.train("acne", steps=1, batch_size=2, n_candidates=(8, 128), data="blob", init=r.path,
                        lr=1e-9, progress=False, validate=False, config=small, blob_sets=blob_sets)
    assert r2.validation == {}
    a, b = r.net.state_dict(), r2.net.state_dict()
    assert all(torch.allclose(a[k].float(), b[k].float(), atol=1e-6) for k in a if "num_batches" not in k)
    with pytest.raises(ValueError, match="shape"):
        training.train("acne", steps=1, data="blob", init=r.path, progress=False, config=dict(small, net_channels=16),
                       blob_sets=blob_sets)
    with pytest.raises(ValueError, match="data"):
        training.train("acne", steps=1, data="real")
