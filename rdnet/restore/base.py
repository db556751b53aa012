"""The :class:`Restorer` protocol and the classical restorers (raw, BAF, STCF, GEF).

A restorer is called in time order on consecutive windows [t0, t1) that tile a
recording, with the events of the window and, when the recording has frames, the APS
frame nearest the window centre (float32 linear intensity in [0, 1], (H, W) grey);
it returns the restored events of that window (time-sorted, inside [t0, t1)). Stateful
restorers (BAF, STCF) carry their timestamp map from one call to the next, so the
result does not depend on the window length. :func:`get_restorer` builds one from the
``restore`` settings; ``method="rdnet"`` loads the learned restorer of
:mod:`rdnet.restore.learned` (imported only then: torch is not needed otherwise).
"""
from __future__ import annotations

from typing import Mapping, Protocol, runtime_checkable

import numpy as np

from rdnet.errors import ConfigError
from rdnet.events.core import Events
from rdnet.restore.settings import METHODS, RestoreConfig


@runtime_checkable
class Restorer(Protocol):
    """What ``rdnet restore`` calls (module docstring). ``name``: e.g. "baf", "stcf", "gef",
    "rdnet-image", "rdnet-events"; ``needs_frames``: refuses recordings without frames;
    ``window_us``: the window length it wants (None: any). Optional attribute ``info``
    (dict): what to record about it in OUT.json (model path, kind, training config and
    metrics for a learned one). Optional method ``parallel(workers, sensor_pixels)``: a
    context manager yielding how many windows may be restored at once inside it (the
    learned restorer's :meth:`~rdnet.restore.learned.LearnedRestorer.parallel`; a restorer
    without it, or one that carries state from window to window, gets them one at a time).
    Optional method ``share_decisions(memo)``: take and give each window's decision through
    a :class:`~rdnet.restore.learned.DecisionMemo` shared by runs on the same recording
    (``restore_recording(memo=...)``; a restorer without it computes every window)."""

    name: str
    needs_frames: bool
    window_us: int | None

    def restore(self, events: Events, t0_us: int, t1_us: int, frame: np.ndarray | None) -> Events: ...


class RawRestorer:
    """Identity: the recorded events (the reference row of every comparison)."""

    name = "raw"
    needs_frames = False
    window_us = None

    def __init__(self):
        self.info = {"kind": "identity"}

    def restore(self, events, t0_us, t1_us, frame):
        return events


class BafRestorer:
    """Background-activity filter (:mod:`rdnet.baselines.baf`), streamed."""

    name = "baf"
    needs_frames = False
    window_us = None

    def __init__(self, cfg: RestoreConfig):
        self.dt_us = cfg.baf_dt_us
        self.state = None
        self.info = {"kind": "filter", "dt_us": self.dt_us}

    def restore(self, events, t0_us, t1_us, frame):
        from rdnet.baselines.baf import baf_filter, baf_state
        if self.state is None:
            self.state = baf_state(events.width, events.height)
        return baf_filter(events, self.dt_us, state=self.state)


class StcfRestorer:
    """Spatio-temporal correlation filter (:mod:`rdnet.baselines.stcf`), streamed."""

    name = "stcf"
    needs_frames = False
    window_us = None

    def __init__(self, cfg: RestoreConfig):
        self.kw = dict(tau_us=cfg.stcf_tau_us, k=cfg.stcf_k, radius=cfg.stcf_radius,
                       same_polarity=cfg.stcf_same_polarity)
        self.state = None
        self.info = {"kind": "filter", **self.kw}

    def restore(self, events, t0_us, t1_us, frame):
        from rdnet.baselines.stcf import StcfState, stcf_filter
        if self.state is None:
            self.state = StcfState(events.width, events.height, self.kw["same_polarity"])
        return stcf_filter(events, **self.kw, state=self.state)


class GefRestorer:
    """Guided event filtering (:func:`rdnet.baselines.gef.gef_voxel`) with the window's
    frame as guide, on the window's events binned into ``gef_bins`` voxels.

    ``gef_mode="mask"`` (default): GEF's mask mode on the unsigned counts decides which
    pixels image structure supports, and the events of those pixels are kept unchanged
    (exact times and polarities; an event is never moved or invented).
    ``gef_mode="filter"``: the signed voxel grid is guided-filtered and rounded back to
    events (:func:`rdnet.events.voxel.voxel_events`: times spread inside their bin; ON and
    OFF events of one voxel cancel)."""

    name = "gef"
    needs_frames = True

    def __init__(self, cfg: RestoreConfig):
        self.radius, self.eps, self.bins, self.mode = cfg.gef_radius, cfg.gef_eps, cfg.gef_bins, cfg.gef_mode
        self.window_us = None
        self.info = {"kind": "filter", "radius": self.radius, "eps": self.eps, "bins": self.bins,
                     "guide": "gradient", "mode": self.mode}

    def restore(self, events, t0_us, t1_us, frame):
        from rdnet.baselines.gef import gef_voxel
        if frame is None:
            raise ConfigError("restore.method", "gef needs the recording's frames")
        if len(events) == 0:
            return events
        dur = max(int(t1_us) - int(t0_us), 1)
        if self.mode == "filter":
            from rdnet.events.voxel import voxel_events, voxel_grid
            grid = gef_voxel(voxel_grid(events, self.bins, t0_us, dur), frame, self.radius, self.eps, mode="filter")
            # spread over [t0, t1 - 1]: every event stays inside the window [t0, t1)
            out = voxel_events(grid, t0_us, max(dur - 1, 1))
            return out.slice_time(int(t0_us), int(t1_us))
        from rdnet.eval.events import polarity_counts
        counts = polarity_counts(events, self.bins, t0_us, dur).sum(0)
        kept = (gef_voxel(counts, frame, self.radius, self.eps) != 0).any(axis=0)     # (H, W)
        return events.select(kept[events.y, events.x])


def get_restorer(method: str, params: Mapping, checkpoint=None, *, has_frames: bool) -> Restorer:
    """The restorer of ``method`` with the settings of ``params`` (the params.yaml dict;
    its ``restore`` section); ``checkpoint`` is only for ``rdnet`` and ``ednccn``. Raises
    :class:`ConfigError` for an unknown method, a missing learned restorer, and gef
    without frames."""
    from rdnet.config import section
    cfg: RestoreConfig = section(params, "restore")
    if method not in METHODS:
        raise ConfigError("restore.method", f"unknown method {method!r}; use one of {', '.join(METHODS)}")
    if checkpoint is not None and method not in ("rdnet", "ednccn"):
        raise ConfigError("checkpoint", f"--checkpoint is for --method rdnet or ednccn, not {method}")
    if method == "raw":
        return RawRestorer()
    if method == "baf":
        return BafRestorer(cfg)
    if method == "stcf":
        return StcfRestorer(cfg)
    if method == "ednccn":
        from rdnet.restore.ednccn import load_ednccn
        return load_ednccn(checkpoint, device=cfg.device)
    if method == "gef":
        if not has_frames:
            raise ConfigError("restore.method", "gef is image-guided and the recording has no frames; "
                                                "use baf, stcf or rdnet")
        return GefRestorer(cfg)
    try:
        from rdnet.restore.learned import load_restorer
    except ModuleNotFoundError as e:
        if e.name != "rdnet.restore.learned":
            raise
        raise ConfigError("restore.method", "learned restorer not available in this installation "
                                            "(rdnet.restore.learned is missing); use baf, stcf or gef") from None
    return load_restorer(checkpoint, has_frames=has_frames, params=dict(params), device=cfg.device,
                         event_times=cfg.event_times, add_events=cfg.add_events,
                         delete_events=cfg.delete_events, guide=cfg.guide,
                         guide_threshold=cfg.guide_threshold)
