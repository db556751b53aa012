"""``train`` and ``model`` sections of params.yaml.

Defaults follow the paper (Sec. 4.1): Adam, learning rate 2e-4 decayed with a cosine
schedule to 1e-7, loss weights alpha = beta = 0.5.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional

from rdnet.config import MAX_SEED, MAX_THREADS, check_bounds, positive
from rdnet.errors import ConfigError
from rdnet.events.core import MAX_SENSOR_SIDE

#: train.count_loss values (:func:`rdnet.nn.losses.count_loss_terms`)
COUNT_LOSSES = ("l1", "poisson")
#: train.restore_output -> RestoreNet output.
RESTORE_OUTPUTS = {"signed_masked": "signed", "counts": "counts"}

#: bounds of the ``train`` keys (checked by :func:`rdnet.config.check_bounds`; ``lr_min`` is at
#: most ``lr``, ``clean_fraction`` below 1)
TRAIN_UPPER_BOUNDS = {
    # optimiser steps: the paper trains 300,000; 1e8 is years at a step a second; the steps
    # between logs and checkpoints likewise
    "iterations": 100_000_000, "log_every": 100_000_000, "ckpt_every": 100_000_000,
    # samples per step, in memory at once (the paper: 8; 1e9 was killed for memory)
    "batch_size": 4096,
    # a square crop of a frame: at most the largest frame side
    "crop": MAX_SENSOR_SIDE,
    # Adam's step size: at 1 a step moves every weight by up to 1 (the paper: 2e-4; 1e300
    # overflowed float32); the weight decay pulls weights to 0 at most as fast
    "lr": 1.0, "weight_decay": 1.0,
    # a gradient norm beyond 1e6 never clips: as good as off (0)
    "grad_clip": 1e6,
    # loss-term weights relative to the deblurring loss's 1 (the study's are <= 1): beyond 1000
    # one term swamps the others
    "alpha": 1000.0, "beta": 1000.0, "stage2_alpha": 1000.0, "empty_weight": 1000.0,
    "occupancy_weight": 1000.0,
    # stage 1's learning rate relative to ``lr`` (the study: 1)
    "restore_lr_scale": 10.0,
    # held-out sequences: as many as ``scenes.n_train`` may hold
    "val_sequences": 10_000,
    "seed": MAX_SEED, "num_workers": MAX_THREADS, "threads": MAX_THREADS}

#: bounds of the ``model`` keys: the first level's channels (doubled per level; the paper
#: preset's 24: parameters grow with its square, 256 gives ~110x the paper's 7.9 M) and the
#: residual blocks per level (the presets' 1-2)
MODEL_UPPER_BOUNDS = {"width": 256, "enc_depths": 64, "middle_depth": 64, "dec_depths": 64}


@dataclass(frozen=True)
class TrainConfig:
    """How a network is optimised (one run of :func:`rdnet.train.loop.train`).

    ``iterations``: optimiser steps; ``batch_size``: samples per step over all processes
    (divisible by the number of processes); ``crop``: square training crop in pixels
    (None = full frames); ``augment``: random flips.
    ``lr``/``lr_min``: Adam learning rate, cosine-annealed to ``lr_min`` over
    ``iterations``; ``weight_decay``: Adam L2 weight decay; ``grad_clip``: max gradient
    norm (0 = off).
    ``alpha``: weight of the masked voxel L1 term (stage 1); ``beta``: weight of the
    feature term L1(F(E_r) - F(E_u)) (stage 2); ``stage2_alpha``: weight of the masked
    voxel L1 term added in stage 2 (0 = the paper: stage 2 trains on L_d plus the
    feature term only); ``empty_weight``: weight of the L1 on voxels where neither
    E_u nor E_d has events (0 = the paper's mask).
    ``restore_output``: stage-1 output and loss: ``signed_masked`` (the paper: a signed
    voxel, L1 masked to where events are) or ``counts`` (per-polarity counts with an
    occupancy head, loss on every voxel, :func:`rdnet.nn.losses.count_restoration_loss`;
    ``alpha`` then weights the count term and ``occupancy_weight`` the occupancy BCE).
    ``count_loss`` (counts output): the count term, ``l1`` (the count head aims at the
    median count of an occupied voxel) or ``poisson`` (the Poisson half-deviance: it aims
    at the mean count, which a restored count equal to the undegraded one needs;
    docs/restoration.md, "The count head's loss").
    ``clean_fraction`` (tasks restore, restore_events): the share of training samples whose
    input events are the undegraded ones themselves (identity pairs, drawn per sample from
    ``(seed, epoch, row)``): without them every stage-1 input has lost events, and the
    restorer learns to add events to any stream, a clean one included (docs/restoration.md,
    "A stream that needs no restoring"). 0 = the paper's training data.
    ``support_rule`` (counts output): whether the fitted decision may drop the voxels with no
    input event at any of the 8 neighbouring pixels in the window; it does when, on the
    validation rows, those voxels are real less often than the occupancy threshold
    (:func:`rdnet.nn.decision.fit_support`; docs/restoration.md, "Events with no
    neighbour"). False = the threshold alone (every decision before it).
    ``fit_count_gain`` (counts output): whether the fitted decision also scales the count
    head's excess over one event, ``1 + g (mu - 1)``, with the gain ``g`` of
    :data:`rdnet.nn.decision.COUNT_GAINS` whose refitted threshold gives the highest F1 on the
    validation rows (:func:`rdnet.nn.decision.fit_count_gain`). False = the count head as it is.
    ``val_sequences``: the last sequences of the training file held out from stage-1
    training (tasks restore, restore_events) to fit the voxel -> event decision
    (:mod:`rdnet.nn.decision`); needed by ``counts`` (>= 1), 0 = train on every row.
    ``stage2_input`` (task rdnet): stage 2 reads the ``restored`` voxel (the paper) or
    ``dual``: the restored and the raw voxels concatenated (it cannot lose what the raw
    events hold; :class:`rdnet.nn.models.RDNet`).
    ``feature_grad`` (task rdnet): whether the feature term of L_er also trains stage 2's
    event encoder F. False (default): F is a fixed perceptual encoder inside that term (its
    weights detached there; the deblurring loss still trains them), so the term trains
    stage 1 only. True: F's weights get the term's gradient too; its target F(E_u) is
    detached, so F chases a moving target: in the study that term grew from about 0.07
    to 1.0-23,800 in 6 of 9 RDNet trainings and to 0.1-0.2 in the other 3 (docs/study.md,
    "Investigation of the RDNet row").
    ``finetune_restore``: stage 2 also updates the stage-1 weights, at
    ``lr * restore_lr_scale``; false freezes them.
    ``seed``: model init, data order, crops; ``device``: cpu, cuda or auto (cuda when
    available); ``num_workers``: DataLoader workers; ``threads``: torch intra-op CPU
    threads of the process (0 = torch's default; a bit-identical resume needs the same
    count as the interrupted run); ``log_every``/``ckpt_every``: steps between metric
    logs / checkpoints (out_dir/last.pt); ``dvclive``: log with DVCLive (else only the
    Python log).
    """

    iterations: int = 200000
    batch_size: int = 8
    crop: Optional[int] = 256
    augment: bool = True
    lr: float = 2e-4
    lr_min: float = 1e-7
    weight_decay: float = 0.0
    grad_clip: float = 0.0
    alpha: float = 0.5
    beta: float = 0.5
    stage2_alpha: float = 0.0
    empty_weight: float = 0.0
    restore_output: Literal["signed_masked", "counts"] = "signed_masked"
    occupancy_weight: float = 1.0
    count_loss: Literal["l1", "poisson"] = "l1"
    clean_fraction: float = 0.0
    support_rule: bool = False
    fit_count_gain: bool = False
    val_sequences: int = 0
    stage2_input: Literal["restored", "dual"] = "restored"
    feature_grad: bool = False
    finetune_restore: bool = True
    restore_lr_scale: float = 1.0
    seed: int = 0
    device: Literal["cpu", "cuda", "auto"] = "auto"
    num_workers: int = 0
    threads: int = 0
    log_every: int = 100
    ckpt_every: int = 1000
    dvclive: bool = True

    @property
    def model_output(self) -> str:
        """The RestoreNet ``output`` of :attr:`restore_output` (signed or counts)."""
        return RESTORE_OUTPUTS[self.restore_output]

    def __post_init__(self):
        for key in ("iterations", "batch_size", "log_every", "ckpt_every"):
            positive(f"train.{key}", getattr(self, key), allow_zero=False)
        if self.crop is not None:
            positive("train.crop", self.crop, allow_zero=False)
        positive("train.lr", self.lr, allow_zero=False)
        positive("train.lr_min", self.lr_min)
        if self.lr_min > self.lr:
            raise ConfigError("train.lr_min", f"{self.lr_min} is larger than train.lr = {self.lr}")
        for key in ("weight_decay", "grad_clip", "alpha", "beta", "stage2_alpha", "empty_weight",
                    "restore_lr_scale", "num_workers", "threads", "seed", "occupancy_weight",
                    "val_sequences"):
            positive(f"train.{key}", getattr(self, key))
        if not 0.0 <= self.clean_fraction < 1.0:
            raise ConfigError("train.clean_fraction", f"must be in [0, 1), got {self.clean_fraction}")
        if self.restore_output not in RESTORE_OUTPUTS:
            raise ConfigError("train.restore_output", f"must be one of {', '.join(RESTORE_OUTPUTS)}, "
                              f"got {self.restore_output!r}")
        if self.count_loss not in COUNT_LOSSES:
            raise ConfigError("train.count_loss", f"must be one of {', '.join(COUNT_LOSSES)}, "
                              f"got {self.count_loss!r}")
        if self.restore_output == "counts" and self.val_sequences < 1:
            raise ConfigError("train.val_sequences", "restore_output counts fits its decision on held-out "
                              "sequences: needs >= 1")
        if self.stage2_input not in ("restored", "dual"):
            raise ConfigError("train.stage2_input", f"must be restored or dual, got {self.stage2_input!r}")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ConfigError("train.device", f"must be cpu, cuda or auto, got {self.device!r}")
        check_bounds("train", self, TRAIN_UPPER_BOUNDS)


@dataclass(frozen=True)
class ModelConfig:
    """Network size: ``size`` picks a preset of :func:`rdnet.nn.models.build_model`
    (tiny/small for tests and quick runs, paper = 7.86 M parameters over both stages);
    the other keys, when set, override the preset's value for every stage network."""

    size: Literal["tiny", "small", "paper"] = "paper"
    width: Optional[int] = None
    enc_depths: Optional[tuple[int, ...]] = None
    middle_depth: Optional[int] = None
    dec_depths: Optional[tuple[int, ...]] = None

    def __post_init__(self):
        if self.size not in ("tiny", "small", "paper"):
            raise ConfigError("model.size", f"must be tiny, small or paper, got {self.size!r}")
        if self.width is not None:
            positive("model.width", self.width, allow_zero=False)
        if self.middle_depth is not None:
            positive("model.middle_depth", self.middle_depth)
        for key in ("enc_depths", "dec_depths"):
            v = getattr(self, key)
            if v is not None and any(d < 0 for d in v):
                raise ConfigError(f"model.{key}", f"depths must be >= 0, got {list(v)}")
        if (self.enc_depths is not None and self.dec_depths is not None
                and len(self.enc_depths) != len(self.dec_depths)):
            raise ConfigError("model.dec_depths", "must have as many levels as model.enc_depths")
        check_bounds("model", self, MODEL_UPPER_BOUNDS)

    def overrides(self) -> dict:
        """The keyword overrides passed to ``build_model`` (the keys that are set)."""
        out = {}
        for key in ("width", "enc_depths", "middle_depth", "dec_depths"):
            v = getattr(self, key)
            if v is not None:
                out[key] = list(v) if isinstance(v, tuple) else v
        return out
