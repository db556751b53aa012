"""Seeds of the study: config validation, checkpoint layout, seed means and paired gaps."""
import json
import os

import numpy as np
import pytest

from rdnet.config import from_dict
from rdnet.errors import ConfigError
from rdnet.study.config import NetworkConfig, StudyConfig, network, seed_checkpoint
from rdnet.study.report import ablation_markdown, network_compute, paired_gap, plot_data
from rdnet.study.rows import mean_over_seeds, seed_spread


def test_study_config_validates():
    assert from_dict(StudyConfig, {"seeds": [2, 0, 1]}, "study").seeds == (2, 0, 1)
    for bad in ({"seeds": []}, {"seeds": [0, 0]}, {"seeds": [-1]}, {"parallel": 0}):
        with pytest.raises(ConfigError):
            from_dict(StudyConfig, bad, "study")
    with pytest.raises(ConfigError, match="networks.nope"):
        network({"networks": {"a": {"task": "deblur"}}}, "nope")
    with pytest.raises(ConfigError, match="iterations_factor"):
        NetworkConfig(task="deblur", iterations_factor=0)


def test_seed_checkpoint_layout(tmp_path):
    assert seed_checkpoint("models/rdnet", 2).as_posix() == "models/rdnet/seed2/model.pt"
    assert seed_checkpoint("some/model.pt", 2).as_posix() == "some/model.pt"


def test_mean_over_seeds_averages_numbers_elementwise():
    a = {"psnr": 20.0, "n": 5, "method": "deblur", "by_level": [{"level_bin": 1.0, "n": 3, "psnr": 19.0}]}
    b = {"psnr": 22.0, "n": 5, "method": "deblur", "by_level": [{"level_bin": 1.0, "n": 3, "psnr": 23.0}]}
    m = mean_over_seeds([a, b])
    assert m == {"psnr": 21.0, "n": 5, "method": "deblur", "by_level": [{"level_bin": 1.0, "n": 3, "psnr": 21.0}]}
    assert a["psnr"] == 20.0                      # inputs untouched
    assert seed_spread([1.0, 2.0, 3.0]) == pytest.approx(1.0)
    assert seed_spread([5.0]) == 0.0


def test_paired_gap_uses_per_seed_differences():
    # row a beats b by exactly 0.5 dB on every seed although the seeds scatter by 2 dB:
    # the paired spread is 0, the unpaired one would hide the gap
    a = {"psnr": 21.5, "seeds": [0, 1, 2], "psnr_seeds": [20.5, 22.5, 21.5]}
    b = {"psnr": 21.0, "seeds": [0, 1, 2], "psnr_seeds": [20.0, 22.0, 21.0]}
    g = paired_gap(a, b)
    assert g["mean"] == pytest.approx(0.5) and g["std"] == pytest.approx(0.0, abs=1e-12)
    assert g["positive"] == 3 and g["n"] == 3
    c = {"psnr": 21.0, "seeds": [0, 1, 2], "psnr_seeds": [21.0, 20.0, 22.0]}
    g2 = paired_gap(a, c)
    assert g2["per_seed"] == pytest.approx([-0.5, 2.5, -0.5])
    assert g2["p"] > 0.3                          # a noisy gap is not significant
    # an untrained row (no seeds) against a trained one: difference of means
    d = {"psnr": 20.0, "seeds": []}
    assert paired_gap(a, d) == {"mean": 1.5, "std": None, "n": 1, "positive": 1, "p": None, "per_seed": []}


def test_report_table_shows_spread_compute_and_gaps(tmp_path):
    for name, init, wall in (("restore", None, 10.0), ("rdnet", str(tmp_path / "restore"), 30.0)):
        d = tmp_path / name
        d.mkdir()
        runs = [{"seed": s, "wall_s": wall + s, "iterations": 100, "train_gflop": wall * 100} for s in (0, 1)]
        (d / "summary.json").write_text(json.dumps({"runs": runs, "init": init, "parameters": 1234}))
    c = network_compute(str(tmp_path / "rdnet"))
    assert c["train_s"] == pytest.approx(10.5 + 30.5) and c["iterations"] == 200 and c["parameters"] == 1234
    assert c["train_gflop"] == pytest.approx(4000.0)
    assert network_compute("x/model.pt") is None and network_compute(None) is None
    rows = {"degraded_train": {"method": "deblur", "events": "degraded", "psnr": 25.0, "psnr_std": 0.1,
                               "ssim": 0.8, "ssim_std": 0.01, "seeds": [0, 1], "psnr_seeds": [24.9, 25.1],
                               "by_level": [{"level_bin": 1.0, "psnr": 24.0}]},
            "rdnet": {"method": "rdnet", "events": "degraded", "psnr": 25.5, "psnr_std": 0.3, "ssim": 0.81,
                      "ssim_std": 0.02, "seeds": [0, 1], "psnr_seeds": [25.2, 25.8], "paper_psnr": 37.33,
                      "by_level": [{"level_bin": 1.0, "psnr": 25.0}]}}
    md = ablation_markdown(rows, {"degraded": {"voxel_l1": 1.0, "voxel_psnr": 10.0}}, {"rdnet": c})
    assert "25.50 ± 0.30" in md and "1,234" in md and "| 4.0 " in md and "1.0000" in md
    assert "+0.50 ± 0.28" in md and "2/2" in md           # paired: diffs 0.3 and 0.7
    assert "circuit" not in md
    circuit = {"degraded_train": {"psnr": 26.0, "psnr_seeds": [25.9, 26.1], "seeds": [0, 1]},
               "rdnet": {"psnr": 26.3, "psnr_seeds": [26.0, 26.6], "seeds": [0, 1]}}
    md = ablation_markdown(rows, None, {"rdnet": c}, circuit)     # the restoration_circuit rows as columns
    assert "PSNR, circuit events (dB)" in md and "26.30 ± 0.42" in md
    assert "+0.30 ± 0.28" in md                            # circuit gap, paired: 0.1 and 0.5
    from rdnet.study.figures import gap_figure
    png = gap_figure(rows, circuit, tmp_path / "gaps.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bars, levels = plot_data(rows)
    assert bars[1] == {"row": "rdnet", "psnr": 25.5, "psnr_std": 0.3}
    assert levels == [{"level": 1.0, "degraded_train": 24.0, "rdnet": 25.0}]
    assert np.isfinite([b["psnr"] for b in bars]).all()


def test_calibrated_configs_read_a_calibration_report(tmp_path):
    from rdnet.errors import FormatError
    from rdnet.study.config import calibrated_configs
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps({"fitted_config": {"sensor": {"threshold_on": 0.3, "threshold_off": 0.25},
                                                 "degrade": {"latency_us": 3800.0, "shot_noise_hz": 0.0}}}))
    sensor, deg = calibrated_configs(rep)
    assert (sensor.threshold_on, sensor.threshold_off, deg.latency_us, deg.shot_noise_hz) == (0.3, 0.25, 3800.0, 0.0)
    with pytest.raises(FormatError, match="no such file"):
        calibrated_configs(tmp_path / "missing.json")
    rep.write_text(json.dumps({"effects": []}))
    with pytest.raises(FormatError, match="fitted_config"):
        calibrated_configs(rep)
    rep.write_text(json.dumps({"fitted_config": {"sensor": {"threshold_on": -1}, "degrade": {}}}))
    with pytest.raises(ConfigError, match="threshold_on"):
        calibrated_configs(rep)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes on this platform")
def test_calibrated_configs_refuses_a_report_that_is_not_a_regular_file(tmp_path):
    """A FIFO once blocked the read forever (checked only by `rdnet restore --calibration`,
    not for study.degrade_from); a folder is refused the same way."""
    import threading
    from rdnet.errors import FormatError
    from rdnet.study.config import calibrated_configs
    fifo, folder = tmp_path / "fifo.json", tmp_path / "dir.json"
    os.mkfifo(fifo)
    folder.mkdir()

    def unblock():                   # should the read block again, end it (EOF) instead of hanging
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:              # no reader waiting: nothing blocked
            pass
    timer = threading.Timer(10.0, unblock)
    timer.start()
    try:
        for path in (fifo, folder):
            with pytest.raises(FormatError) as e:
                calibrated_configs(path)
            assert str(e.value) == f"{path}: not a regular file"
    finally:
        timer.cancel()


def test_forward_flops_count_convolutions():
    from rdnet.nn.models import build_model
    from rdnet.study.training import forward_flops
    deblur = build_model("deblur", size="tiny", image_channels=1, bins=10)
    rdnet = build_model("rdnet", size="tiny", image_channels=1, bins=10)
    f1, f2 = forward_flops(deblur, 32, 1, 10), forward_flops(rdnet, 32, 1, 10)
    assert f1 > 0 and f2 > 1.8 * f1                   # RDNet runs two stage networks
    assert forward_flops(deblur, 64, 1, 10) == pytest.approx(4 * f1, rel=0.01)   # linear in pixels


def test_train_seeds_reuses_the_record_of_a_finished_run(tmp_path):
    from rdnet.study.training import train_seeds
    from rdnet.train.config import ModelConfig, TrainConfig
    from rdnet.train.synthetic import write_synthetic_pairs
    pairs = write_synthetic_pairs(tmp_path / "train.h5", n=4, bins=3, height=16, width=16, seed=1)
    cfg = TrainConfig(iterations=2, batch_size=2, crop=16, device="cpu", log_every=1, ckpt_every=1,
                      dvclive=False, threads=1)
    net, study = NetworkConfig(task="deblur"), StudyConfig(seeds=(0, 1), parallel=1)
    first = train_seeds(net, study, cfg, ModelConfig(size="tiny", width=4), pairs, tmp_path / "m", progress=False)
    assert [r["seed"] for r in first["runs"]] == [0, 1] and all("train_gflop" in r for r in first["runs"])
    again = train_seeds(net, study, cfg, ModelConfig(size="tiny", width=4), pairs, tmp_path / "m", progress=False)
    assert again["runs"] == first["runs"]          # finished: the measured record is kept, not re-timed


def test_seed_paired_needs_the_same_seeds_on_both_rows():
    from rdnet.study.report import seed_paired
    a = {"psnr": 30.0, "psnr_seeds": [29.0, 31.0], "seeds": [0, 1]}
    assert seed_paired(a, dict(a))
    assert not seed_paired(a, {**a, "seeds": [0, 2]})            # other seeds: not paired
    assert not seed_paired(a, {"psnr": 29.0})                     # an untrained row (no seeds)
    assert not seed_paired(a, None) and not seed_paired(None, a)  # a row that was not scored
