"""Training the count-output restorer: the decision is fitted on held-out sequences and
stored in model.pt; a noise-free stream passes through; the paper's signed/masked
option, the events-only task and an RDNet on a counts stage 1 still train."""
import h5py
import numpy as np
import pytest

from rdnet.errors import ConfigError, FormatError
from rdnet.train.checkpoint import read_checkpoint
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.data import PairsDataset, split_rows
from rdnet.train.loop import train
from rdnet.train.synthetic import write_synthetic_pairs

TINY = ModelConfig(size="tiny", width=4)
CFG = dict(iterations=6, batch_size=4, crop=16, device="cpu", log_every=3, ckpt_every=100,
           dvclive=False, seed=1, lr=1e-3)
COUNTS = TrainConfig(**CFG, restore_output="counts", val_sequences=2)


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    return write_synthetic_pairs(tmp_path_factory.mktemp("p") / "train.h5", n=10, bins=3,
                                 height=24, width=24, seed=4)


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    return write_synthetic_pairs(tmp_path_factory.mktemp("p") / "clean.h5", n=10, bins=3,
                                 height=24, width=24, seed=5, noise_free=True)


def test_dataset_serves_per_polarity_counts_and_holds_out_whole_sequences(noisy):
    ds = PairsDataset(noisy, crop=None)
    s = ds[0]
    assert s["counts_degraded"].shape == (6, 24, 24) and (s["counts_degraded"] >= 0).all()
    np.testing.assert_array_equal((s["counts_degraded"][:3] - s["counts_degraded"][3:]).numpy(),
                                  s["voxel_degraded"].numpy())
    tr, va = split_rows(noisy, 2)                       # sequences are row // 2: 0..4
    assert tr.tolist() == list(range(6)) and va.tolist() == [6, 7, 8, 9]
    sub = PairsDataset(noisy, crop=None, rows=va)
    assert len(sub) == 4 and int(sub[0]["index"]) == 6
    with pytest.raises(ConfigError, match="val_sequences"):
        split_rows(noisy, 5)


def test_noise_free_stream_passes_through_and_decision_is_stored(clean, tmp_path):
    path = train("restore", COUNTS, TINY, clean, tmp_path / "r", progress=False)
    ck = read_checkpoint(path)
    d = ck["extra"]["decision"]
    assert d["rule"] == "occupancy_threshold" and 0 < d["threshold"] <= 1
    assert ck["extra"]["val_rows"] == [6, 7, 8, 9] and ck["model_args"]["restore_output"] == "counts"
    assert ck["extra"]["window_us"] == 5000
    m = d["val_metrics"]                  # decided events on the held-out rows == undegraded
    assert m["precision"] == 1.0 and m["recall"] == 1.0 and m["count_ratio"] == 1.0


def test_signed_masked_option_events_only_and_rdnet_on_counts(noisy, tmp_path):
    signed = train("restore", TrainConfig(**CFG, val_sequences=1), TINY, noisy, tmp_path / "s", progress=False)
    ck = read_checkpoint(signed)
    assert "restore_output" not in ck["model_args"] and ck["extra"]["decision"]["rule"] == "round"
    assert 0 < ck["extra"]["decision"]["val_metrics"]["f1"] <= 1
    ev = train("restore_events", COUNTS, TINY, noisy, tmp_path / "e", progress=False)
    ck = read_checkpoint(ev)
    assert ck["model_args"]["image_channels"] == 0 and ck["extra"]["decision"]["threshold"] > 0
    r = train("restore", COUNTS, TINY, noisy, tmp_path / "c", progress=False)
    rd = train("rdnet", COUNTS, TINY, noisy, tmp_path / "rd", init_checkpoint=r, progress=False)
    ck = read_checkpoint(rd)                   # stage 1 fine-tuned: its threshold refitted on its val rows
    d, d1 = ck["extra"]["decision"], read_checkpoint(r)["extra"]["decision"]
    assert d["rule"] == d1["rule"] and d["val_rows"] == d1["val_rows"] and "refit" in d
    assert d["val_metrics"]["count_ratio"] == pytest.approx(1.0, abs=0.05)
    import dataclasses
    frozen = train("rdnet", dataclasses.replace(COUNTS, finetune_restore=False), TINY, noisy, tmp_path / "rf",
                   init_checkpoint=r, progress=False)
    assert read_checkpoint(frozen)["extra"]["decision"] == d1            # stage 1 unchanged: kept
    with pytest.raises(FormatError, match="restore_output"):   # a signed stage 1 for a counts RDNet
        train("rdnet", COUNTS, TINY, noisy, tmp_path / "rd2", init_checkpoint=signed, progress=False)
    from rdnet.train.loop import build_seeded, model_args
    from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
    args = model_args("deblur", TINY, 1, 3)
    deblur = save_checkpoint(tmp_path / "d.pt", make_checkpoint(build_seeded(args, 0), "deblur", args))
    with pytest.raises(FormatError, match=r"model_kind.*'deblur'"):   # the wrong kind named, not its output
        train("rdnet", COUNTS, TINY, noisy, tmp_path / "rd3", init_checkpoint=deblur, progress=False)


def test_counts_needs_per_polarity_voxels_and_validation(tmp_path):
    old = write_synthetic_pairs(tmp_path / "old.h5", n=6, bins=3, height=24, width=24, polarity=False)
    with h5py.File(old) as f:
        assert "voxel_degraded_on" not in f
    assert PairsDataset(old).info.has_counts is False
    with pytest.raises(FormatError, match="voxel_degraded_on"):
        train("restore", COUNTS, TINY, old, tmp_path / "x", progress=False)
    with pytest.raises(ConfigError, match="val_sequences"):
        TrainConfig(restore_output="counts", val_sequences=0)
    with pytest.raises(ConfigError, match="restore_output"):
        TrainConfig(restore_output="signed")


def test_dual_stage2_starts_as_the_restored_only_rdnet_and_trains(noisy, tmp_path):
    """stage2_input dual: DeblurNet reads restored + raw voxels; initialised from a
    DeblurNet, the raw half of its input layers is zero, so it starts as the
    restored-only RDNet with the same weights; it trains, and evaluates like any RDNet."""
    import torch
    from rdnet.eval.predict import predict
    from rdnet.nn.models import build_model
    from rdnet.train.loop import _init_deblur, model_args
    deblur = train("deblur", TrainConfig(**CFG), TINY, noisy, tmp_path / "d", progress=False)
    image = train("restore", COUNTS, TINY, noisy, tmp_path / "r", progress=False)
    dual_cfg = TrainConfig(**CFG, restore_output="counts", val_sequences=2, stage2_input="dual")
    args = model_args("rdnet", TINY, 1, 3, "counts", "dual")
    assert args["stage2_input"] == "dual"
    dual = build_model(**args)
    plain = build_model(**model_args("rdnet", TINY, 1, 3, "counts"))
    _init_deblur("rdnet", dual, deblur, args)
    _init_deblur("rdnet", plain, deblur, model_args("rdnet", TINY, 1, 3, "counts"))
    dual.restore.load_state_dict(plain.restore.state_dict())
    g = torch.Generator().manual_seed(0)
    img, x = torch.rand(2, 1, 24, 24, generator=g), torch.randint(0, 3, (2, 6, 24, 24), generator=g).float()
    with torch.no_grad():
        torch.testing.assert_close(dual(img, x)[1], plain(img, x)[1])
    path = train("rdnet", dual_cfg, TINY, noisy, tmp_path / "dual", init_checkpoint=image, init_deblur=deblur,
                 progress=False)
    ck = read_checkpoint(path)
    assert ck["model_args"]["stage2_input"] == "dual" and ck["extra"]["decision"]["rule"] == "occupancy_threshold"
    assert "stage 2" in ck["extra"]["decision"]["refit"]          # refitted after fine-tuning stage 1
    p = predict("rdnet", path, noisy, device="cpu")
    assert p["pred"].shape == (10, 1, 24, 24) and np.isfinite(p["pred"]).all()


def test_clean_fraction_serves_identity_pairs_without_moving_the_crops(noisy):
    """train.clean_fraction: that share of samples (drawn per (seed, epoch, row)) has the
    undegraded events as its input and level 0; the crops and flips stay those of fraction 0,
    and fraction 0 serves the file unchanged."""
    base = PairsDataset(noisy, crop=16, augment=True, seed=3)
    mixed = PairsDataset(noisy, crop=16, augment=True, seed=3, clean_fraction=0.5)
    clean = 0
    for epoch in range(8):
        for i in range(len(base)):
            b, m = base[(i, epoch)], mixed[(i, epoch)]
            np.testing.assert_array_equal(b["counts_undegraded"].numpy(), m["counts_undegraded"].numpy())
            np.testing.assert_array_equal(b["blurry"].numpy(), m["blurry"].numpy())
            assert not np.array_equal(b["counts_degraded"].numpy(), b["counts_undegraded"].numpy())
            if np.array_equal(m["counts_degraded"].numpy(), m["counts_undegraded"].numpy()):
                clean += 1
                np.testing.assert_array_equal(m["voxel"].numpy(), m["voxel_undegraded"].numpy())
                assert float(m["level"]) == 0.0
            else:
                np.testing.assert_array_equal(m["counts_degraded"].numpy(), b["counts_degraded"].numpy())
                assert float(m["level"]) == float(b["level"])
    assert 0.3 < clean / (8 * len(base)) < 0.7
    with pytest.raises(ConfigError, match="clean_fraction"):
        TrainConfig(**CFG, clean_fraction=1.0)
    with pytest.raises(ConfigError, match="clean_fraction"):
        PairsDataset(noisy, clean_fraction=-0.1)


def test_support_rule_is_fitted_and_stored_and_keeps_a_clean_stream(clean, noisy, tmp_path):
    import dataclasses

    from rdnet.nn.decision import SUPPORT_RULE
    cfg = dataclasses.replace(COUNTS, support_rule=True)
    d = read_checkpoint(train("restore", cfg, TINY, clean, tmp_path / "c", progress=False))["extra"]["decision"]
    s = d["support"]
    # a noise-free stream: whatever has no neighbour is real, so nothing is dropped and the
    # threshold stays the one fitted without the rule
    assert s["rule"] == SUPPORT_RULE and not s["drop"] and s["threshold_before"] == d["threshold"]
    assert s["val_events"] == 0 or s["val_precision"] == 1.0
    assert d["val_metrics"]["precision"] == 1.0 and d["val_metrics"]["recall"] == 1.0
    d = read_checkpoint(train("restore_events", cfg, TINY, noisy, tmp_path / "n", progress=False))["extra"]["decision"]
    s = d["support"]
    assert s["rule"] == SUPPORT_RULE and isinstance(s["drop"], bool) and s["val_events"] >= 0
    assert s["drop"] == (s["val_precision"] is not None and s["val_precision"] < s["threshold_before"])
    assert "support" not in read_checkpoint(train("restore", COUNTS, TINY, clean, tmp_path / "p",
                                                  progress=False))["extra"]["decision"]
