"""The restoration stage's table: event-level metrics of the raw degraded events and of
stage-1 networks with the count output (image-guided, events-only), the paper's signed
output and an RDNet on a counts stage 1 (its fine-tuned stage 1)."""
import h5py
import numpy as np
import pytest

from rdnet.eval.events import match_metrics
from rdnet.study.rows import AblationConfig, restoration_table
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.loop import train
from rdnet.train.synthetic import write_synthetic_pairs

TINY = ModelConfig(size="tiny", width=4)
CFG = dict(iterations=3, batch_size=4, crop=16, device="cpu", log_every=3, ckpt_every=100,
           dvclive=False, seed=1, lr=1e-3, val_sequences=1)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("r")
    pairs = write_synthetic_pairs(tmp / "p.h5", n=6, bins=3, height=24, width=24, seed=4)
    counts = TrainConfig(**CFG, restore_output="counts")
    image = train("restore", counts, TINY, pairs, tmp / "image", progress=False)
    nets = {"image": image,
            "events": train("restore_events", counts, TINY, pairs, tmp / "events", progress=False),
            "signed": train("restore", TrainConfig(**CFG), TINY, pairs, tmp / "signed", progress=False),
            "rdnet": train("rdnet", counts, TINY, pairs, tmp / "rdnet", init_checkpoint=image, progress=False)}
    return pairs, nets


def test_raw_events_score_their_own_counts_and_networks_get_event_metrics(trained):
    pairs, nets = trained
    res = restoration_table(AblationConfig(batch_size=4, device="cpu"), pairs, None, nets, filters=())
    assert set(res) == {"degraded", *nets}
    with h5py.File(pairs, "r") as f:
        cu = np.stack([f["voxel_undegraded_on"][:], f["voxel_undegraded_off"][:]], 1).round().astype(np.int64)
        cd = np.stack([f["voxel_degraded_on"][:], f["voxel_degraded_off"][:]], 1).round().astype(np.int64)
    want = match_metrics(cd, cu)
    got = res["degraded"]["events"]
    assert got["precision"] == pytest.approx(want["precision"]) and got["count_ratio"] == pytest.approx(
        cd.sum() / cu.sum())
    assert got["reference"] == int(cu.sum()) and 0 < got["f1"] < 1
    for name in nets:
        ev = res[name]["events"]
        assert 0 <= ev["precision"] <= 1 and 0 <= ev["recall"] <= 1 and ev["reference"] == int(cu.sum())
        assert ev["restored"] >= 0 and "voxel_l1" in res[name] and res[name]["seeds"] == [0]
        assert {g["group"] for g in ev["by_degradation"]} == {g["group"] for g in res[name]["by_degradation"]}


def test_rdnet_row_and_restored_filter_run_on_a_counts_stage1(trained):
    from rdnet.eval.predict import evaluate_row, predict
    from rdnet.study.rows import voxel_filter
    pairs, nets = trained
    row = evaluate_row("rdnet", nets["rdnet"], pairs, device="cpu", level_bins=2)
    assert row["n"] == 6 and np.isfinite(row["psnr"]) and "voxel_l1" in row["restoration"]
    p = predict("rdnet", nets["rdnet"], pairs, device="cpu", events_out=True)
    assert p["restored"].shape == (6, 3, 24, 24) and p["restored_counts"].shape == (6, 2, 3, 24, 24)
    t = voxel_filter("rdnet", pairs, None, None, nets["rdnet"], 4, "cpu")
    np.testing.assert_array_equal(t(None, np.array([2, 0])), p["restored"][[2, 0]])


def test_report_shows_the_event_metrics_beside_the_response_l1():
    from rdnet.study.report import restoration_frame
    rest = {"degraded": {"voxel_l1": 1.0, "voxel_psnr": 10.0,
                         "events": {"precision": 0.5, "recall": 0.75, "f1": 0.6, "count_ratio": 1.5,
                                    "voxel_l1_all": 0.01, "voxel_l1_event": 0.9}},
            "rdnet": {"voxel_l1": 0.5, "voxel_psnr": 12.0, "seeds": [0, 1], "voxel_l1_std": 0.1,
                      "events": {"precision": 0.8, "recall": 0.7, "f1": 0.75, "f1_std": 0.02, "count_ratio": None}}}
    df = restoration_frame(rest)
    assert df.loc[0, "F1"] == "0.600" and df.loc[0, "count ratio"] == "1.50"
    assert df.loc[1, "F1"] == "0.750 ± 0.020" and df.loc[1, "count ratio"] == "-"


def test_training_flops_count_every_stage1_and_stage2_input():
    """The FLOPs record of a training (train.json) runs each network once on zeros: a
    count-output stage 1 reads 2 x bins channels, an events-only one no image, and the
    dual stage 2 costs more than the restored-only one."""
    from rdnet.nn.models import build_model
    from rdnet.study.training import forward_flops
    events_only = forward_flops(build_model("restore", "tiny", 0, 3, "counts", width=4), 16, 0, 3)
    image = forward_flops(build_model("restore", "tiny", 1, 3, "counts", width=4), 16, 1, 3)
    plain = forward_flops(build_model("rdnet", "tiny", 1, 3, "counts", width=4), 16, 1, 3)
    dual = forward_flops(build_model("rdnet", "tiny", 1, 3, "counts", "dual", width=4), 16, 1, 3)
    assert 0 < events_only < image < plain < dual
