"""Self-describing checkpoints (nanoGPT style): a checkpoint rebuilds its network alone.

A checkpoint is a ``torch.save`` dict with:

* ``format`` (:data:`FORMAT`), ``rdnet_version``;
* ``task`` (restore / deblur / rdnet / image_only), ``model_kind`` and ``model_args``
  (the keyword arguments of :func:`rdnet.nn.models.build_model`: kind, size,
  image_channels, bins and the overrides), ``model_class`` and ``model_config`` (the
  network's constructor arguments, checked on load);
* ``state_dict``; ``config`` (the train config dict), ``extra`` (e.g. the input event
  kind of a deblur model, and ``voxel``: bins, mode and normalisation of the training
  voxels, :func:`rdnet.train.data.read_pairs_voxel`);
* for resuming: ``optimizer``, ``scheduler``, ``step``, ``rng`` (torch CPU/CUDA and
  numpy global generator states).

Files are written atomically (temporary name in the same folder, then ``os.replace``),
byte for byte the same for the same content (:func:`save_checkpoint`), and read with ``torch.load(weights_only=True)``: only tensors and plain Python values
are stored, so loading a checkpoint never executes code.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

import rdnet
from rdnet.errors import ConfigError, FormatError
from rdnet.events.io._common import require_file

FORMAT = "rdnet-checkpoint-1"
REQUIRED_KEYS = ("format", "task", "model_kind", "model_args", "model_class", "model_config",
                 "state_dict")


def unwrap(model: nn.Module) -> nn.Module:
    """The bare network of a DistributedDataParallel / DataParallel wrapper."""
    return getattr(model, "module", model)


def rng_state() -> dict:
    """Torch (CPU and CUDA) and numpy global generator states, as plain values."""
    np_state = np.random.get_state()
    state = {
        "torch": torch.get_rng_state(),
        "numpy": [np_state[0], torch.from_numpy(np_state[1].astype(np.int64)), int(np_state[2]),
                  int(np_state[3]), float(np_state[4])],
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: Mapping) -> None:
    torch.set_rng_state(state["torch"].cpu())
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((name, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    if "cuda" in state and torch.cuda.is_available():
        cuda = list(state["cuda"])
        if len(cuda) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all([s.cpu() for s in cuda])


def _plain(v: Any) -> Any:
    """Config values as plain lists/dicts (no tuples/dataclasses) for weights_only loads."""
    if isinstance(v, Mapping):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


def make_checkpoint(model: nn.Module, task: str, model_args: Mapping, *, config: Mapping | None = None,
                    optimizer=None, scheduler=None, step: int = 0, extra: Mapping | None = None,
                    with_rng: bool = True) -> dict:
    net = unwrap(model)
    ck = {
        "format": FORMAT,
        "rdnet_version": rdnet.__version__,
        "task": task,
        "model_kind": model_args["kind"],
        "model_args": _plain(model_args),
        "model_class": type(net).__name__,
        "model_config": _plain(getattr(net, "config", {})),
        "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()},
        "config": _plain(config or {}),
        "extra": _plain(extra or {}),
        "step": int(step),
    }
    if optimizer is not None:
        ck["optimizer"] = optimizer.state_dict()
    if scheduler is not None:
        ck["scheduler"] = scheduler.state_dict()
    if with_rng:
        ck["rng"] = rng_state()
    return ck


def save_checkpoint(path: str | Path, checkpoint: Mapping) -> Path:
    """Write ``checkpoint`` to ``path`` atomically (temp file + os.replace).

    Byte-deterministic: equal content gives equal bytes, so DVC sees an unchanged out
    when a rerun reproduces the same weights. ``torch.save`` to a *file name* prefixes
    every zip record with that name (here the random temporary name); to an open file it
    uses the fixed prefix ``archive/`` (zip timestamps are fixed by torch). Nothing of
    wall-clock time is stored in a checkpoint."""
    from rdnet.events.io._common import atomic_output
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp, open(tmp, "wb") as f:
        torch.save(dict(checkpoint), f)
    return path


def read_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict:
    """Load and check the top-level layout of a checkpoint (FormatError otherwise)."""
    path = Path(path)
    if not path.exists():
        raise FormatError(path, None, "checkpoint not found")
    require_file(path)                  # a FIFO or folder: "not a regular file", not "not found"
    try:
        ck = torch.load(path, map_location=device, weights_only=True)
    except Exception as e:  # corrupt zip, truncated file, foreign pickle ...
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise FormatError(path, None, f"not a readable checkpoint ({type(e).__name__}: {msg[:200]})") from None
    if not isinstance(ck, dict):
        raise FormatError(path, None, f"not an rdnet checkpoint (a {type(ck).__name__})")
    for key in REQUIRED_KEYS:
        if key not in ck:
            raise FormatError(path, key, "missing from checkpoint (not an rdnet checkpoint?)")
    if ck["format"] != FORMAT:
        raise FormatError(path, "format", f"unsupported checkpoint format {ck['format']!r}, expected {FORMAT!r}")
    return ck


def build_from_args(model_args: Mapping) -> nn.Module:
    from rdnet.nn.models import build_model
    args = dict(model_args)
    return build_model(args.pop("kind"), args.pop("size"), **args)


def check_compatible(path, ck: Mapping, *, expected_kind: str | None = None,
                     bins: int | None = None, image_channels: int | None = None,
                     size: str | None = None) -> None:
    """FormatError when the checkpoint is not of the expected kind / voxel bins /
    image channels / size."""
    args = ck["model_args"]
    if expected_kind is not None and ck["model_kind"] != expected_kind:
        raise FormatError(path, "model_kind",
                          f"checkpoint holds a {ck['model_kind']!r} model ({ck['model_class']}), "
                          f"expected {expected_kind!r}")
    if bins is not None and args.get("bins") != bins:
        raise FormatError(path, "model_args.bins",
                          f"model was trained on {args.get('bins')} voxel bins, data has {bins}")
    if image_channels is not None and args.get("image_channels") != image_channels:
        raise FormatError(path, "model_args.image_channels",
                          f"model takes {args.get('image_channels')} image channels, data has {image_channels}")
    if size is not None and args.get("size") != size:
        raise FormatError(path, "model_args.size", f"model size {args.get('size')!r}, expected {size!r}")


def load_state(path, net: nn.Module, state_dict: Mapping, field: str = "state_dict") -> None:
    """``net.load_state_dict(strict=True)`` with a FormatError naming missing, unexpected
    or mis-shaped parameters."""
    own = net.state_dict()
    missing = [k for k in own if k not in state_dict]
    unexpected = [k for k in state_dict if k not in own]
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"{len(missing)} missing (first: {missing[0]})")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected (first: {unexpected[0]})")
        raise FormatError(path, field, "parameters do not match the network: " + ", ".join(parts))
    for k, v in own.items():
        if tuple(state_dict[k].shape) != tuple(v.shape):
            raise FormatError(path, f"{field}.{k}",
                              f"shape {tuple(state_dict[k].shape)} != network {tuple(v.shape)}")
    net.load_state_dict(state_dict, strict=True)


def model_from_checkpoint(path, ck: Mapping, device: str | torch.device = "cpu") -> nn.Module:
    """Rebuild the network of a loaded checkpoint dict and load its weights."""
    try:
        net = build_from_args(ck["model_args"])
    except (TypeError, ValueError, KeyError, ConfigError) as e:
        raise FormatError(path, "model_args", f"cannot rebuild the network: {e}") from None
    if type(net).__name__ != ck["model_class"]:
        raise FormatError(path, "model_class",
                          f"checkpoint says {ck['model_class']}, its arguments build {type(net).__name__}")
    cfg = _plain(getattr(net, "config", {}))
    stored = ck["model_config"]
    if stored and cfg != stored:
        diff = [f"{k}: stored {stored.get(k)!r}, rebuilt {cfg.get(k)!r}"
                for k in sorted(set(cfg) | set(stored)) if cfg.get(k) != stored.get(k)]
        raise FormatError(path, "model_config",
                          f"model_args build a different network ({'; '.join(diff[:3])})")
    load_state(path, net, ck["state_dict"])
    return net.to(device)


def load_model(path: str | Path, expected_kind: str | None = None, device: str | torch.device = "cpu",
               *, bins: int | None = None, image_channels: int | None = None,
               loaded: dict | None = None) -> nn.Module:
    """The network stored in checkpoint ``path``, rebuilt from the checkpoint alone, in
    eval mode on ``device``. ``expected_kind``/``bins``/``image_channels``, when given,
    must match (FormatError naming the file and field otherwise). ``loaded``: the
    checkpoint dict already read from ``path`` (the file is then not read again)."""
    ck = read_checkpoint(path) if loaded is None else loaded
    check_compatible(path, ck, expected_kind=expected_kind, bins=bins, image_channels=image_channels)
    net = model_from_checkpoint(path, ck, device)
    net.eval()
    return net


def checkpoint_summary(path: str | Path) -> dict:
    """Plain description of a checkpoint (task, model, step, parameter count)."""
    ck = read_checkpoint(path)
    n = sum(int(v.numel()) for v in ck["state_dict"].values())
    return {"task": ck["task"], "model_kind": ck["model_kind"], "model_class": ck["model_class"],
            "model_args": ck["model_args"], "step": ck.get("step"), "state_numel": n,
            "extra": ck.get("extra", {}), "rdnet_version": ck.get("rdnet_version")}
