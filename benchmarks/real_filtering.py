"""What the benchmarks that filter the real recordings share: each recording that rdnet reads
(``data/real`` and ``../shared/real``, facts from ``stages/real_recordings.yaml``), its events
after ``rdnet restore``'s hot-pixel pass (the ``restore`` section's settings), ``restore_real``'s
region masks, and the event-frame consistency R^2 where it has frames (the ``sensor``
thresholds and ``log_eps`` of params.yaml). Used by ``stcf_radius_real.py`` and
``burst_filter_real.py``."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class RealRecording:
    """``raw``: the recorded events; ``events``: after the hot-pixel pass; ``masks``: region ->
    pixel mask (``activity``, ``background``, and ``hot_pixels`` when asked for and the facts
    list some); ``consistency``: events -> R^2, None without frames."""

    name: str
    raw: object
    events: object
    masks: dict
    consistency: Callable | None

    def shares(self, kept) -> dict:
        """Share of the raw events of each region that ``kept`` keeps (``restore_real``'s
        :func:`rdnet.eval.noref.mask_fractions`)."""
        from rdnet.eval.noref import mask_fractions
        return {m: round(v["fraction"], 5) for m, v in mask_fractions(self.raw, kept, self.masks).items()}


def real_recordings(hot_pixel_mask: bool = False) -> Iterator[RealRecording]:
    from rdnet.config import load_params, section
    from rdnet.deblur.consistency import LogFrames, compare_consistency
    from rdnet.eval.noref import ACTIVITY_MASK, activity_mask, pixel_mask
    from rdnet.events.io import load
    from rdnet.restore.hotpixels import drop_pixels, hot_pixels, pixel_counts
    from rdnet.restore.real import read_facts, recordings

    params = load_params(ROOT / "params.yaml")
    cfg, sensor = section(params, "restore"), section(params, "sensor")
    facts = read_facts(ROOT / "stages" / "real_recordings.yaml")
    for name, path in recordings([ROOT / "data" / "real", ROOT.parent / "shared" / "real"]):
        size = facts.sensor_size.get(name)
        rec = load(path, sensor_size=tuple(size)) if size else load(path)
        raw = rec.events
        act = activity_mask(raw, **ACTIVITY_MASK)
        masks = {"activity": act, "background": ~act}
        if hot_pixel_mask and facts.hot_pixels.get(name):
            masks["hot_pixels"] = pixel_mask(raw.width, raw.height, facts.hot_pixels[name])
        counts, dur = pixel_counts([raw], raw.width, raw.height)
        ev = drop_pixels(raw, hot_pixels(counts, dur, cfg.hot_pixel_factor, cfg.hot_pixel_min_hz))
        frames = rec.frames if rec.frames is not None and len(rec.frames) else None
        yield RealRecording(name, raw, ev, masks,
                            None if frames is None else _consistency(LogFrames.of(frames, raw, sensor.log_eps), sensor,
                                                                     compare_consistency))


def _consistency(log_frames, sensor, compare_consistency) -> Callable:
    def r2(events) -> float:
        return float(compare_consistency(log_frames, {"e": events}, sensor.threshold_on,
                                         sensor.threshold_off)["e"]["r2_fitted"])
    return r2

