import pytest
import torch

from rdnet.errors import ConfigError
from rdnet.nn import (MODEL_SIZES, DeblurNet, RDNet, RestoreNet, build_model, count_parameters,
                      model_from_config)
from rdnet.nn.blocks import NAFBlock, nafblock_params


def meta_count(*args, **kw):
    with torch.device("meta"):
        return count_parameters(build_model(*args, **kw))


def test_nafblock_param_formula():
    for c in (3, 8, 24):
        assert count_parameters(NAFBlock(c)) == nafblock_params(c) == 7 * c * c + 33 * c


@pytest.mark.parametrize("channels", [1, 3])
def test_paper_size_matches_paper_count(channels):
    n = meta_count("rdnet", "paper", channels, 10)
    assert abs(n - 7.86e6) / 7.86e6 < 0.02
    if channels == 1:
        assert n == 7_905_779  # the count stated in rdnet.nn.models docstring


@pytest.mark.parametrize("size", ["tiny", "paper"])
def test_matched_deblurnet_within_2_percent(size):
    target = meta_count("rdnet", size, 1, 10)
    m = build_model("deblurnet_matched", size, 1, 10)
    assert isinstance(m, DeblurNet) and m.use_events
    assert m.config["width"] > MODEL_SIZES[size]["width"]
    assert abs(count_parameters(m) - target) / target < 0.02


def test_stages_have_equal_structure_and_sizes_grow():
    counts = [meta_count("rdnet", s, 1, 10) for s in ("tiny", "small", "paper")]
    assert counts == sorted(counts)
    with torch.device("meta"):
        r = build_model("rdnet", "tiny", 1, 10)
    # same structure, separate weights: the two stages differ only in the in/out convs
    assert abs(count_parameters(r.restore) - count_parameters(r.deblur)) < 1000
    assert r.restore.net.ending.weight is not r.deblur.net.ending.weight


@pytest.mark.parametrize("shape", [(32, 32), (19, 27), (5, 9)])
def test_output_shapes_any_size(shape):
    torch.manual_seed(0)
    H, W = shape
    img = torch.rand(2, 3, H, W)
    vox = torch.randn(2, 10, H, W)
    rd = build_model("rdnet", "tiny", 3, 10)
    restored, sharp = rd(img, vox)
    assert restored.shape == vox.shape and sharp.shape == img.shape
    assert build_model("restore", "tiny", 3, 10)(img, vox).shape == vox.shape
    assert build_model("deblur", "tiny", 3, 10)(img, vox).shape == img.shape
    assert build_model("image_only", "tiny", 3, 10)(img).shape == img.shape
    assert build_model("deblurnet_matched", "tiny", 3, 10)(img, vox).shape == img.shape


def test_fresh_stages_are_identity_by_global_residual():
    torch.manual_seed(0)
    img, vox = torch.rand(1, 1, 20, 20), torch.randn(1, 10, 20, 20)
    rd = build_model("rdnet", "tiny", 1, 10)
    restored, sharp = rd(img, vox)
    assert torch.equal(restored, vox) and torch.equal(sharp, img)


def test_image_only_has_no_event_branch_and_rejects_voxels():
    m = build_model("image_only", "tiny", 1, 10)
    e = build_model("deblur", "tiny", 1, 10)
    assert m.net.event_branch is None
    assert count_parameters(m) < count_parameters(e)
    with pytest.raises(ValueError):
        m(torch.rand(1, 1, 8, 8), torch.rand(1, 10, 8, 8))
    with pytest.raises(ValueError):
        m.event_features(torch.rand(1, 10, 8, 8))


def test_event_features_multiscale_and_independent_of_image():
    torch.manual_seed(0)
    m = build_model("deblur", "tiny", 1, 10)
    vox = torch.randn(2, 10, 30, 21)
    feats = m.event_features(vox)
    L = len(MODEL_SIZES["tiny"]["enc_depths"])
    assert len(feats) == L + 1
    for i, f in enumerate(feats):
        assert f.shape == (2, MODEL_SIZES["tiny"]["width"] * 2 ** i, -(-30 // 2 ** i), -(-21 // 2 ** i))
    # deterministic function of the voxels alone (the image is not an argument)
    assert all(torch.equal(a, b) for a, b in zip(feats, m.event_features(vox.clone())))


def test_fusion_direction():
    """Stage 1's output depends on the image only through the image->event fusion; with the
    ending conv made non-zero, changing the image changes the restored voxels."""
    torch.manual_seed(0)
    r = build_model("restore", "tiny", 1, 10)
    torch.nn.init.normal_(r.net.ending.weight, std=0.1)
    for blk in r.net.modules():
        if hasattr(blk, "beta"):
            torch.nn.init.normal_(blk.beta, std=0.1)
            torch.nn.init.normal_(blk.gamma, std=0.1)
    vox = torch.randn(1, 10, 16, 16)
    a = r(torch.zeros(1, 1, 16, 16), vox)
    b = r(torch.ones(1, 1, 16, 16), vox)
    assert not torch.allclose(a, b)
    assert r.net.fuse_into == "event" and r.net.source is r.net.image_branch


def test_config_roundtrip_rebuilds_same_architecture():
    torch.manual_seed(0)
    for kind in ("restore", "deblur", "rdnet", "image_only", "deblurnet_matched"):
        m = build_model(kind, "tiny", 1, 10)
        m2 = model_from_config(m.config)
        assert type(m2) is type(m)
        assert m2.config == m.config
        m2.load_state_dict(m.state_dict())  # same parameter names and shapes


def test_overrides_and_errors():
    m = build_model("restore", "tiny", 1, 4, width=6)
    assert isinstance(m, RestoreNet) and m.config["width"] == 6 and m.config["bins"] == 4
    with pytest.raises(ConfigError):
        build_model("restore", "huge", 1, 10)
    with pytest.raises(ConfigError):
        build_model("nope", "tiny", 1, 10)
    with pytest.raises(ConfigError):
        build_model("restore", "tiny", 1, 10, depth=3)
    with pytest.raises(ConfigError):
        build_model("rdnet", "tiny", 1, 10, enc_depths=(1, 1))
    with pytest.raises(ConfigError):
        build_model("rdnet", "tiny", 1, 10, width=0)
    assert build_model("rdnet", "tiny", 1, 10, enc_depths=[2, 1, 0]).config["restore"]["enc_depths"] == (2, 1, 0)
    with pytest.raises(ValueError):
        RDNet(RestoreNet(1, 10, width=8), DeblurNet(3, 10, width=8))
