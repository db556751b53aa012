"""Train one network of the study once per seed (``study.seeds``), optionally several
seeds at once in worker processes (``study.parallel``).

Layout of ``out_dir``::

    seed0/model.pt  seed0/train.json     # train.json: seed, iterations, parameters, FLOPs
    seed1/...
    summary.json                          # the per-seed train.json entries + totals

``train.json`` records the optimisation steps and FLOPs of each training so that the
report can put every row's training compute beside its PSNR (the equal-compute
comparison of RDNet and DeblurNet). The wall times go to a sidecar *outside* ``out_dir``
(``timing``, default ``<out_dir>.timing.json``; ``summary.json`` names it): everything in
``out_dir`` is then a function of the settings and the data, so a rerun that reproduces
the weights reproduces the directory byte for byte and DVC sees an unchanged out.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from rdnet.study.config import NetworkConfig, StudyConfig, seed_checkpoint, seed_dir

log = logging.getLogger(__name__)


def _seed_train_cfg(train_cfg, net: NetworkConfig, seed: int):
    iters = max(1, int(round(train_cfg.iterations * net.iterations_factor)))
    return dataclasses.replace(train_cfg, seed=int(seed), iterations=iters)


def forward_flops(net, crop: int, image_channels: int, bins: int) -> float:
    """FLOPs of one forward pass of ``net`` on one ``crop`` x ``crop`` sample (torch's
    FlopCounterMode: convolutions and matrix products). A training step costs about
    three forward passes (forward + backward); for RDNet the forward runs both stages."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode
    image = torch.zeros(1, image_channels, crop, crop) if image_channels else None
    stage1 = getattr(net, "restore", net)            # a count-output stage 1 reads 2 x bins channels
    voxel = torch.zeros(1, getattr(stage1, "in_channels", bins), crop, crop)
    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        if getattr(net, "use_events", True):
            net(image, voxel)
        else:
            net(image)
    return float(counter.get_total_flops())


def timing_path(out_dir: str | Path) -> Path:
    """Default wall-time sidecar of a network directory: beside it, not in it."""
    out_dir = Path(out_dir)
    return out_dir.with_name(out_dir.name + ".timing.json")


def read_timing(path: Path | None) -> dict:
    """{seed: wall_s} of a timing sidecar ({} when absent or unreadable)."""
    try:
        return {int(r["seed"]): r["wall_s"] for r in json.loads(Path(path).read_text())["runs"]}
    except (OSError, TypeError, ValueError, KeyError):
        return {}


def _train_one(task, train_cfg, model_cfg, train_path, out, events, init, init_deblur, guide, progress) -> dict:
    """Worker body: one seed's training (also run in-process when parallel is 1). Returns
    the train.json record plus ``wall_s`` (None for a finished run, not re-timed)."""
    from rdnet.train.loop import train
    out = Path(out)
    record_path = out / "train.json"
    # a finished run (model.pt, no last.pt) is only re-checked by train(): keep its record
    finished = record_path.is_file() and (out / "model.pt").is_file() and not (out / "last.pt").is_file()
    t0 = time.perf_counter()
    ck = train(task, train_cfg, model_cfg, train_path, out, events=events, init_checkpoint=init,
               init_deblur=init_deblur, resume=True, progress=progress, guide=guide)
    wall = time.perf_counter() - t0
    if finished:
        return {"wall_s": None, **json.loads(record_path.read_text())}   # older records hold wall_s
    from rdnet.train.checkpoint import load_model, read_checkpoint
    net, args = load_model(ck), read_checkpoint(ck)["model_args"]
    n_params = int(sum(p.numel() for p in net.parameters()))
    step_flops = 3 * forward_flops(net, train_cfg.crop, int(args["image_channels"]), int(args["bins"]))
    gflop = step_flops * train_cfg.batch_size * train_cfg.iterations / 1e9
    from rdnet.eval.report import write_text_atomic
    from rdnet.train.distributed import dist_info
    record = {"seed": train_cfg.seed, "task": task, "events": events, "iterations": train_cfg.iterations,
              "parameters": n_params, "train_gflop": round(gflop, 1), "checkpoint": str(ck),
              "threads": train_cfg.threads, "processes": dist_info().world_size}
    if dist_info().rank == 0:
        write_text_atomic(record_path, json.dumps(record, indent=2) + "\n")
    return {**record, "wall_s": round(wall, 2)}


def train_seeds(net: NetworkConfig, study: StudyConfig, train_cfg, model_cfg, train_path: str | Path,
                out_dir: str | Path, *, init: str | Path | None = None, init_deblur: str | Path | None = None,
                progress: bool = True, timing: str | Path | None = None, guide=None) -> dict:
    """Train ``net`` for every seed of ``study`` into ``out_dir/seed<k>``; ``guide``: the
    frame-pair guide of task restore_frames (:func:`rdnet.train.run.frame_pair_guide`); ``init`` (a
    network directory or a ``.pt`` file) gives each seed's starting weights, seed by seed
    (:func:`~rdnet.study.config.seed_checkpoint`), and ``init_deblur`` RDNet's stage 2.
    Writes ``summary.json`` (no wall time) and the wall times to ``timing`` (default
    :func:`timing_path`); returns the summary with each run's ``wall_s`` and
    ``wall_s_total`` (a finished run keeps its recorded time)."""
    from rdnet.errors import ConfigError
    from rdnet.train.distributed import dist_info
    out_dir = Path(out_dir)
    if dist_info().world_size > 1 and study.parallel > 1:
        raise ConfigError("study.parallel", "must be 1 under torchrun (the processes are data-parallel ranks)")
    jobs = []
    for s in study.seeds:
        cfg = _seed_train_cfg(train_cfg, net, s)
        ini = None if init is None else str(seed_checkpoint(init, s))
        ini2 = None if init_deblur is None else str(seed_checkpoint(init_deblur, s))
        jobs.append((net.task, cfg, model_cfg, str(train_path), str(seed_dir(out_dir, s)), net.events, ini, ini2,
                     guide))
    workers = min(study.parallel, len(jobs))
    if workers == 1:
        records = [_train_one(*j, progress) for j in jobs]
    else:
        log.info("training %d seeds of %s, %d at a time", len(jobs), net.task, workers)
        # spawn: a clean interpreter per worker (no forked torch/OpenMP state)
        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
            futures = [ex.submit(_train_one, *j, False) for j in jobs]
            records = []
            for s, f in zip(study.seeds, futures):
                records.append(f.result())
                log.info("seed %d done in %.0f s", s, records[-1]["wall_s"] or 0.0)
    timing = timing_path(out_dir) if timing is None else Path(timing)
    before = read_timing(timing)
    walls = [before.get(int(r["seed"])) if r["wall_s"] is None else r["wall_s"] for r in records]
    runs = [{k: v for k, v in r.items() if k != "wall_s"} for r in records]
    summary = {"task": net.task, "events": net.events, "iterations_factor": net.iterations_factor,
               "seeds": list(study.seeds), "init": None if init is None else str(init),
               "init_deblur": None if init_deblur is None else str(init_deblur), "runs": runs,
               "parameters": records[0]["parameters"], "timing": str(timing)}
    times = {"runs": [{"seed": r["seed"], "wall_s": w} for r, w in zip(runs, walls)],
             "wall_s_total": round(sum(w for w in walls if w is not None), 2)}
    from rdnet.eval.report import write_text_atomic
    if dist_info().rank == 0:
        write_text_atomic(out_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
        timing.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(timing, json.dumps(times, indent=2) + "\n")
    return {**summary, "runs": [{**r, "wall_s": w} for r, w in zip(runs, walls)],
            "wall_s_total": times["wall_s_total"]}
