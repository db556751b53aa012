"""The training loop: losses go down, stopping and resuming gives the same weights as an
uninterrupted run, stage 2 starts from stage 1, resume guards, the run entry point."""
import csv
import json
import os
import subprocess
import sys
import textwrap

import pytest
import torch

from rdnet.errors import ConfigError, FormatError
from rdnet.train.checkpoint import make_checkpoint, read_checkpoint, save_checkpoint
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.data import PairsDataset
from rdnet.train.loop import build_seeded, compute_loss, make_optimizer, model_args, train
from rdnet.train.synthetic import write_synthetic_pairs

TINY = ModelConfig(size="tiny", width=4)
CFG = TrainConfig(iterations=4, batch_size=4, crop=16, device="cpu", log_every=2, ckpt_every=2,
                  dvclive=False, seed=3)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    return write_synthetic_pairs(tmp_path_factory.mktemp("pairs") / "train.h5", n=6, bins=3,
                                 height=24, width=24, seed=2)


def weights(path):
    return read_checkpoint(path)["state_dict"]


@pytest.mark.parametrize("task", ["restore", "deblur", "image_only", "rdnet"])
def test_one_step_lowers_the_loss_on_a_fixed_batch(pairs, task):
    ds = PairsDataset(pairs, crop=16, augment=False)
    batch = {k: torch.stack([ds[i][k] for i in range(4)]) for k in ds[0]}
    cfg = TrainConfig(lr=1e-4, iterations=10, device="cpu")
    net = build_seeded(model_args(task, TINY, 1, 3), seed=0)
    # move off the exact identity map of the fresh residual nets, where the L1 losses sit
    # on their kinks (zero residuals) and a gradient step need not descend
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 1e-2)
    opt, sched = make_optimizer(task, net, cfg)
    before, _ = compute_loss(task, net, batch, cfg)
    opt.zero_grad()
    before.backward()
    opt.step()
    with torch.no_grad():
        after, parts = compute_loss(task, net, batch, cfg)
    assert after.item() < before.item()
    if task == "rdnet":
        assert parts["loss_restore"].item() > 0  # the feature term is active


@pytest.mark.parametrize("feature_grad", [False, True])
def test_the_feature_term_trains_stage_2s_encoder_only_with_feature_grad(pairs, feature_grad):
    from rdnet.nn.losses import deblur_loss
    ds = PairsDataset(pairs, crop=16, augment=False)
    batch = {k: torch.stack([ds[i][k] for i in range(4)]) for k in ds[0]}
    net = build_seeded(model_args("rdnet", TINY, 1, 3), seed=0)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn(p.shape, generator=g) * 1e-2)
    cfg = TrainConfig(device="cpu", feature_grad=feature_grad, beta=0.5, stage2_alpha=0.0)
    loss, parts = compute_loss("rdnet", net, batch, cfg)
    assert parts["loss_restore"].item() > 0
    loss.backward()
    total = {k: p.grad.clone() for k, p in net.deblur.named_parameters() if p.grad is not None}
    net.zero_grad()
    _, pred = net(batch["blurry"], batch["voxel_degraded"])     # the signed stage 1 (cfg default)
    deblur_loss(pred, batch["sharp"]).backward()        # the deblurring term alone
    alone = {k: p.grad.clone() for k, p in net.deblur.named_parameters() if p.grad is not None}
    assert total.keys() == alone.keys()
    same = all(torch.allclose(total[k], alone[k], atol=1e-7) for k in total)
    assert same is (not feature_grad)                  # the feature term reaches F only when asked


def test_stop_and_resume_in_a_new_process_equals_uninterrupted(pairs, tmp_path):
    straight = train("deblur", CFG, TINY, pairs, tmp_path / "a", progress=False)
    part = train("deblur", CFG, TINY, pairs, tmp_path / "b", progress=False, stop_after=2)
    assert part.name == "last.pt" and read_checkpoint(part)["step"] == 2
    assert not (tmp_path / "b" / "model.pt").exists()
    code = textwrap.dedent(f"""
        import torch
        torch.manual_seed(999)  # unrelated global RNG state must not matter
        from rdnet.train.config import ModelConfig, TrainConfig
        from rdnet.train.loop import train
        cfg = TrainConfig(**{{**{CFG.__dict__!r}, "num_workers": 2}})  # workers: same batches
        print(train("deblur", cfg, ModelConfig(size="tiny", width=4), {str(pairs)!r},
                    {str(tmp_path / "b")!r}, progress=False))
    """)
    env_threads = {"OMP_NUM_THREADS": str(torch.get_num_threads())}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, **env_threads})
    assert out.returncode == 0, out.stderr
    resumed = tmp_path / "b" / "model.pt"
    assert out.stdout.strip().endswith("model.pt") and resumed.is_file()
    assert not (tmp_path / "b" / "last.pt").exists()
    wa, wb = weights(straight), weights(resumed)
    assert wa.keys() == wb.keys()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    # and training changed the weights (the comparison is not between two fresh nets)
    fresh = build_seeded(model_args("deblur", TINY, 1, 3), CFG.seed).state_dict()
    assert any(not torch.equal(fresh[k], wa[k]) for k in wa)


def test_resume_refuses_other_settings_and_finished_run_is_reused(pairs, tmp_path):
    train("restore", CFG, TINY, pairs, tmp_path, progress=False, stop_after=2)
    other = TrainConfig(**{**CFG.__dict__, "lr": 1e-3})
    with pytest.raises(ConfigError, match=r"train\.lr.*last\.pt"):
        train("restore", other, TINY, pairs, tmp_path, progress=False)
    with pytest.raises(ConfigError, match="task"):
        train("deblur", CFG, TINY, pairs, tmp_path, progress=False)
    done = train("restore", CFG, TINY, pairs, tmp_path, progress=False)
    mtime = done.stat().st_mtime_ns
    assert train("restore", CFG, TINY, pairs, tmp_path, progress=False) == done
    assert done.stat().st_mtime_ns == mtime  # complete: nothing retrained


def test_count_loss_stored_only_off_its_default_and_resume_compares_it(pairs, tmp_path):
    """train.count_loss was added after the study's checkpoints: at its default (l1) it stays out
    of the checkpoint's config (those checkpoints stay byte-identical), and a resume still sees a
    change in either direction."""
    train("restore", CFG, TINY, pairs, tmp_path / "l1", progress=False, stop_after=2)
    assert "count_loss" not in read_checkpoint(tmp_path / "l1" / "last.pt")["config"]
    poisson = TrainConfig(**{**CFG.__dict__, "count_loss": "poisson"})
    with pytest.raises(ConfigError, match=r"train\.count_loss.*'l1'.*'poisson'"):
        train("restore", poisson, TINY, pairs, tmp_path / "l1", progress=False)
    train("restore", poisson, TINY, pairs, tmp_path / "p", progress=False, stop_after=2)
    assert read_checkpoint(tmp_path / "p" / "last.pt")["config"]["count_loss"] == "poisson"
    with pytest.raises(ConfigError, match=r"train\.count_loss.*'poisson'.*'l1'"):
        train("restore", CFG, TINY, pairs, tmp_path / "p", progress=False)


def test_stage2_starts_from_stage1_and_can_freeze_it(pairs, tmp_path, caplog):
    cfg = TrainConfig(**{**CFG.__dict__, "iterations": 2})
    stage1 = train("restore", cfg, TINY, pairs, tmp_path / "s1", progress=False)
    frozen = TrainConfig(**{**cfg.__dict__, "finetune_restore": False})
    with caplog.at_level("WARNING", logger="rdnet.train.loop"):
        s2 = train("rdnet", frozen, TINY, pairs, tmp_path / "s2", init_checkpoint=stage1, progress=False)
    assert "without init_checkpoint" not in caplog.text        # it was given (the warning once came anyway)
    with caplog.at_level("WARNING", logger="rdnet.train.loop"):
        train("rdnet", frozen, TINY, pairs, tmp_path / "s2r", progress=False)
    assert "without init_checkpoint" in caplog.text
    w1, w2 = weights(stage1), weights(s2)
    assert all(torch.equal(w1[k], w2[f"restore.{k}"]) for k in w1)
    tuned = train("rdnet", cfg, TINY, pairs, tmp_path / "s2b", init_checkpoint=stage1, progress=False)
    w3 = weights(tuned)
    assert any(not torch.equal(w1[k], w3[f"restore.{k}"]) for k in w1)
    args = model_args("deblur", TINY, 1, 3)
    deblur = save_checkpoint(tmp_path / "d.pt", make_checkpoint(build_seeded(args, 0), "deblur", args))
    with pytest.raises(FormatError, match=r"model_kind.*'deblur'"):
        train("rdnet", cfg, TINY, pairs, tmp_path / "s2c", init_checkpoint=deblur, progress=False)


def test_stage2_can_start_from_a_deblurnet(pairs, tmp_path):
    from rdnet.train.loop import _init_deblur
    args = model_args("deblur", TINY, 1, 3)
    deblur = build_seeded(args, 5)
    path = save_checkpoint(tmp_path / "d.pt", make_checkpoint(deblur, "deblur", args))
    rd_args = model_args("rdnet", TINY, 1, 3)
    rdnet = build_seeded(rd_args, 0)
    assert any(not torch.equal(v, rdnet.deblur.state_dict()[k]) for k, v in deblur.state_dict().items())
    _init_deblur("rdnet", rdnet, path, rd_args)
    assert all(torch.equal(v, rdnet.deblur.state_dict()[k]) for k, v in deblur.state_dict().items())
    with pytest.raises(ConfigError, match="init_deblur"):
        _init_deblur("deblur", deblur, path, args)
    other = model_args("deblur", ModelConfig(size="tiny", width=6), 1, 3)
    wrong = save_checkpoint(tmp_path / "w.pt", make_checkpoint(build_seeded(other, 0), "deblur", other))
    with pytest.raises(FormatError, match="model_args"):
        _init_deblur("rdnet", rdnet, wrong, rd_args)
    cfg = TrainConfig(**{**CFG.__dict__, "iterations": 2})
    stage1 = train("restore", cfg, TINY, pairs, tmp_path / "s1", progress=False)
    out = train("rdnet", cfg, TINY, pairs, tmp_path / "rd", init_checkpoint=stage1, init_deblur=path, progress=False)
    assert read_checkpoint(out)["extra"]["init_deblur"] == str(path)


def test_dvclive_metrics_and_cosine_schedule(pairs, tmp_path):
    cfg = TrainConfig(**{**CFG.__dict__, "iterations": 4, "dvclive": True, "lr": 1e-3, "lr_min": 1e-5})
    train("image_only", cfg, TINY, pairs, tmp_path, progress=False)
    live = tmp_path / "dvclive"
    summary = json.loads((live / "metrics.json").read_text())
    assert summary["step"] == 4 and summary["train"]["loss"] > 0
    with open(live / "plots" / "metrics" / "train" / "lr.tsv") as f:
        lr = {int(r["step"]): float(r["lr"]) for r in csv.DictReader(f, delimiter="\t")}
    # logged after steps 2 and 4 of a cosine from 1e-3 to 1e-5 over 4 steps
    assert lr == pytest.approx({2: 1e-5 + (1e-3 - 1e-5) / 2, 4: 1e-5})
    assert not (tmp_path.parent / "dvc.yaml").exists()


def test_run_entry_point_reports_user_errors(pairs, tmp_path, capsys):
    from rdnet.train.run import main
    (tmp_path / "p.yaml").write_text("train:\n  iterations: 0\nmodel:\n  size: tiny\n")
    rc = main(["--task", "deblur", "--params", str(tmp_path / "p.yaml"), "--train", str(pairs),
               "--out", str(tmp_path / "o"), "--no-progress"])
    assert rc == 2
    assert "train.iterations" in capsys.readouterr().err

