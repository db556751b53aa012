"""The RDNet checkpoint of ``rdnet deblur``: where it is, and whether it fits the params.

A checkpoint is self-describing (:mod:`rdnet.train.checkpoint`); here it is also checked
against the params the run uses, so that a wrong file fails before any work:

* it must hold an ``rdnet`` network (both stages), not a stage alone or a baseline;
* its size and architecture overrides must be the ``model`` section's;
* its voxel bins must be ``voxel.bins``; its voxel mode and normalisation (recorded by
  training from the pairs file, ``extra.voxel``) must be ``voxel.mode``/``voxel.normalize``.
  Checkpoints written before that record exist carry the bins only; then the mode and
  normalisation of the params are assumed and the result says so.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import torch

from rdnet.errors import FormatError
from rdnet.events.voxel_config import VoxelConfig
from rdnet.train.config import ModelConfig

log = logging.getLogger(__name__)

#: What ``dvc repro`` trains (stage ``train_deblur``): a model.pt, or one per seed.
DEFAULT_CHECKPOINT = Path("models/rdnet")


@dataclass(frozen=True)
class LoadedRDNet:
    """The network (eval mode, on its device), its checkpoint path, the image channels
    and voxel bins it takes, and a note on what could not be checked (empty if all)."""

    net: torch.nn.Module
    path: Path
    image_channels: int
    bins: int
    note: str = ""
    decision: dict | None = None     # stage 1's voxel -> event decision (count output: fitted threshold)


def resolve_checkpoint(path: str | Path | None) -> Path:
    """``path`` itself when it is a file; for a folder its ``model.pt``, else the
    ``seed<k>/model.pt`` of the lowest seed (the study trains one network per seed).
    None means :data:`DEFAULT_CHECKPOINT`."""
    p = Path(DEFAULT_CHECKPOINT if path is None else path)
    if p.resolve() == DEFAULT_CHECKPOINT.resolve() and not p.exists():   # the study's place, however spelt
        raise FormatError(p, None, "the study's RDNet is not trained here: run `dvc repro train_deblur` "
                          "(or `make repro`), or pass --checkpoint FILE")
    if not p.is_dir():
        return p
    if (p / "model.pt").is_file():
        return p / "model.pt"
    seeds = [(int(m.group(1)), d) for d in p.glob("seed*/model.pt")
             if (m := re.fullmatch(r"seed(\d+)", d.parent.name))]
    if seeds:
        return min(seeds)[1]
    raise FormatError(p, None, "no model.pt in this folder (nor in seed<k>/): train the study "
                      "first (`dvc repro train_deblur`) or pass --checkpoint FILE")


def load_rdnet(path: str | Path, model_cfg: ModelConfig, voxel: VoxelConfig,
               device: str | torch.device = "cpu") -> LoadedRDNet:
    """Read checkpoint ``path``, check it against ``model_cfg`` and ``voxel`` (module
    docstring; FormatError naming the file and the field otherwise) and rebuild it."""
    from rdnet.train import checkpoint as ck_mod

    path = Path(path)
    ck = ck_mod.read_checkpoint(path)
    ck_mod.check_compatible(path, ck, expected_kind="rdnet")
    args = ck["model_args"]
    # the checkpoint describes these itself (stage2_input: train.stage2_input, not a model key)
    stored = {k: v for k, v in args.items() if k not in ("kind", "image_channels", "bins", "restore_output", "stage2_input")}
    wanted = ck_mod._plain({"size": model_cfg.size, **model_cfg.overrides()})
    if stored != wanted:
        raise FormatError(path, "model_args", f"holds a {_arch(stored)} network, the params' model "
                          f"section asks for {_arch(wanted)} (pass the matching checkpoint or "
                          f"--set model.size=...)")
    if args.get("bins") != voxel.bins:
        raise FormatError(path, "model_args.bins", f"the network takes {args.get('bins')} voxel bins, "
                          f"voxel.bins is {voxel.bins}")
    recorded = (ck.get("extra") or {}).get("voxel")
    note = ""
    if recorded:
        if recorded.get("mode") is not None and recorded["mode"] != voxel.mode:
            raise FormatError(path, "extra.voxel.mode", f"trained on {recorded['mode']!r} voxels, "
                              f"voxel.mode is {voxel.mode!r}")
        if "normalize" in recorded and _norm(recorded["normalize"]) != _norm(voxel.normalize):
            raise FormatError(path, "extra.voxel.normalize", f"trained on voxels normalised with "
                              f"{recorded['normalize']!r} (None = raw signed counts), "
                              f"voxel.normalize is {voxel.normalize!r}")
    else:
        note = (f"{path} does not record its voxel mode and normalisation (written before they "
                f"were); assumed the params': mode={voxel.mode!r}, normalize={voxel.normalize!r}")
        log.warning(note)
    net = ck_mod.model_from_checkpoint(path, ck, device).eval()
    from rdnet.errors import ValidationError
    from rdnet.nn.decision import read_decision
    try:
        decision = read_decision((ck.get("extra") or {}).get("decision"), net.restore.output)
    except ValidationError as e:
        raise FormatError(path, "extra.decision", str(e)) from None
    if net.restore.output == "counts" and _norm(voxel.normalize) is not None:
        raise FormatError(path, "model_args.restore_output", "a count-output stage 1 reads raw per-polarity "
                          f"counts; voxel.normalize is {voxel.normalize!r}")
    return LoadedRDNet(net=net, path=path, image_channels=int(args["image_channels"]),
                       bins=int(args["bins"]), note=note, decision=decision)


def _norm(value):
    """Voxel normalisation names: None and 'none' both mean raw signed counts."""
    return None if value in (None, "none") else value


def _arch(d: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in d.items())
