"""DVCLive inside ``dvc repro``: a training stage with ``train.dvclive: true`` logs into
its own output folder (OUT/dvclive: metrics.json, params.yaml, plots/metrics/train/*.tsv),
writes no dvc.yaml and saves no experiment, and the stage's cached output holds the
logs. A one-stage DVC project in a temporary git repository, a few training steps."""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from rdnet.train.synthetic import write_synthetic_pairs

ROOT = Path(__file__).resolve().parents[2]
DVC = Path(sys.executable).with_name("dvc")

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not DVC.exists(), reason="dvc not installed beside this python")]

DVC_YAML = """\
stages:
  train:
    cmd: python -m rdnet.train.run --task deblur --train pairs.h5 --out models/net --no-progress
    deps: [pairs.h5]
    params: [model, train]
    outs: [models/net]
"""
PARAMS = """\
model: {size: tiny, width: 4}
train: {iterations: 4, batch_size: 2, crop: 16, log_every: 2, ckpt_every: 2, device: cpu, threads: 1,
        dvclive: true}
"""


def _shell(repo: Path):
    """Runs commands in ``repo`` (git identity set, this venv's dvc/python first on PATH);
    a failure shows the command's output."""
    env = {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]]),
           "PYTHONPATH": str(ROOT), "DVC_NO_ANALYTICS": "1"}
    for who in ("AUTHOR", "COMMITTER"):
        env[f"GIT_{who}_NAME"], env[f"GIT_{who}_EMAIL"] = "t", "t@t"

    def sh(*cmd: str) -> str:
        r = subprocess.run(list(cmd), cwd=repo, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, f"{cmd}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
        return r.stdout + r.stderr
    return sh


def test_dvclive_logs_into_the_stage_output_under_dvc_repro(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    write_synthetic_pairs(repo / "pairs.h5", n=4, bins=3, height=20, width=20, seed=1)
    (repo / "dvc.yaml").write_text(DVC_YAML)
    (repo / "params.yaml").write_text(PARAMS)
    sh = _shell(repo)
    sh("git", "init", "-q")
    sh(str(DVC), "init", "-q")
    sh("git", "add", "-A")
    sh("git", "commit", "-qm", "base")          # DVCLive needs a commit to attach to
    assert "dvclive disabled" not in sh(str(DVC), "repro")

    live = repo / "models" / "net" / "dvclive"
    summary = json.loads((live / "metrics.json").read_text())
    assert summary["step"] == 4 and summary["train"]["loss"] > 0
    with open(live / "plots" / "metrics" / "train" / "loss.tsv") as f:
        assert [int(r["step"]) for r in csv.DictReader(f, delimiter="\t")] == [2, 4]
    assert (live / "params.yaml").is_file()
    # no dvc.yaml of its own, nothing for git to add, no experiment saved: DVC alone owns the graph
    assert not list(repo.rglob("dvclive/dvc.yaml")) and (repo / "dvc.yaml").read_text() == DVC_YAML
    status = sh("git", "status", "--porcelain")
    assert "dvclive" not in status and "dvc.lock" in status
    assert sh("git", "for-each-ref", "refs/exps").strip() == ""
    # the logs are part of the stage's cached output
    lock = (repo / "dvc.lock").read_text()
    assert "models/net" in lock and "nfiles: 6" in lock        # model.pt, metrics.json, params.yaml, 3 tsv
