"""A network directory of the study holds only what the settings and data determine: a rerun
of the same training (DVC deletes the out, then reruns the stage) gives the same bytes, file
by file, so DVC sees an unchanged out; the wall times go to a sidecar outside it (issue 13)."""
import json
import shutil

import pytest

from rdnet.study.config import NetworkConfig, StudyConfig
from rdnet.study.report import network_compute
from rdnet.study.training import timing_path, train_seeds
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.synthetic import write_synthetic_pairs


def tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_rerun_repeats_the_network_directory_byte_for_byte_and_times_go_beside_it(tmp_path):
    pairs = write_synthetic_pairs(tmp_path / "train.h5", n=4, bins=3, height=16, width=16, seed=1)
    cfg = TrainConfig(iterations=2, batch_size=2, crop=16, device="cpu", log_every=1, ckpt_every=1,
                      dvclive=True, threads=1)
    net, study = NetworkConfig(task="deblur"), StudyConfig(seeds=(0,), parallel=1)
    out, side = tmp_path / "models" / "m", tmp_path / "metrics" / "m.json"
    runs = []
    for _ in range(2):
        shutil.rmtree(out, ignore_errors=True)
        s = train_seeds(net, study, cfg, ModelConfig(size="tiny", width=4), pairs, out, progress=False,
                        timing=side)
        runs.append((s, tree(out), json.loads(side.read_text())))
    (a, ta, sa), (b, tb, sb) = runs
    assert {"summary.json", "seed0/model.pt", "seed0/train.json"} <= set(ta)
    assert ta == tb                                   # every file, byte for byte (dvclive too)
    assert b"wall_s" not in ta["seed0/train.json"] + ta["summary.json"]
    assert json.loads(ta["summary.json"])["timing"] == str(side)
    # the wall times: in the sidecar and in the returned summary
    assert sa["runs"][0]["seed"] == 0 and sa["runs"][0]["wall_s"] == a["runs"][0]["wall_s"] > 0
    assert a["wall_s_total"] == sa["wall_s_total"] and sb["wall_s_total"] == b["wall_s_total"]
    assert network_compute(str(out))["train_s"] == pytest.approx(b["runs"][0]["wall_s"])
    assert timing_path(out) == tmp_path / "models" / "m.timing.json"     # the default: beside, not in
