"""The training loop of both RDNet stages and the baselines.

Tasks (:data:`TASKS`) and their objectives (RDNet paper, Sec. 3.4):

* ``restore`` -- stage 1, :class:`~rdnet.nn.models.RestoreNet` on (blurry, E_d) trained
  towards E_u. ``train.restore_output: signed_masked`` (the paper): signed voxels and
  the restoration loss ``alpha * |M (E_r - E_u)|_1`` (Eq. 8; M the voxels where E_u or
  E_d has events, :func:`rdnet.nn.losses.restoration_loss`). ``counts``: per-polarity
  counts, occupancy BCE on every voxel + a count term where events are (``train.count_loss``:
  L1 or Poisson; :func:`rdnet.nn.losses.count_restoration_loss`); after training the voxel -> event
  decision is fitted on the ``train.val_sequences`` held-out sequences
  (:func:`fit_decision`) and stored in ``model.pt`` as ``extra["decision"]``.
* ``restore_events`` -- the same without the image branch (events-only restorer for
  cameras without frames; ``image_channels = 0``).
* ``restore_frames`` -- the same guided by the two sharp frames that bracket the window
  instead of the blurry one (``guide``, :class:`rdnet.nn.guide.FramePairGuide`: the first
  frame and the log change to the last over the threshold; ``image_channels = C + 1``);
  the restorer of recordings with frames that says how many events a window lost
  (docs/restoration.md, "The frames bracketing the window").
* ``deblur`` / ``deblurnet_matched`` -- a :class:`~rdnet.nn.models.DeblurNet` on
  (blurry, E) with E the ``events`` kind (undegraded or degraded), trained with L_d
  (:func:`rdnet.nn.losses.deblur_loss`) towards the sharp frame.
* ``image_only`` -- the DeblurNet without event branch, L_d.
* ``rdnet`` -- stage 2: RDNet (stage 1 initialised from a stage-1 checkpoint,
  ``init_checkpoint``, and fine-tuned when ``train.finetune_restore``) trained on
  ``L_d + beta * |F(E_r) - F(E_u)|_1`` (Eq. 9; F the deblurring network's event
  encoder) plus ``stage2_alpha`` times the masked voxel term (0 by default). With a
  counts stage 1, stage 1 reads per-polarity counts and stage 2 the signed expected
  counts (:class:`~rdnet.nn.models.RDNet`); model.pt carries the decision refitted on the
  stage-1 checkpoint's validation rows when stage 1 was fine-tuned (else its decision).

Optimiser: Adam, cosine annealing from ``lr`` to ``lr_min`` over ``iterations`` steps
(``CosineAnnealingLR(T_max=iterations, eta_min=lr_min)``, paper Sec. 4.1).

Reproducibility: the network is initialised from ``torch.manual_seed(seed)`` (in a
forked RNG scope), the rows and crops of step ``s`` are a pure function of
``(seed, s)`` (:mod:`rdnet.train.data`), and the networks have no dropout; a run
stopped after a checkpoint and resumed ends with the same weights as an uninterrupted
run (bit-identical on CPU with the same thread count).

Outputs in ``out_dir``: ``last.pt`` every ``ckpt_every`` steps (full state for
resuming, removed once the run is complete), ``model.pt`` at the end (weights and
description, no optimiser state), ``dvclive/`` metrics.
"""
from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
from torch import nn
from torch.utils.data import DataLoader

from rdnet.config import to_dict
from rdnet.errors import ConfigError, FormatError
from rdnet.nn.models import EventEncoder
from rdnet.train import checkpoint as ckpt_mod
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.data import (PairsDataset, StepSampler, check_finite, pairs_dataset, read_pairs_voxel,
                              split_rows)
from rdnet.train.distributed import DistInfo, dist_info, all_reduce_mean, barrier, replica_digests

log = logging.getLogger(__name__)

#: task -> network kind of :func:`rdnet.nn.models.build_model`.
TASKS = {"restore": "restore", "restore_events": "restore", "restore_frames": "restore", "deblur": "deblur",
         "deblurnet_matched": "deblurnet_matched", "image_only": "image_only", "rdnet": "rdnet"}
#: train keys that may change between a checkpoint and the run that resumes it.
RESUME_FREE = ("log_every", "ckpt_every", "num_workers", "threads", "device", "dvclive")
#: tasks trained on stage-1 rows only (validation sequences held out, decision fitted).
RESTORE_TASKS = ("restore", "restore_events", "restore_frames")
#: tasks whose input events are a choice (``events``: undegraded or degraded); every other
#: task takes the default, degraded
EVENT_INPUT_TASKS = ("deblur", "deblurnet_matched")


def resolve_device(name: str, info: DistInfo | None = None, key: str = "train.device") -> torch.device:
    """'auto' -> cuda when available, else cpu; under torchrun on CUDA, cuda:LOCAL_RANK.
    ``key``: the params key the device came from, named by the error when cuda is asked for
    and absent."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(key, "cuda requested but no CUDA device is available")
        idx = info.local_rank if info is not None and info.world_size > 1 else torch.cuda.current_device()
        return torch.device("cuda", idx)
    return torch.device("cpu")


def model_args(task: str, model_cfg: ModelConfig, image_channels: int, bins: int,
               restore_output: str = "signed", stage2_input: str = "restored") -> dict:
    """Keyword arguments of ``build_model`` for ``task`` (stored in the checkpoint).
    ``restore_output`` (RestoreNet output, signed or counts) applies to the stage-1
    tasks and rdnet, ``stage2_input`` (restored or dual) to rdnet; each is stored only
    when not the default (old checkpoints stay equal)."""
    if task not in TASKS:
        raise ConfigError("task", f"unknown task {task!r}; known: {', '.join(TASKS)}")
    # restore_frames: the window's first frame and the log change to its last (rdnet.nn.guide)
    channels = {"restore_events": 0, "restore_frames": int(image_channels) + 1}.get(task, int(image_channels))
    args = {"kind": TASKS[task], "size": model_cfg.size, "image_channels": channels,
            "bins": int(bins), **model_cfg.overrides()}
    if restore_output != "signed" and task in RESTORE_TASKS + ("rdnet",):
        args["restore_output"] = restore_output
    if stage2_input != "restored" and task == "rdnet":
        args["stage2_input"] = stage2_input
    return args


def build_seeded(args: Mapping, seed: int) -> nn.Module:
    """The network of ``args`` initialised from ``torch.manual_seed(seed)`` without
    touching the caller's global RNG state."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return ckpt_mod.build_from_args(args)


# --- objectives -----------------------------------------------------------------------
def compute_loss(task: str, model: nn.Module, batch: Mapping[str, torch.Tensor],
                 cfg: TrainConfig) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """(loss, detached components) of one batch for ``task`` (module docstring)."""
    from rdnet.nn.losses import count_loss_terms, deblur_loss, restoration_loss

    blurry = batch["blurry"]
    net = ckpt_mod.unwrap(model)
    counts = cfg.restore_output == "counts"
    if task in RESTORE_TASKS:
        image = None if task == "restore_events" else stage1_image(batch)
        if counts:
            mu, logit = model(image, batch["counts_degraded"], return_heads=True)
            t = count_loss_terms(mu, logit, batch["counts_undegraded"], cfg.count_loss)
            loss = cfg.occupancy_weight * t["occupancy"] + cfg.alpha * t["count"]
            return loss, {"loss": loss.detach(), "loss_occupancy": t["occupancy"].detach(),
                          "loss_count": t["count"].detach()}
        restored = model(image, batch["voxel_degraded"])
        loss = restoration_loss(restored, batch["voxel_undegraded"], batch["voxel_degraded"],
                                alpha=cfg.alpha, empty_weight=cfg.empty_weight)
        return loss, {"loss": loss.detach()}
    if task in ("deblur", "deblurnet_matched"):
        pred = model(blurry, batch["voxel"])
    elif task == "image_only":
        pred = model(blurry, None)
    elif task == "rdnet":
        inp = batch["counts_degraded" if counts else "voxel_degraded"]
        restored, pred = model(blurry, inp)
        ld = deblur_loss(pred, batch["sharp"])
        # F of Eq. 9 is stage 2's event encoder on what stage 2 reads (with the raw voxel when dual);
        # a fixed encoder inside this term unless train.feature_grad
        encoder = EventEncoder(net.deblur)
        if cfg.feature_grad:
            features = lambda v: encoder(net.stage2_events(v, inp))  # noqa: E731
        else:
            fixed = {f"deblur.{k}": w.detach() for k, w in net.deblur.named_parameters()}
            features = lambda v: torch.func.functional_call(  # noqa: E731
                encoder, fixed, (net.stage2_events(v, inp),))
        lr = restoration_loss(restored, batch["voxel_undegraded"], batch["voxel_degraded"],
                              alpha=cfg.stage2_alpha, feature_fn=features,
                              beta=cfg.beta, empty_weight=cfg.empty_weight)
        loss = ld + lr
        return loss, {"loss": loss.detach(), "loss_deblur": ld.detach(), "loss_restore": lr.detach(),
                      "psnr": batch_psnr(pred.detach(), batch["sharp"])}
    else:
        raise ConfigError("task", f"unknown task {task!r}; known: {', '.join(TASKS)}")
    loss = deblur_loss(pred, batch["sharp"])
    return loss, {"loss": loss.detach(), "psnr": batch_psnr(pred.detach(), batch["sharp"])}


def batch_psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean PSNR (dB, peak 1) of a batch of [0, 1] images, clipped; a cheap training-time
    monitor (the reported metrics are :mod:`rdnet.eval.metrics`)."""
    mse = ((pred.clamp(0, 1) - target) ** 2).flatten(1).mean(1).clamp_min(1e-10)
    return (-10.0 * torch.log10(mse)).mean()


# --- optimiser ------------------------------------------------------------------------
def make_optimizer(task: str, net: nn.Module, cfg: TrainConfig):
    """Adam (stage-1 parameters of RDNet at ``lr * restore_lr_scale`` or frozen) and the
    cosine schedule to ``lr_min`` over ``iterations`` steps."""
    if task == "rdnet":
        rest = [p for n, p in net.named_parameters() if not n.startswith("restore.")]
        groups = [{"params": rest, "lr": cfg.lr}]
        if cfg.finetune_restore and cfg.restore_lr_scale > 0:
            groups.append({"params": list(net.restore.parameters()), "lr": cfg.lr * cfg.restore_lr_scale})
        else:
            for p in net.restore.parameters():
                p.requires_grad_(False)
    else:
        groups = [{"params": list(net.parameters()), "lr": cfg.lr}]
    opt = torch.optim.Adam(groups, lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.iterations, eta_min=cfg.lr_min)
    return opt, sched


def optimizer_step(net: nn.Module, opt, sched, loss: torch.Tensor, grad_clip: float) -> None:
    """One update from ``loss``: gradients of ``net`` (clipped to norm ``grad_clip`` when > 0),
    the optimiser's step and the schedule's."""
    opt.zero_grad(set_to_none=True)
    loss.backward()
    if grad_clip > 0:
        nn.utils.clip_grad_norm_(net.parameters(), grad_clip)
    opt.step()
    sched.step()


def _median_window_us(path: str | Path, rows) -> int | None:
    """Median exposure window (column ``duration_us``) of the training rows: the window
    length a stage-1 network was trained for (None when the file has no such column)."""
    import h5py
    with h5py.File(path, "r") as f:
        if "duration_us" not in f:
            return None
        d = np.asarray(pairs_dataset(f, path, "duration_us")[...])[np.asarray(rows, np.int64)]
    return int(np.median(d)) if d.size else None


# --- the voxel -> event decision -------------------------------------------------------
def stage1_image(batch: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """The image that guides stage 1: the batch's ``guide`` when its dataset builds one (the
    frame-pair guide, :class:`rdnet.train.data.PairsDataset`), else the blurry frame."""
    return batch["guide"] if "guide" in batch else batch["blurry"]


@torch.no_grad()
def predict_counts(net: nn.Module, data: PairsDataset, device: torch.device, *, image: bool = True,
                   batch_size: int = 8, with_support: bool = False):
    """Run a RestoreNet over every row of ``data`` (full frames): ``(mu, prob, target)``
    per-polarity arrays (N, 2 * bins, H, W) for the counts output; for the signed output
    ``(restored signed voxel, None, target signed voxel)``. ``with_support``: a fourth item,
    the inputs' :func:`rdnet.nn.decision.input_support` (N, 1, H, W) (None for the signed
    output)."""
    from rdnet.nn.decision import input_support
    net.eval()
    counts = net.output == "counts"
    outs, probs, targets, support = [], [], [], []
    for i0 in range(0, len(data), batch_size):
        rows = [data[i] for i in range(i0, min(len(data), i0 + batch_size))]
        batch = {k: torch.stack([r[k] for r in rows]).to(device) for k in rows[0] if k not in ("level", "index")}
        img = stage1_image(batch) if image else None
        if counts:
            mu, logit = net(img, batch["counts_degraded"], return_heads=True)
            outs.append(mu.cpu().numpy())
            probs.append(torch.sigmoid(logit).cpu().numpy())
            targets.append(batch["counts_undegraded"].cpu().numpy())
            support.append(input_support(batch["counts_degraded"]))
        else:
            outs.append(net(img, batch["voxel_degraded"]).cpu().numpy())
            targets.append(batch["voxel_undegraded"].cpu().numpy())
    cat = np.concatenate
    if with_support:
        return cat(outs), (cat(probs) if counts else None), cat(targets), (cat(support) if counts else None)
    return cat(outs), (cat(probs) if counts else None), cat(targets)


def fit_decision(net: nn.Module, train_path: str | Path, val_rows, device: torch.device, *,
                 image: bool = True, support_rule: bool = True, count_gain: bool = False, guide=None) -> dict:
    """The voxel -> event decision of a trained RestoreNet (``extra["decision"]``):
    counts output -- the occupancy threshold fitted on the validation rows so that the
    restored event count matches the undegraded one (:func:`rdnet.nn.decision.fit_threshold`)
    and, with ``support_rule`` (``train.support_rule``), whether to drop the voxels without
    a neighbouring input event (:func:`rdnet.nn.decision.fit_support`, which refits the
    threshold when it drops them), and with ``count_gain`` (``train.fit_count_gain``) the
    count head's gain (:func:`rdnet.nn.decision.fit_count_gain`: the gain whose refitted
    threshold gives the highest validation F1); signed output -- the paper's rounding. Both with the
    validation event metrics (:func:`rdnet.eval.events.match_metrics`) of the decided events.
    ``guide``: the frame-pair guide the network reads (:mod:`rdnet.nn.guide`), or None."""
    from rdnet.eval.events import match_metrics
    from rdnet.nn.decision import (decide_counts, decision_dict, decision_gain, fit_count_gain, fit_support,
                                   fit_threshold, polarity_grid, split_signed, support_applies)
    if len(val_rows) == 0:
        if net.output == "counts":
            raise ConfigError("train.val_sequences", "the counts decision needs validation rows")
        return decision_dict(None, fitted_on="none")
    data = PairsDataset(train_path, events="degraded", crop=None, augment=False, rows=val_rows, guide=guide)
    try:
        out, prob, target, support = predict_counts(net, data, device, image=image, with_support=True)
    finally:
        data.close()
    info = {"fitted_on": f"{len(val_rows)} held-out training rows (train.val_sequences)",
            "val_rows": int(len(val_rows))}
    if net.output == "counts":
        threshold = fit_threshold(out, prob, int(target.sum()))
        if support_rule:
            threshold, info["support"] = fit_support(out, prob, target, support, threshold)
        sup = support if support_applies(info) else None
        reference = polarity_grid(np.rint(target).astype(np.int64))
        if count_gain:
            _, threshold, info["count_gain"] = fit_count_gain(
                out, prob, target, sup, lambda c: match_metrics(polarity_grid(c), reference)["f1"])
        restored = decide_counts(out, prob, threshold, sup, decision_gain(info))
        metrics = match_metrics(polarity_grid(restored), reference)
    else:
        threshold = None
        metrics = match_metrics(polarity_grid(split_signed(np.rint(out)).astype(np.int64)),
                                polarity_grid(split_signed(np.rint(target)).astype(np.int64)))
    log.info("decision: threshold %s, validation %s", threshold, {k: round(v, 4) for k, v in metrics.items()})
    metrics = {k: (v if np.isfinite(v) else None) for k, v in metrics.items()}   # JSON-able card
    return decision_dict(threshold, **info, val_metrics=metrics)


# --- initialisation / resume ----------------------------------------------------------
def _init_from(task: str, net: nn.Module, path: Path, args: Mapping) -> None:
    """Copy weights from ``init_checkpoint``: for ``rdnet`` a stage-1 (restore) or an
    rdnet checkpoint; otherwise a checkpoint of the same kind (fine-tuning)."""
    ck = ckpt_mod.read_checkpoint(path)
    kinds = ("restore", "rdnet") if task == "rdnet" else (args["kind"],)
    if ck["model_kind"] not in kinds:         # the kind first: a wrong kind is the user's first mistake
        raise FormatError(path, "model_kind", f"holds a {ck['model_kind']!r} model; "
                          f"task {task!r} can start from {' or '.join(map(repr, kinds))}")
    if ck["model_args"].get("restore_output", "signed") != args.get("restore_output", "signed"):
        raise FormatError(path, "model_args.restore_output",
                          f"holds a {ck['model_args'].get('restore_output', 'signed')!r} stage-1 output, this run "
                          f"trains {args.get('restore_output', 'signed')!r} (train.restore_output)")
    ckpt_mod.check_compatible(path, ck, bins=args["bins"], image_channels=args["image_channels"])
    if task == "rdnet" and ck["model_kind"] == "restore":
        stored = {k: v for k, v in ck["model_args"].items() if k != "kind"}
        wanted = {k: v for k, v in ckpt_mod._plain(args).items() if k not in ("kind", "stage2_input")}
        if stored != wanted:
            raise FormatError(path, "model_args", f"stage-1 network {stored} differs from this "
                              f"run's stage 1 {wanted}")
        ckpt_mod.load_state(path, net.restore, ck["state_dict"])
    else:
        ckpt_mod.load_state(path, net, ck["state_dict"])
    log.info("initialised %s from %s (step %s)", task, path, ck.get("step"))


def _init_deblur(task: str, net: nn.Module, path: Path, args: Mapping) -> None:
    """Stage 2 of an RDNet from a DeblurNet checkpoint (``init_deblur``; a DeblurNet of
    the same size trained on undegraded events gives stage 2, and with it the event
    encoder F of the feature loss, a clean-event starting point)."""
    if task != "rdnet":
        raise ConfigError("init_deblur", f"only task rdnet takes a stage-2 initialisation, not {task!r}")
    ck = ckpt_mod.read_checkpoint(path)
    if ck["model_kind"] != "deblur":
        raise FormatError(path, "model_kind", f"holds a {ck['model_kind']!r} model; stage 2 starts from a 'deblur' one")
    ckpt_mod.check_compatible(path, ck, bins=args["bins"], image_channels=args["image_channels"])
    stage1_only = ("kind", "restore_output", "stage2_input")       # not DeblurNet arguments
    stored = {k: v for k, v in ck["model_args"].items() if k not in stage1_only}
    wanted = {k: v for k, v in ckpt_mod._plain(args).items() if k not in stage1_only}
    if stored != wanted:
        raise FormatError(path, "model_args", f"DeblurNet {stored} differs from this run's stage 2 {wanted}")
    state = dict(ck["state_dict"])
    if args.get("stage2_input") == "dual":
        # the event input layers read 2 x bins channels: the restored half starts from the
        # DeblurNet's weights, the raw half from zero (the start is the restored-only RDNet)
        own = net.deblur.state_dict()
        for k, w in state.items():
            if k in own and own[k].ndim == w.ndim and own[k].shape != w.shape \
                    and own[k].shape[1] == 2 * w.shape[1] and own[k].shape[0] == w.shape[0]:
                grown = torch.zeros_like(own[k])
                grown[:, :w.shape[1]] = w
                state[k] = grown
    ckpt_mod.load_state(path, net.deblur, state)
    log.info("initialised stage 2 of rdnet from %s (step %s)", path, ck.get("step"))


#: train keys added after the study's checkpoints were written, with the value every earlier
#: run had: a run at that value leaves them out of the checkpoint's config (read back as the
#: default), so its checkpoint is byte-identical to one written before the key existed
ADDED_TRAIN_KEYS = {"count_loss": "l1"}


def _same_run(path: Path, ck: Mapping, task: str, args: Mapping, config: Mapping, extra: Mapping) -> None:
    """ConfigError when checkpoint ``ck`` was written by a run with other settings."""
    def differ(key, a, b):
        raise ConfigError(key, f"{path} was written with {a!r}, this run has {b!r}; "
                          "delete it or run without resuming")
    if ck["task"] != task:
        differ("task", ck["task"], task)
    if ck["model_args"] != ckpt_mod._plain(args):
        differ("model", ck["model_args"], ckpt_mod._plain(args))
    defaults = {f.name: f.default for f in dataclasses.fields(TrainConfig)}
    # a key left out of either (added later, or ADDED_TRAIN_KEYS at its default): its default
    for k in sorted(set(config) | (set(ck["config"]) & set(defaults))):
        was, now = ck["config"].get(k, defaults.get(k)), config.get(k, defaults.get(k))
        if k not in RESUME_FREE and was != now:
            differ(f"train.{k}", was, now)
    for k in ("events", "pairs_shape"):
        if ck.get("extra", {}).get(k) != extra.get(k):
            differ(k, ck.get("extra", {}).get(k), extra.get(k))


def _open_live(out_dir: Path, resume: bool, params: Mapping):
    """DVCLive logger, or None when dvclive is unavailable or fails to start. Never
    writes dvc.yaml nor saves an experiment (safe inside ``dvc repro``/``dvc exp run``)."""
    try:
        from dvclive import Live
        live = Live(dir=str(out_dir / "dvclive"), resume=resume, save_dvc_exp=False,
                    dvcyaml=None, report=None, monitor_system=False)
        live.log_params(ckpt_mod._plain(params))
        return live
    except Exception as e:  # optional: never fail a run because of logging
        log.warning("dvclive disabled: %s", e)
        return None


# --- the loop -------------------------------------------------------------------------
def train(task: str, cfg: TrainConfig, model_cfg: ModelConfig, train_path: str | Path,
          out_dir: str | Path, *, events: str = "degraded", init_checkpoint: str | Path | None = None,
          init_deblur: str | Path | None = None,
          resume: bool = True, progress: bool = True, stop_after: int | None = None, guide=None) -> Path:
    """Train ``task`` on the pairs file ``train_path``; return ``out_dir/model.pt``.

    ``events``: the input event kind of deblur/deblurnet_matched (undegraded or
    degraded; restore and rdnet always read degraded events and target undegraded).
    ``init_deblur`` (rdnet only): stage-2 starting weights from a DeblurNet checkpoint.
    ``init_checkpoint``: starting weights (required for rdnet: the stage-1 checkpoint;
    a warning and a random stage 1 otherwise). ``resume``: continue from
    ``out_dir/last.pt`` when it exists (ConfigError if it was written with other
    settings); a finished ``model.pt`` of the same settings is returned as is.
    ``stop_after``: stop once this many steps are done, as if killed right after the
    checkpoint saved then (for tests of resuming); returns ``last.pt``.
    ``guide`` (task restore_frames only, required there): the
    :class:`rdnet.nn.guide.FramePairGuide` of the image input, stored in the checkpoint.

    Runs data-parallel when ``torch.distributed`` is initialised (see
    :mod:`rdnet.train.distributed`): each process takes its share of every step's
    batch, only rank 0 logs and writes files.
    """
    if task not in TASKS:
        raise ConfigError("task", f"unknown task {task!r}; known: {', '.join(TASKS)}")
    if events not in ("undegraded", "degraded"):
        raise ConfigError("events", f"must be undegraded or degraded, got {events!r}")
    if events != "degraded" and task not in EVENT_INPUT_TASKS:
        raise ConfigError("events", f"task {task!r} reads no choice of events (restore and rdnet read the "
                          f"degraded ones and target the undegraded; image_only reads none); only "
                          f"{', '.join(EVENT_INPUT_TASKS)} take events: {events}")
    if (guide is not None) != (task == "restore_frames"):
        raise ConfigError("guide", "task restore_frames reads the frame-pair guide and needs one" if guide is None
                          else f"only task restore_frames reads a frame-pair guide, not {task!r}")
    info = dist_info()
    device = resolve_device(cfg.device, info)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    out_dir = Path(out_dir)
    last_path, final_path = out_dir / "last.pt", out_dir / "model.pt"

    rows, val_rows = split_rows(train_path, cfg.val_sequences if task in RESTORE_TASKS else 0)
    data = PairsDataset(train_path, events=events, crop=cfg.crop, augment=cfg.augment, seed=cfg.seed,
                        rows=rows, clean_fraction=cfg.clean_fraction if task in RESTORE_TASKS else 0.0,
                        guide=guide)
    counts = cfg.restore_output == "counts" and task in RESTORE_TASKS + ("rdnet",)
    if counts and not data.info.has_counts:
        raise FormatError(Path(train_path), "voxel_degraded_on", "train.restore_output counts needs the "
                          "per-polarity voxels (pairs file written before they existed: rerun the blur step)")
    check_finite(train_path, data.info)     # NaN/inf: refused before any step or output, not a non-finite loss
    args = model_args(task, model_cfg, data.info.channels, data.info.bins, cfg.model_output, cfg.stage2_input)
    config = to_dict(cfg)
    for key, default in ADDED_TRAIN_KEYS.items():   # stored only when not the default: old checkpoints stay equal
        if config[key] == default:
            del config[key]
    extra = {"events": events, "train_path": str(Path(train_path)),
             "init_checkpoint": None if init_checkpoint is None else str(init_checkpoint),
             "init_deblur": None if init_deblur is None else str(init_deblur),
             "model_cfg": to_dict(model_cfg),
             # the shape only (has_counts, has_frame_pair: properties of the file, not of the run)
             "pairs_shape": {k: v for k, v in dataclasses.asdict(data.info).items()
                             if k not in ("has_counts", "has_frame_pair")},
             "voxel": read_pairs_voxel(train_path)}
    if guide is not None:
        extra["guide"] = guide.to_dict()
    if task in RESTORE_TASKS:
        extra["val_rows"] = [int(r) for r in val_rows]
        extra["window_us"] = _median_window_us(train_path, rows)

    if resume and final_path.is_file() and not last_path.is_file():
        ck = ckpt_mod.read_checkpoint(final_path)
        _same_run(final_path, ck, task, args, config, extra)
        if ck.get("step") == cfg.iterations:
            log.info("%s is complete; nothing to do", final_path)
            return final_path

    net = build_seeded(args, cfg.seed)
    start = 0
    state = None
    if resume and last_path.is_file():
        state = ckpt_mod.read_checkpoint(last_path)
        _same_run(last_path, state, task, args, config, extra)
        for key in ("optimizer", "scheduler", "step", "rng"):
            if key not in state:
                raise FormatError(last_path, key, "missing: cannot resume from this checkpoint")
        ckpt_mod.load_state(last_path, net, state["state_dict"])
        start = int(state["step"])
        log.info("resuming %s from %s at step %d", task, last_path, start)
    elif init_checkpoint is not None:
        _init_from(task, net, Path(init_checkpoint), args)
    if state is None and init_deblur is not None:
        _init_deblur(task, net, Path(init_deblur), args)
    if task == "rdnet" and state is None and init_checkpoint is None:
        log.warning("rdnet without init_checkpoint: stage 1 starts from random weights")
    net.to(device)
    opt, sched = make_optimizer(task, net, cfg)
    if state is not None:
        try:
            opt.load_state_dict(state["optimizer"])
            sched.load_state_dict(state["scheduler"])
        except (ValueError, KeyError) as e:
            raise FormatError(last_path, "optimizer", f"does not fit this network: {e}") from None
        ckpt_mod.set_rng_state(state["rng"])
    del state

    model: nn.Module = net
    if info.world_size > 1:
        from torch.nn.parallel import DistributedDataParallel as DDP
        model = DDP(net, device_ids=[device.index] if device.type == "cuda" else None)
    model.train()

    stop = cfg.iterations if stop_after is None else min(cfg.iterations, int(stop_after))
    sampler = StepSampler(len(data), cfg.batch_size, cfg.seed, start, stop, info.rank, info.world_size)
    loader = DataLoader(data, batch_size=sampler.local, sampler=sampler, num_workers=cfg.num_workers,
                        pin_memory=device.type == "cuda", drop_last=False,
                        persistent_workers=False)

    main = info.rank == 0
    live = _open_live(out_dir, resume=start > 0, params={"task": task, "train": config, **extra}) \
        if (main and cfg.dvclive and start < stop) else None
    from tqdm.auto import tqdm
    bar = tqdm(total=cfg.iterations, initial=start, desc=f"train {task}", unit="step",
               disable=(not progress or not main) or None, dynamic_ncols=True)

    def save(path: Path, step: int, full: bool) -> None:
        ck = ckpt_mod.make_checkpoint(net, task, args, config=config, step=step, extra=extra,
                                      optimizer=opt if full else None,
                                      scheduler=sched if full else None, with_rng=full)
        if info.world_size > 1:
            ck["replica_digests"] = replica_digests(net)
        if main:
            ckpt_mod.save_checkpoint(path, ck)
        barrier()

    sums: dict[str, torch.Tensor] = {}
    count = 0
    step = start
    try:
        for batch in loader:
            batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
            loss, parts = compute_loss(task, model, batch, cfg)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"non-finite loss {loss.item()} at step {step}")
            optimizer_step(net, opt, sched, loss, cfg.grad_clip)
            step += 1
            for k, v in parts.items():
                sums[k] = sums.get(k, 0) + v.float()
            count += 1
            bar.update(1)
            if step % cfg.log_every == 0 or step == stop:
                means = {k: float(all_reduce_mean(v / count)) for k, v in sums.items()}
                sums, count = {}, 0
                if main:
                    means["lr"] = opt.param_groups[0]["lr"]
                    bar.set_postfix({k: f"{v:.4g}" for k, v in means.items()})
                    log.debug("step %d %s", step, means)
                    if live is not None:
                        live.step = step
                        for k, v in means.items():
                            live.log_metric(f"train/{k}", v)
                        live.next_step()
            if step < cfg.iterations and (step % cfg.ckpt_every == 0 or step == stop):
                save(last_path, step, full=True)
    finally:
        bar.close()
        if live is not None:
            try:
                live.end()
            except FileNotFoundError:
                # dvclive's last step (removing its VS Code signal file under `dvc exp run`)
                # races with the other seeds' processes (exists, then remove): nothing lost
                pass
        data.close()

    if stop < cfg.iterations:
        return last_path
    if task in RESTORE_TASKS:
        extra["decision"] = fit_decision(net, train_path, val_rows, device, image=task != "restore_events",
                                         support_rule=cfg.support_rule, count_gain=cfg.fit_count_gain,
                                         guide=guide) if main else None
    elif task == "rdnet" and init_checkpoint is not None:
        init_extra = ckpt_mod.read_checkpoint(init_checkpoint).get("extra", {})
        extra["decision"] = init_extra.get("decision")
        val = init_extra.get("val_rows") or []
        if counts and cfg.finetune_restore and len(val) and main:
            # stage 2 fine-tuned stage 1: its occupancy moved, so the threshold is refitted on
            # stage 1's held-out rows (stage 2 trained on them: a count match, not a test score)
            extra["decision"] = {**fit_decision(net.restore, train_path, np.asarray(val, np.int64), device,
                                                support_rule=cfg.support_rule, count_gain=cfg.fit_count_gain),
                                 "refit": "after stage 2 fine-tuning, on the stage-1 validation rows"}
    save(final_path, step, full=False)
    if main and last_path.exists():
        last_path.unlink()
    return final_path
