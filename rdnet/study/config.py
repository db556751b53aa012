"""Study-level settings: the ``study`` section (training seeds) and the ``networks``
section (the trainings of the study, one ``train_baseline@<name>`` stage each).

Every trained row of the ablation is trained once per seed of ``study.seeds`` (network
initialisation, data order and crops change with the seed; the data set does not), so
that a gap between rows can be told from training noise: rows report the mean and the
sample standard deviation over seeds, and gaps the mean and spread of the *paired*
per-seed differences.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

from rdnet.config import MAX_SEED, MAX_THREADS, at_most, check_bounds, from_dict
from rdnet.errors import ConfigError
from rdnet.sim.settings import RANDOMIZE_UPPER_BOUNDS

#: bounds of the ``study`` keys (checked by :func:`rdnet.config.check_bounds`; at most
#: :data:`MAX_SEEDS` seeds)
UPPER_BOUNDS = {
    "seeds": MAX_SEED,
    # training processes at once (as threads)
    "parallel": MAX_THREADS,
    # factors on the ``degrade`` section, as the ``randomize`` scales
    "stress_scales": RANDOMIZE_UPPER_BOUNDS["test_scale"],
    # draws of the circuit generator: seconds each on the embedded test split, hours on GOPRO's
    "circuit_draws": 100}
#: every network is trained once per seed (as ``calibrate.seeds``: far more than a spread needs)
MAX_SEEDS = 100


@dataclass(frozen=True)
class StudyConfig:
    """``seeds``: training seeds of every network (at least one; distinct).
    ``parallel``: trainings run at once by a training stage (processes; each uses
    ``train.threads`` torch threads). ``launcher``: the command that runs the training
    stages (dvc.yaml ``${study.launcher}``): ``python``, or for several GPUs
    ``torchrun --standalone --nproc_per_node=8`` (then ``parallel`` must be 1).
    ``degrade_from``: a ``report.json`` of ``rdnet calibrate``; when set, its
    ``fitted_config`` (sensor + degrade) replaces the ``sensor`` and ``degrade`` sections
    for the simulated training and test events (randomized by ``randomize`` as usual):
    the study rerun with a camera-calibrated degradation.
    ``rdnet_stage2_init``: a network of ``networks`` (a DeblurNet, e.g. ``deblur_undegraded``)
    whose weights start RDNet's stage 2, seed by seed; null: stage 2 starts from scratch.
    ``stress_scales`` / ``stress_rows``: the stress test (:mod:`rdnet.study.stress`) scores
    these rows on the test sequences with every effect at exactly each scale x ``degrade``.
    ``circuit_draws``: independent draws of the circuit generator in stage
    ``restoration_circuit`` (:mod:`rdnet.study.independent`); 0 switches the stage off (it
    integrates every pixel in steps of at most 250 us: a few seconds a draw for the embedded
    64x64 test split, several hours estimated from that rate for GOPRO's 1280x720 one)."""

    seeds: tuple = (0, 1, 2)
    parallel: int = 1
    launcher: str = "python"
    degrade_from: Optional[str] = None
    rdnet_stage2_init: Optional[str] = None
    stress_scales: tuple = (0.5, 1.0, 1.5, 2.0, 3.0)
    stress_rows: tuple = ("undegraded_train", "degraded_train", "rdnet", "restored")
    circuit_draws: int = 3

    def __post_init__(self):
        seeds = tuple(int(s) for s in self.seeds)
        if not seeds:
            raise ConfigError("study.seeds", "needs at least one seed")
        if len(set(seeds)) != len(seeds):
            raise ConfigError("study.seeds", f"seeds must be distinct, got {list(seeds)}")
        if any(s < 0 for s in seeds):
            raise ConfigError("study.seeds", "seeds must be >= 0")
        object.__setattr__(self, "seeds", seeds)
        scales = tuple(float(v) for v in self.stress_scales)
        if any(not v > 0 for v in scales):
            raise ConfigError("study.stress_scales", f"must be > 0, got {list(scales)}")
        object.__setattr__(self, "stress_scales", scales)
        object.__setattr__(self, "stress_rows", tuple(str(r) for r in self.stress_rows))
        if not self.launcher.strip():
            raise ConfigError("study.launcher", "must name a command (python or torchrun ...)")
        if int(self.circuit_draws) < 0:
            raise ConfigError("study.circuit_draws", f"must be >= 0 (0: off), got {self.circuit_draws}")
        if int(self.parallel) < 1:
            raise ConfigError("study.parallel", f"must be >= 1, got {self.parallel}")
        if len(seeds) > MAX_SEEDS:
            raise ConfigError("study.seeds", f"at most {MAX_SEEDS} seeds, got {len(seeds)}")
        check_bounds("study", self, UPPER_BOUNDS)


@dataclass(frozen=True)
class NetworkConfig:
    """One training of the study (an entry of the ``networks`` section).

    ``task``: a task of :data:`rdnet.train.loop.TASKS`; ``events``: the training events;
    ``iterations_factor``: multiplies ``train.iterations`` (2 gives a network the
    optimisation steps of both RDNet stages together: the equal-compute comparison)."""

    task: Literal["restore", "deblur", "deblurnet_matched", "image_only", "rdnet"]
    events: Literal["degraded", "undegraded"] = "degraded"
    iterations_factor: float = 1.0

    def __post_init__(self):
        if not self.iterations_factor > 0:
            raise ConfigError("networks.*.iterations_factor", f"must be > 0, got {self.iterations_factor}")
        at_most("networks.*.iterations_factor", self.iterations_factor, 100.0)   # the study's: 2


def network(params: dict, name: str) -> NetworkConfig:
    nets = params.get("networks") or {}
    if name not in nets:
        raise ConfigError(f"networks.{name}", f"unknown network; networks: {', '.join(nets) or 'none'}")
    return from_dict(NetworkConfig, nets[name], f"networks.{name}")


def seed_dir(run_dir: str | Path, seed: int) -> Path:
    """Where the training of ``seed`` lives inside a network's output directory."""
    return Path(run_dir) / f"seed{int(seed)}"


def seed_checkpoint(checkpoint: str | Path, seed: int) -> Path:
    """The checkpoint of ``seed``: ``checkpoint`` itself when it names a ``.pt`` file (one
    model, the same for every seed), else ``<checkpoint>/seed<seed>/model.pt``."""
    p = Path(checkpoint)
    return p if p.suffix == ".pt" else seed_dir(p, seed) / "model.pt"


def calibrated_configs(report_path: str | Path, option: str = "study.degrade_from"):
    """``(SensorConfig, DegradeConfig)`` of the ``fitted_config`` of an ``rdnet calibrate``
    report (FormatError / ConfigError naming the file and field when it is not one;
    ``option``: where the path came from, for the missing-file message). A path that
    exists but is not a regular file (a FIFO, which would block the read forever, or a
    folder) is refused before anything is read."""
    import json
    from rdnet.errors import FormatError
    from rdnet.events.io._common import require_file
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    p = Path(report_path)
    if not p.exists():
        raise FormatError(p, None, f"no such file ({option})")
    require_file(p)                     # not a regular file (FIFO, folder), permission denied
    try:
        rep = json.loads(p.read_text())
    except (OSError, ValueError) as e:
        raise FormatError(p, None, f"not a JSON calibration report: {e}") from None
    fitted = rep.get("fitted_config") if isinstance(rep, dict) else None
    if not isinstance(fitted, dict) or not isinstance(fitted.get("sensor"), dict) \
            or not isinstance(fitted.get("degrade"), dict):
        raise FormatError(p, "fitted_config", "missing or without sensor/degrade sections")
    return (from_dict(SensorConfig, fitted["sensor"], "fitted_config.sensor", p),
            from_dict(DegradeConfig, fitted["degrade"], "fitted_config.degrade", p))
