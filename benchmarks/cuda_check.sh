#!/bin/bash
# The CUDA path end to end, on a machine with an NVIDIA GPU (not run by `make bench`, which
# runs benchmarks/bench_*.py on CPU). Usage, from the repository root, with rdnet importable:
#
#   OUT=some/folder bash benchmarks/cuda_check.sh
#
# Needs the study's models/rdnet (dvc repro) and data/pairs/train.h5. Writes OUT/e2e.log (rdnet
# restore and rdnet deblur on DAVIS346 on cuda and on cpu, compared; stage 1 and RDNet trained a
# few steps on cuda, RDNet initialised from that stage 1), OUT/paper.log (training speed and
# peak GPU memory of the paper-size networks: 256x256 crops, batch 8, 10 bins, two run lengths,
# so start-up cancels in the difference) and OUT/pytest.log (the test suite, where the default
# device `auto` picks cuda). Results: benchmarks/results/cuda_check.md.
set -u
: "${OUT:?set OUT to an output folder}"
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
PY=${PYTHON:-python3}
T=$(mktemp -d)
R=data/real/davis346_road/davis346.aedat4
step() { echo "=== $1 ($(date +%T))"; }
{ nvidia-smi -L; $PY -c "import torch,numpy,numba;print('torch',torch.__version__,'cuda',torch.version.cuda,torch.cuda.get_device_name(),'numpy',numpy.__version__,'numba',numba.__version__)"; nproc; } 2>&1 | tee "$OUT/env.txt"
{
for dev in cuda cpu; do
  step "rdnet restore on $dev"; timeout 300 $PY -m rdnet.cli restore $R "$T/r_$dev.h5" --set restore.device=$dev --no-progress; echo rc=$?
done
$PY - "$T" <<'PYEOF'
import json, sys
import h5py, numpy as np
t = sys.argv[1]
def flat(d, p=""):
    out = {}
    for k, v in d.items():
        out.update(flat(v, p + k + ".") if isinstance(v, dict) else {p + k: v})
    return out
a, b = (flat(json.load(open(f"{t}/r_{d}.json"))) for d in ("cuda", "cpu"))
for k in sorted(a):
    if a[k] != b.get(k):
        print(f"json differs: {k}: cuda {a[k]} cpu {b.get(k)}")
ea, eb = (h5py.File(f"{t}/r_{d}.h5")["events"] for d in ("cuda", "cpu"))
print("events cuda", ea["t"].shape[0], "cpu", eb["t"].shape[0],
      "identical" if all(np.array_equal(ea[k], eb[k]) for k in ("t", "x", "y", "p")) else "not identical")
PYEOF
for dev in cuda cpu; do
  step "rdnet deblur on $dev (8 frames)"; timeout 300 $PY -m rdnet.cli deblur $R "$T/d_$dev" --set deblur.device=$dev --set deblur.max_frames=8 --no-progress; echo rc=$?
done
$PY -c "import json; print({d: json.load(open('$T/d_'+d+'/consistency.json'))['restored'] for d in ('cuda','cpu')})"
step "train stage 1 on cuda"; timeout 300 $PY -m rdnet.train.run --task restore --train data/pairs/train.h5 --out "$T/tr" --set train.iterations=60 --set train.device=cuda --set train.dvclive=false --set train.log_every=20 --no-progress; echo rc=$?
step "train rdnet on cuda, stage 1 from that run"; timeout 300 $PY -m rdnet.train.run --task rdnet --init "$T/tr/model.pt" --train data/pairs/train.h5 --out "$T/rd" --set train.iterations=40 --set train.ckpt_every=20 --set train.device=cuda --set train.dvclive=false --set train.log_every=20 --no-progress; echo rc=$?
$PY -c "from rdnet.train.checkpoint import read_checkpoint as r; c=r('$T/rd/model.pt'); print('checkpoint step', c['step'], 'tensors on', {str(v.device) for v in c['state_dict'].values()})"
} 2>&1 | tee "$OUT/e2e.log"
step "paper-size training speed on cuda" | tee "$OUT/paper.log"
timeout 400 $PY - "$T" <<'PYEOF' 2>&1 | tee -a "$OUT/paper.log"
import sys, time, torch
from rdnet.train.synthetic import write_synthetic_pairs
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.loop import train
t = sys.argv[1]
pairs = write_synthetic_pairs(f"{t}/big.h5", n=24, bins=10, height=288, width=288, seed=0)
for task in ("deblur", "rdnet"):
    for iterations in (10, 70):
        cfg = TrainConfig(iterations=iterations, batch_size=8, crop=256, device="cuda", seed=0, log_every=1000,
                          ckpt_every=100000, dvclive=False, val_sequences=0 if task == "deblur" else 1)
        torch.cuda.reset_peak_memory_stats(); start = time.perf_counter()
        train(task, cfg, ModelConfig(size="paper"), pairs, f"{t}/o_{task}{iterations}", progress=False)
        torch.cuda.synchronize()
        print(task, "paper size, crop 256, batch 8:", iterations, "iterations", round(time.perf_counter() - start, 2),
              "s, peak GiB", round(torch.cuda.max_memory_allocated() / 2**30, 2), flush=True)
PYEOF
step "test suite (device auto -> cuda)" | tee "$OUT/pytest.log"
timeout 600 $PY -m pytest -q -p no:cacheprovider -n 12 --timeout 200 2>&1 | tail -60 >> "$OUT/pytest.log"
rm -rf "$T"
