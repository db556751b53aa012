"""Where the time of one training step goes (the loop of ``rdnet.train.loop.train``), to find
why a training on a GPU ran about 80 ms a step at the embedded study's 48-64 px crops for the
tiny and the paper-size stage 1 alike (benchmarks/results/restore_scale.md).

For one task, network size, crop and batch on one device, each variant runs ``--steps`` steps
after ``--warmup`` and reports the mean wall time per step:

- ``loop``: the training loop's own step: a batch from the ``DataLoader`` (crops and flips
  drawn on the host), moved to the device, loss, the finiteness check (``torch.isfinite(loss)``
  read on the host: a device synchronisation every step), backward, gradient clipping, Adam,
  the schedule;
- ``no_sync``: the same without the per-step finiteness check (the loss is read once at the end);
- ``staged``: ``no_sync`` on one batch already on the device (no data loading, no copy): the
  time of the network and the optimiser alone;
- ``forward``: the loss of the staged batch without backward and optimiser.

On a GPU, ``loop - no_sync`` is what the per-step synchronisation costs, ``no_sync - staged``
the host's data preparation and copy, and ``staged`` against the GPU's own kernel time (a
profiler) whether the step is bound by issuing kernels. On a CPU the differences say how much
of a step is data. ``--adam loop foreach --rounds 3`` times the step with the training's
Adam update (torch's per-parameter loop, its CPU default) against its multi-tensor update,
alternated round by round (session 41: the same weights bit for bit, no faster on CPU). Results: ``benchmarks/results/train_step.json`` (append with ``--label``).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_train_step.py --pairs data/pairs/train.h5 \\
        --task restore --size tiny --crop 48 --device cpu --threads 1
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.data import PairsDataset, StepSampler, split_rows
from rdnet.train.loop import (RESTORE_TASKS, build_seeded, compute_loss, make_optimizer, model_args, optimizer_step,
                              resolve_device)

ROOT = Path(__file__).resolve().parents[1]


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure(task: str, size: str, crop: int, batch: int, device_name: str, pairs: Path, steps: int,
            warmup: int, seed: int = 0, adam: str = "loop") -> dict:
    """Mean seconds per step of each variant (module docstring). ``adam``: ``loop`` (torch's
    per-parameter loop, its CPU default and the training's update) or ``foreach`` (its
    multi-tensor update, torch's default on CUDA)."""
    cfg = TrainConfig(iterations=steps + warmup, batch_size=batch, crop=crop, device=device_name, seed=seed,
                      dvclive=False, log_every=10 ** 6, ckpt_every=10 ** 6)
    device = resolve_device(cfg.device)
    rows, _ = split_rows(pairs, cfg.val_sequences if task in RESTORE_TASKS else 0)
    data = PairsDataset(pairs, crop=cfg.crop, augment=cfg.augment, seed=cfg.seed, rows=rows,
                        clean_fraction=cfg.clean_fraction if task in RESTORE_TASKS else 0.0)
    args = model_args(task, ModelConfig(size=size), data.info.channels, data.info.bins, cfg.model_output,
                      cfg.stage2_input)
    net = build_seeded(args, cfg.seed).to(device)
    net.train()
    opt, sched = make_optimizer(task, net, cfg)
    if device.type == "cpu":          # on CUDA both settings take torch's default there (foreach)
        for group in opt.param_groups:
            group["foreach"] = adam == "foreach"

    def step(batch, check: bool):
        loss, _ = compute_loss(task, net, batch, cfg)
        if check and not torch.isfinite(loss):
            raise FloatingPointError("non-finite loss")
        optimizer_step(net, opt, sched, loss, cfg.grad_clip)
        return loss

    def loader():
        sampler = StepSampler(len(data), cfg.batch_size, cfg.seed, 0, cfg.iterations, 0, 1)
        return DataLoader(data, batch_size=sampler.local, sampler=sampler, num_workers=0,
                          pin_memory=device.type == "cuda")

    def timed(run) -> float:
        _sync(device)
        t = time.perf_counter()
        run()
        _sync(device)
        return (time.perf_counter() - t) / steps

    def from_loader(check: bool):
        def run():
            it = iter(loader())
            for _ in range(warmup):
                step({k: v.to(device, non_blocking=True) for k, v in next(it).items()}, check)
            _sync(device)
            t = time.perf_counter()
            last = None
            for _ in range(steps):
                last = step({k: v.to(device, non_blocking=True) for k, v in next(it).items()}, check)
            float(last.detach())
            _sync(device)
            return (time.perf_counter() - t) / steps
        return run()

    out = {"loop": from_loader(True), "no_sync": from_loader(False)}
    staged = {k: v.to(device) for k, v in next(iter(loader())).items()}
    for _ in range(warmup):
        step(staged, False)
    out["staged"] = timed(lambda: [step(staged, False) for _ in range(steps)])
    with torch.no_grad():
        out["forward"] = timed(lambda: [compute_loss(task, net, staged, cfg) for _ in range(steps)])
    data.close()
    return {k: round(v * 1e3, 2) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=Path, default=ROOT / "data" / "pairs" / "train.h5")
    ap.add_argument("--task", default="restore")
    ap.add_argument("--size", nargs="*", default=["tiny"], help="model.size values")
    ap.add_argument("--crop", type=int, nargs="*", default=[48])
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--adam", nargs="+", default=["loop"], choices=["loop", "foreach"],
                    help="Adam's update on CPU: the per-parameter loop (the training's) or the multi-tensor one")
    ap.add_argument("--rounds", type=int, default=1, help="each --adam setting this many times, alternated")
    ap.add_argument("--label", default=None, help="results key (default: the device)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "train_step.json")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    name = torch.cuda.get_device_name() if args.device == "cuda" else f"cpu ({os.cpu_count()} cores, {args.threads} thread(s))"
    rows = []
    for size in args.size:
        for crop in args.crop:
            for rnd in range(args.rounds):
                for adam in args.adam:
                    ms = measure(args.task, size, crop, args.batch, args.device, args.pairs, args.steps,
                                 args.warmup, adam=adam)
                    rows.append({"task": args.task, "size": size, "crop": crop, "batch": args.batch,
                                 "adam": adam, "round": rnd, "ms_per_step": ms})
                    print(json.dumps(rows[-1]), flush=True)
    res = json.loads(args.out.read_text()) if args.out.exists() else {"benchmark": "train_step", "runs": {}}
    res["runs"][args.label or args.device] = {"device": name, "python": platform.python_version(),
                                              "torch": torch.__version__, "steps": args.steps,
                                              "warmup": args.warmup, "rows": rows,
                                              "load_average_1min": os.getloadavg()[0]}
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(json.dumps(res, indent=2) + "\n")
    os.replace(tmp, args.out)


if __name__ == "__main__":
    main()
