"""Two CPU processes under torchrun (gloo): the run completes, both ranks end with
identical weights, and the result matches a single-process run of the same global batch."""
import os
import subprocess
import sys

import torch

from rdnet.train.checkpoint import read_checkpoint
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.loop import build_seeded, model_args, train
from rdnet.train.synthetic import write_synthetic_pairs

PARAMS = """\
train:
  iterations: 3
  batch_size: 4
  crop: 16
  device: cpu
  seed: 1
  log_every: 1
  ckpt_every: 2
  dvclive: false
model:
  size: tiny
  width: 4
"""


def test_torchrun_two_processes(tmp_path):
    pairs = write_synthetic_pairs(tmp_path / "train.h5", n=6, bins=3, height=24, width=24, seed=4)
    (tmp_path / "params.yaml").write_text(PARAMS)
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
           "-m", "rdnet.train.run", "--task", "deblur", "--params", "params.yaml",
           "--train", str(pairs), "--out", "ddp", "--no-progress"]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=180,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert out.returncode == 0, out.stderr[-3000:]
    ck = read_checkpoint(tmp_path / "ddp" / "model.pt")
    assert ck["step"] == 3
    digests = ck["replica_digests"]
    assert len(digests) == 2 and digests[0] == digests[1]
    assert not (tmp_path / "ddp" / "last.pt").exists()

    cfg = TrainConfig(iterations=3, batch_size=4, crop=16, device="cpu", seed=1, log_every=1,
                      ckpt_every=2, dvclive=False)
    single = read_checkpoint(train("deblur", cfg, ModelConfig(size="tiny", width=4), pairs,
                                   tmp_path / "single", progress=False))
    a, b = ck["state_dict"], single["state_dict"]
    # same global batches; only the float summation order of the gradient differs
    assert all(torch.allclose(a[k], b[k], rtol=0, atol=1e-5) for k in a)
    # ... and training moved the weights much further than that tolerance
    fresh = build_seeded(model_args("deblur", ModelConfig(size="tiny", width=4), 1, 3), 1).state_dict()
    assert max((a[k] - fresh[k]).abs().max().item() for k in a) > 1e-4
