"""Self-describing checkpoints and their errors; train/model config validation."""
import os

import pytest
import torch

from rdnet.config import from_dict
from rdnet.errors import ConfigError, FormatError, RdnetError
from rdnet.nn.models import build_model
from rdnet.train.checkpoint import (load_model, make_checkpoint, read_checkpoint, rng_state,
                                    save_checkpoint, set_rng_state)
from rdnet.train.config import ModelConfig, TrainConfig

ARGS = {"kind": "deblur", "size": "tiny", "image_channels": 1, "bins": 4}


def randomized(net, seed=0):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.1)
    return net


@pytest.fixture
def saved(tmp_path):
    net = randomized(build_model(**ARGS))
    opt = torch.optim.Adam(net.parameters())
    path = save_checkpoint(tmp_path / "m.pt", make_checkpoint(net, "deblur", ARGS, config={"lr": 1e-3},
                                                              optimizer=opt, step=7))
    return net, path


def test_model_rebuilds_from_checkpoint_alone(saved):
    net, path = saved
    ck = read_checkpoint(path)
    assert ck["model_class"] == "DeblurNet" and ck["task"] == "deblur" and ck["step"] == 7
    assert ck["model_args"] == ARGS and ck["model_config"]["width"] == 8
    assert {"optimizer", "rng", "rdnet_version", "config"} <= set(ck)
    loaded = load_model(path, expected_kind="deblur", bins=4, image_channels=1)
    assert not loaded.training
    x, v = torch.rand(2, 1, 16, 16), torch.randn(2, 4, 16, 16)
    net.eval()
    with torch.no_grad():
        assert torch.equal(loaded(x, v), net(x, v))
    assert not [f for f in os.listdir(path.parent) if f.endswith(".tmp")]


def test_rdnet_checkpoint_rebuilds_both_stages(tmp_path):
    args = {**ARGS, "kind": "rdnet", "width": 4}
    net = randomized(build_model(**args), seed=3)
    path = save_checkpoint(tmp_path / "r.pt", make_checkpoint(net, "rdnet", args))
    loaded = load_model(path, "rdnet")
    assert type(loaded).__name__ == "RDNet" and loaded.config == net.config
    assert loaded.config["restore"]["width"] == loaded.config["deblur"]["width"] == 4
    for (k, a), (_, b) in zip(net.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), k


def test_wrong_kind_bins_channels_are_clear_errors(saved):
    _, path = saved
    with pytest.raises(FormatError, match=r"m\.pt.*model_kind.*'deblur'.*expected 'restore'"):
        load_model(path, expected_kind="restore")
    with pytest.raises(FormatError, match=r"model_args\.bins.*4 voxel bins, data has 10"):
        load_model(path, bins=10)
    with pytest.raises(FormatError, match=r"image_channels"):
        load_model(path, image_channels=3)


def test_missing_keys_and_mismatched_weights(tmp_path, saved):
    net, path = saved
    ck = read_checkpoint(path)
    del ck["model_args"]
    save_checkpoint(tmp_path / "nokey.pt", ck)
    with pytest.raises(FormatError, match=r"nokey\.pt: field 'model_args': missing"):
        load_model(tmp_path / "nokey.pt")
    ck = read_checkpoint(path)
    ck["model_args"] = {**ARGS, "size": "small"}   # a checkpoint claiming another size
    save_checkpoint(tmp_path / "size.pt", ck)
    with pytest.raises(FormatError, match=r"size\.pt: field 'model_config'.*width: stored 8, rebuilt 16"):
        load_model(tmp_path / "size.pt")
    ck = read_checkpoint(path)
    ck["state_dict"].pop(next(iter(ck["state_dict"])))
    save_checkpoint(tmp_path / "partial.pt", ck)
    with pytest.raises(FormatError, match=r"partial\.pt: field 'state_dict'.*1 missing"):
        load_model(tmp_path / "partial.pt")


def test_corrupt_foreign_and_absent_files(tmp_path, saved):
    _, path = saved
    data = path.read_bytes()
    (tmp_path / "trunc.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=r"trunc\.pt: not a readable checkpoint"):
        load_model(tmp_path / "trunc.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "foreign.pt")
    with pytest.raises(FormatError, match=r"foreign\.pt: field 'format'"):
        load_model(tmp_path / "foreign.pt")
    with pytest.raises(FormatError, match="not found"):
        load_model(tmp_path / "absent.pt")


def test_rng_state_roundtrip():
    import numpy as np
    torch.manual_seed(4)
    np.random.seed(4)
    st = rng_state()
    a, b = torch.rand(3), np.random.rand(3)
    set_rng_state(st)
    assert torch.equal(torch.rand(3), a) and np.array_equal(np.random.rand(3), b)


def test_train_and_model_config_validation():
    cfg = from_dict(TrainConfig, {"iterations": 10, "crop": None, "device": "cpu"}, "train")
    assert cfg.lr == 2e-4 and cfg.lr_min == 1e-7 and cfg.alpha == cfg.beta == 0.5
    with pytest.raises(ConfigError, match="train.lrr"):
        from_dict(TrainConfig, {"lrr": 1}, "train")
    with pytest.raises(ConfigError, match="train.lr_min"):
        from_dict(TrainConfig, {"lr": 1e-4, "lr_min": 1e-3}, "train")
    with pytest.raises(ConfigError, match="train.batch_size"):
        from_dict(TrainConfig, {"batch_size": 0}, "train")
    with pytest.raises(ConfigError, match="train.device"):
        from_dict(TrainConfig, {"device": "tpu"}, "train")
    m = from_dict(ModelConfig, {"size": "tiny", "width": 4, "enc_depths": [1, 2]}, "model")
    assert m.overrides() == {"width": 4, "enc_depths": [1, 2]}
    with pytest.raises(ConfigError, match="model.size"):
        from_dict(ModelConfig, {"size": "huge"}, "model")
    with pytest.raises(ConfigError, match="model.dec_depths"):
        from_dict(ModelConfig, {"enc_depths": [1, 1], "dec_depths": [1]}, "model")
    assert issubclass(ConfigError, RdnetError)


def test_two_saves_of_the_same_content_are_byte_identical(tmp_path, saved):
    """Equal content, equal bytes (DVC hashes the file): no temporary file name, time or
    memo address leaks into the zip. The saved file still loads as before."""
    net, path = saved
    opt = torch.optim.Adam(net.parameters())
    ck = make_checkpoint(net, "deblur", ARGS, config={"lr": 1e-3}, optimizer=opt, step=7)
    a = save_checkpoint(tmp_path / "a" / "model.pt", ck).read_bytes()
    b = save_checkpoint(tmp_path / "b" / "other_name.pt", dict(ck)).read_bytes()
    assert a == b == path.read_bytes()
    # different content, different bytes (the comparison is not blind)
    c = save_checkpoint(tmp_path / "c.pt", {**ck, "step": 8}).read_bytes()
    assert c != a
    assert read_checkpoint(tmp_path / "a" / "model.pt")["step"] == 7


def test_training_twice_or_killed_and_resumed_gives_byte_identical_model(tmp_path):
    """Two runs of the same tiny training (same seed), and one stopped half way then resumed,
    write the same model.pt bytes, so `dvc repro` sees an unchanged out."""
    from rdnet.train.loop import train
    from rdnet.train.synthetic import write_synthetic_pairs
    pairs = write_synthetic_pairs(tmp_path / "train.h5", n=4, bins=3, height=20, width=20, seed=2)
    cfg = TrainConfig(iterations=2, batch_size=2, crop=16, device="cpu", log_every=1, ckpt_every=1,
                      dvclive=False, seed=3)
    tiny = ModelConfig(size="tiny", width=4)
    runs = [train("deblur", cfg, tiny, pairs, tmp_path / d, progress=False) for d in ("a", "b")]
    assert train("deblur", cfg, tiny, pairs, tmp_path / "c", progress=False, stop_after=1).name == "last.pt"
    runs.append(train("deblur", cfg, tiny, pairs, tmp_path / "c", progress=False))   # resumes at step 1
    assert [r.name for r in runs] == ["model.pt"] * 3
    data = [r.read_bytes() for r in runs]
    assert data[0] == data[1] == data[2]
    assert read_checkpoint(runs[0])["step"] == 2
