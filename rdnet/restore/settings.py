"""``restore`` section of params.yaml (how ``rdnet restore`` cleans a recording) and
``ednccn`` (the EDnCNN-style baseline of :mod:`rdnet.restore.ednccn`). Neither imports
torch: ``rdnet restore`` with a classical method never loads it."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from rdnet.config import MAX_RATE_HZ, MAX_SEED, MAX_THREADS, ONE_HOUR_US, check_bounds, positive
from rdnet.errors import ConfigError
from rdnet.sim.settings import SENSOR_LOWER_BOUNDS, SENSOR_UPPER_BOUNDS

METHODS = ("rdnet", "baf", "stcf", "gef", "raw", "ednccn")
#: how a learned restorer's voxel counts become events (``RestoreConfig.event_times``)
EVENT_TIMES = ("input", "bins")
#: what guides the learned restorer on a recording with frames (``RestoreConfig.guide``)
GUIDES = ("auto", "frame", "frame_pair")

#: bounds of the ``restore`` keys (checked by :func:`rdnet.config.check_bounds`; the filter
#: keys are shared with ``ablation.filters``, and ``stcf_k`` is bounded by ``stcf_radius``:
#: :func:`check_stcf_k`)
RESTORE_UPPER_BOUNDS = {
    # durations in int64 microseconds (1e19 overflowed the timestamp arithmetic)
    "window_us": ONE_HOUR_US, "baf_dt_us": ONE_HOUR_US, "stcf_tau_us": ONE_HOUR_US,
    "esr_interval_us": ONE_HOUR_US, "latency_us": ONE_HOUR_US,
    # events held in memory at a time (13 bytes each: 1.3 GB at 1e8)
    "chunk_events": 100_000_000,
    # neighbourhood radii in pixels: STCF reads (2r+1)^2 pixels per event (4,225 at 32), GEF's
    # box sums pad every time bin by r on each side (1e6 asked for a 29 TiB array)
    "stcf_radius": 32, "gef_radius": 32,
    # the guided filter's regulariser for a [0, 1] guide: beyond ~1 it is a box mean already
    "gef_eps": 100.0,
    # time bins of a window's voxel grid, about ten float64 copies of bins x H x W in the guided
    # filter (a 50 ms window in 0.5 ms bins; 100000 ran until killed)
    "gef_bins": 100,
    # raw events scored at most: a day at 10 M events/s is 8.6e11 (the default 1e9: no cap)
    "score_max_events": 1e12,
    # a pixel a million times its neighbours' median count; a rate as the simulator's
    "hot_pixel_factor": 1e6, "hot_pixel_min_hz": MAX_RATE_HZ,
    "workers": MAX_THREADS,
    # a contrast threshold in log units, bounded as the sensor's (rdnet.sim.settings)
    "guide_threshold": SENSOR_UPPER_BOUNDS["threshold_on"]}


def check_stcf_k(key: str, k: int, radius: int) -> None:
    """STCF keeps an event with at least ``k`` supporting pixels among the ``(2 radius + 1)^2 -
    1`` around it (:mod:`rdnet.baselines.stcf`): a larger ``k`` drops every event."""
    most = (2 * radius + 1) ** 2 - 1
    if k > most:
        raise ConfigError(key, f"must be at most {most} (the pixels within radius {radius} of an event), got {k}")


def calibrated_restore(sensor, degrade) -> dict:
    """The ``restore`` keys that ``rdnet restore --calibration REPORT`` sets from the sensor
    and degradation ``rdnet calibrate`` fitted (:func:`rdnet.study.config.calibrated_configs`):
    ``latency_us``, and ``guide_threshold``, the mean of the fitted ON and OFF thresholds
    (the frame-pair guide divides by one threshold)."""
    return {"latency_us": float(degrade.latency_us),
            "guide_threshold": 0.5 * (float(sensor.threshold_on) + float(sensor.threshold_off))}


@dataclass(frozen=True)
class RestoreConfig:
    """``method``: rdnet (the learned restorer: image-guided when the recording has frames,
    events-only otherwise), baf, stcf, gef (needs frames), raw (copy, the reference) or
    ednccn (the EDnCNN-style per-event classifier of :mod:`rdnet.restore.ednccn`).
    ``window_us``: length of the consecutive time windows the recording is restored in
    (a learned restorer may ask for its own). ``chunk_events``: events read at a time
    (memory bound). Filters (defaults = ``ablation.filters``): ``baf_dt_us``;
    ``stcf_tau_us``/``stcf_k``/``stcf_radius``/``stcf_same_polarity``; ``gef_radius``/
    ``gef_eps`` and ``gef_bins`` (time bins of the window voxel grid GEF filters);
    ``gef_mode``: mask (keep the events of the pixels GEF supports, unchanged) or filter
    (the guided-filtered signed voxel grid rounded back to events: times move to the bins).
    ``device``: for the learned restorer. ``workers``: on a CPU, how many windows the
    learned restorer runs at once, torch's threads shared among them (0: one per torch
    thread on sensors up to 640 x 480, one at a time on larger ones, where a window's
    operations are large enough to share out; 1: one window at a time on every thread); the
    events are the same either way.
    ``esr_interval_us``: packet length
    of the ESR no-reference score (E-MLB uses 33 ms); ``scores``: compute the no-reference
    scores at all (false: faster, OUT.json has counts only); ``score_max_events``: event-frame
    consistency is scored only when the raw stream has at most this many events (it is
    streamed, with count images only for the frame intervals in progress: the cap bounds its
    time, not memory; the default, 1e9, is no cap in practice).
    ``hot_pixel_factor``/``hot_pixel_min_hz``: before every method but raw, one pass over
    the recording flags the pixels whose event count exceeds factor x the median of their
    neighbours' on the sensor and whose rate exceeds min_hz, and their events are dropped
    (:mod:`rdnet.restore.hotpixels`; factor 0: off, else >= 1). ``latency_us``: a constant
    sensor latency undone before anything else: subtracted from every event timestamp
    (events that would fall before 0 are dropped), e.g. the ``latency_us`` that
    ``rdnet calibrate`` fitted (``rdnet restore --calibration REPORT``); 0: off.
    ``frame_compression``: how the frames copied to OUT.h5 are stored (none, gzip or lzf;
    events are always gzip): APS frames hardly compress (gzip: 16 % smaller on the DAVIS346
    road recording) and gzip costs 7 % of the learned restorer's time there.
    ``event_times``: how the learned restorer's voxel counts become events: ``input`` (the
    events it keeps are the recording's own, with their timestamps; only the events a voxel
    gets beyond its input are spread over the bin: :mod:`rdnet.events.select`) or ``bins``
    (every output event spread evenly over its bin, as the voxel grid alone allows). Both
    give the same voxel grid. ``add_events``: false caps each voxel of the learned restorer
    at its input events, so it deletes but never adds (its output is then a subset of the
    recording); true (the default) keeps the events it adds where it judges some lost.
    ``delete_events``: false raises each voxel of the learned restorer to at least its input
    events, so it adds but never deletes (every recorded event is in its output); true (the
    default) deletes the events it judges noise. Both false would return the recording as
    it is (``method: raw``) and is refused.
    ``guide``: which trained restorer ``method: rdnet`` uses on a recording with frames when
    no checkpoint is given: ``frame`` (the frame nearest each window, the study's
    ``models/restore_image``), ``frame_pair`` (the two frames bracketing each window, the
    study's ``models/restore_frames``: windows from frame to frame; docs/restoration.md,
    "The frames bracketing the window") or ``auto`` (the default: ``frame_pair`` when the
    camera's threshold is known, ``guide_threshold`` set or ``rdnet restore --calibration``
    given, else ``frame``); a recording without frames gets the events-only restorer either
    way.
    ``guide_threshold``: the camera's contrast threshold (log units) that a frame-pair
    restorer divides the frames' log change by, so that its guide counts the events this
    camera fires; null: the threshold the network was trained with (the simulator's
    ``sensor.threshold_on``, stored in its checkpoint). ``rdnet restore --calibration
    REPORT`` sets it to the thresholds ``rdnet calibrate`` fitted (their mean). On the
    DAVIS346 take (fitted 0.41 against the study's 0.2) the simulator's value made two of
    three seeds add a quarter of their output (docs/restoration.md, "The guide's
    threshold"). The other restorers ignore it."""

    method: Literal["rdnet", "baf", "stcf", "gef", "raw", "ednccn"] = "rdnet"
    window_us: int = 50_000
    chunk_events: int = 1_000_000
    baf_dt_us: int = 10_000
    stcf_tau_us: int = 10_000
    stcf_k: int = 2
    stcf_radius: int = 1
    stcf_same_polarity: bool = False
    gef_radius: int = 2
    gef_eps: float = 0.01
    gef_bins: int = 5
    gef_mode: Literal["mask", "filter"] = "mask"
    device: Literal["cpu", "cuda", "auto"] = "auto"
    workers: int = 0
    esr_interval_us: int = 33_000
    scores: bool = True
    score_max_events: int = 1_000_000_000
    hot_pixel_factor: float = 20.0
    hot_pixel_min_hz: float = 100.0
    latency_us: float = 0.0
    frame_compression: Literal["none", "gzip", "lzf"] = "none"
    event_times: Literal["input", "bins"] = "input"
    add_events: bool = True
    delete_events: bool = True
    guide: Literal["auto", "frame", "frame_pair"] = "auto"
    guide_threshold: float | None = None

    def __post_init__(self):
        for key in ("window_us", "chunk_events", "baf_dt_us", "stcf_tau_us", "stcf_k", "stcf_radius",
                    "gef_radius", "gef_bins", "esr_interval_us"):
            positive(f"restore.{key}", getattr(self, key), allow_zero=False)
        positive("restore.gef_eps", self.gef_eps, allow_zero=False)
        positive("restore.workers", self.workers)
        positive("restore.score_max_events", self.score_max_events)
        positive("restore.hot_pixel_factor", self.hot_pixel_factor)
        if 0 < self.hot_pixel_factor < 1:
            raise ConfigError("restore.hot_pixel_factor", f"must be 0 (off) or >= 1 (a pixel that many times "
                                                         f"its neighbours' median), got {self.hot_pixel_factor}")
        positive("restore.hot_pixel_min_hz", self.hot_pixel_min_hz)
        positive("restore.latency_us", self.latency_us)
        if self.guide_threshold is not None:
            positive("restore.guide_threshold", self.guide_threshold, allow_zero=False)
        check_bounds("restore", self, RESTORE_UPPER_BOUNDS,
                     {"guide_threshold": SENSOR_LOWER_BOUNDS["threshold_on"]})
        check_stcf_k("restore.stcf_k", self.stcf_k, self.stcf_radius)
        if self.method not in METHODS:
            raise ConfigError("restore.method", f"must be one of {list(METHODS)}, got {self.method!r}")
        if self.event_times not in EVENT_TIMES:
            raise ConfigError("restore.event_times", f"must be one of {list(EVENT_TIMES)}, got {self.event_times!r}")
        if self.guide not in GUIDES:
            raise ConfigError("restore.guide", f"must be one of {list(GUIDES)}, got {self.guide!r}")
        if self.gef_mode not in ("mask", "filter"):
            raise ConfigError("restore.gef_mode", f"must be mask or filter, got {self.gef_mode!r}")
        if not self.add_events and not self.delete_events:
            raise ConfigError("restore.delete_events", "false together with restore.add_events: false leaves "
                                                      "every voxel at its input, the recording as it is "
                                                      "(restore.method: raw does that)")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ConfigError("restore.device", f"must be cpu, cuda or auto, got {self.device!r}")
        if self.frame_compression not in ("none", "gzip", "lzf"):
            raise ConfigError("restore.frame_compression", f"must be none, gzip or lzf, got {self.frame_compression!r}")


#: bounds of the ``ednccn`` keys (checked by :func:`rdnet.config.check_bounds`)
EDNCCN_UPPER_BOUNDS = {
    # every event carries a (2 depth, 2r+1, 2r+1) float32 patch, in memory for all training
    # events (EDnCNN: 7x7, r = 3; at r = 8 and depth 8 the default 400,000 events take 7.4 GB)
    "radius": 8, "depth": 8,
    "tau_us": ONE_HOUR_US,
    # channels and units per layer (parameters grow with the product of neighbours)
    "conv_channels": 4096, "hidden": 4096,
    # training events with their patches in memory (784 bytes each at the defaults: 7.8 GB)
    "max_train_events": 10_000_000,
    # passes over the training events, events per step (both time)
    "epochs": 1000, "batch_size": 65_536,
    # Adam's step size, as ``train.lr``
    "lr": 1.0,
    # held-out sequences: as many as ``scenes.n_train`` may hold
    "val_sequences": 10_000,
    "seed": MAX_SEED, "threads": MAX_THREADS}


@dataclass(frozen=True)
class EdnccnConfig:
    """``ednccn`` section of params.yaml. Features: ``radius`` (patch (2r+1)^2),
    ``depth`` (timestamps per pixel and polarity), ``tau_us`` (time scale of the decay).
    Network: ``conv_channels`` (3x3 convolutions, no padding), ``hidden`` (fully connected
    widths). Training: ``max_train_events`` (events drawn from the training windows),
    ``epochs``, ``batch_size``, ``lr`` (Adam, cosine decay to 0), ``val_sequences`` (last
    training sequences held out to fit the keep threshold), ``seed``, ``device``,
    ``threads`` (torch CPU threads; 0 = torch default)."""

    radius: int = 3
    depth: int = 2
    tau_us: int = 10_000
    conv_channels: tuple[int, ...] = (16, 32)
    hidden: tuple[int, ...] = (192, 96)
    max_train_events: int = 400_000
    epochs: int = 4
    batch_size: int = 512
    lr: float = 0.002
    val_sequences: int = 2
    seed: int = 0
    device: str = "auto"
    threads: int = 1

    def __post_init__(self):
        for key in ("radius", "depth", "tau_us", "max_train_events", "epochs", "batch_size", "val_sequences"):
            positive(f"ednccn.{key}", getattr(self, key), allow_zero=False)
        positive("ednccn.lr", self.lr, allow_zero=False)
        positive("ednccn.threads", self.threads)
        positive("ednccn.seed", self.seed)
        check_bounds("ednccn", self, EDNCCN_UPPER_BOUNDS)
        if any(int(c) < 1 for c in self.conv_channels) or any(int(h) < 1 for h in self.hidden):
            raise ConfigError("ednccn.hidden", "conv_channels and hidden widths must be >= 1")
        if 2 * self.radius + 1 - 2 * len(self.conv_channels) < 1:
            raise ConfigError("ednccn.conv_channels", f"{len(self.conv_channels)} unpadded 3x3 convolutions do "
                              f"not fit a {2 * self.radius + 1}-pixel patch (radius {self.radius})")
        if self.device not in ("cpu", "cuda", "auto"):
            raise ConfigError("ednccn.device", f"must be cpu, cuda or auto, got {self.device!r}")
